"""The operator page's server: aiohttp on its own thread and event loop, so the run's loop never waits on it.

Routes: ``/`` the page; ``/assets/...`` its script and style (shipped in the wheel, nothing from the network);
``/api/meta`` the run's devices and epoch; ``/api/samples`` every sample so far (the decimated replay, or what a
live run has pushed); ``/api/stars`` the catalog; ``/api/events`` the event log; ``/ws`` a websocket on which a
live run pushes new samples, events and status; ``POST /api/control`` pause, resume or stop a live run.

Control is accepted only from the address the server is bound to, unless a token is configured; then only with
the token (header ``X-Stand-Token``), from anywhere that can reach the server. Binding anywhere but 127.0.0.1
requires a token. A control request must be JSON and, when the browser sends an Origin, come from the page
itself, so another site open in the operator's browser cannot pause the run.
"""

from __future__ import annotations

import asyncio
import hmac
import json
import os
import socket
import threading
import time
from pathlib import Path

import numpy as np
from aiohttp import WSMsgType, web

from . import state

ASSETS = Path(__file__).with_name("assets")
LOCAL = "127.0.0.1"
#: Longest wait for the server thread to bind (or fail to).
START_TIMEOUT_S = 10.0


class ViewError(ValueError):
    """A --view / --bind / --token value the server cannot use (one sentence)."""


def parse_bind(text: str | None, default_host: str = LOCAL) -> tuple[str, int]:
    """``HOST:PORT``, ``HOST`` or ``:PORT`` (port 0 or absent: a free port)."""
    if text is None or text == "":
        return default_host, 0
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = text, "0"
    host = host.strip("[]") or default_host
    try:
        p = int(port or 0)
    except ValueError:
        p = -1
    if not 0 <= p <= 65535:
        raise ViewError(f"--view/--bind {text!r} is not allowed: HOST:PORT with a port from 0 (any free) to 65535.")
    try:
        socket.getaddrinfo(host, None)
    except socket.gaierror:
        raise ViewError(f"--view/--bind {text!r} is not allowed: host {host!r} is not an address of this "
                        "machine or a name it can resolve.") from None
    return host, p


class ReplaySource:
    """A finished (or still running, or killed) run folder."""

    mode = "replay"

    def __init__(self, run_dir, max_samples: int = state.MAX_SAMPLES):
        self.run_dir = Path(run_dir)
        self.meta = state.load_meta(run_dir)
        self.sky = state.Sky(self.meta)
        self.max_samples = max_samples
        self.listeners: list = []
        self.status = "replay"

    def snapshot(self):
        return (state.replay_samples(self.run_dir, self.meta, self.max_samples, self.sky),
                state.read_events(self.run_dir))


class ViewServer:
    """Serve ``source`` (a :class:`ReplaySource` or a :class:`state.LiveFeed`) on ``host:port``."""

    def __init__(self, source, host: str = LOCAL, port: int = 0, token: str | None = None):
        if host != LOCAL and not token:
            raise ViewError(f"binding the view to {host!r} is not allowed without a token: pass --view-token or set "
                            "STAND_VIEW_TOKEN (anyone who can reach the page could otherwise stop the run); "
                            "127.0.0.1 needs none.")
        self.source, self.host, self.port, self.token = source, host, port, token
        self.sockets: set = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._runner: web.AppRunner | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._stars: dict[float, bytes] = {}
        self.sent = 0

    # -- lifecycle ---------------------------------------------------------------------------------------
    def start(self) -> str:
        """Bind and serve on a thread; returns the page's URL."""
        self._thread = threading.Thread(target=self._serve, name="view-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(START_TIMEOUT_S):
            raise ViewError(f"the view server did not start within {START_TIMEOUT_S:g} s.")
        if self._error is not None:
            err = self._error
            raise ViewError(f"the view server cannot listen on {self.host}:{self.port}: "
                            f"{getattr(err, 'strerror', None) or err}.")
        self.source.listeners.append(self._push)
        return self.url

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    def _serve(self) -> None:
        loop = self._loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        try:
            self._runner = web.AppRunner(self.app(), access_log=None)
            loop.run_until_complete(self._runner.setup())
            site = web.TCPSite(self._runner, self.host, self.port, reuse_address=True)
            loop.run_until_complete(site.start())
            self.port = site._server.sockets[0].getsockname()[1]
        except BaseException as exc:  # reported by start() in the caller's thread
            self._error = exc
            self._ready.set()
            loop.close()
            return
        self._ready.set()
        try:
            loop.run_forever()
        finally:
            loop.run_until_complete(self._shutdown())
            loop.close()

    async def _shutdown(self) -> None:
        for ws in list(self.sockets):
            await ws.close()
        if self._runner is not None:
            await self._runner.cleanup()

    def close(self, linger_s: float = 0.0) -> None:
        """Stop serving (idempotent); ``linger_s`` gives open pages time to take the last push."""
        if self._push in self.source.listeners:
            self.source.listeners.remove(self._push)
        if self._loop is not None and self._thread is not None and self._thread.is_alive():
            if linger_s > 0:
                time.sleep(linger_s)
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=10.0)

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.close()

    # -- pushing from the live feed's thread -------------------------------------------------------------
    def _push(self, message: dict) -> None:
        if self._loop is None or not self.sockets:
            return
        text = json.dumps(message)
        try:
            self._loop.call_soon_threadsafe(lambda: self._loop.create_task(self._broadcast(text)))
        except RuntimeError:  # the loop closed while the run ends
            pass

    async def _broadcast(self, text: str) -> None:
        for ws in list(self.sockets):
            if ws.closed:
                self.sockets.discard(ws)
                continue
            try:
                await ws.send_str(text)
                self.sent += 1
            except (ConnectionError, RuntimeError):
                self.sockets.discard(ws)

    # -- the app -----------------------------------------------------------------------------------------
    def app(self) -> web.Application:
        app = web.Application(middlewares=[self._headers])
        app.router.add_get("/", self._index)
        app.router.add_static("/assets/", ASSETS)
        app.router.add_get("/api/meta", self._meta)
        app.router.add_get("/api/samples", self._samples)
        app.router.add_get("/api/stars", self._stars_route)
        app.router.add_get("/api/events", self._events)
        app.router.add_get("/ws", self._ws)
        app.router.add_post("/api/control", self._control)
        return app

    @web.middleware
    async def _headers(self, request, handler):
        resp = await handler(request)
        # The page loads nothing from elsewhere; say so to the browser too.
        resp.headers.setdefault("Content-Security-Policy", "default-src 'self'; connect-src 'self' ws: wss:; "
                                "img-src 'self' data:; style-src 'self'; script-src 'self'")
        resp.headers.setdefault("Cache-Control", "no-store")
        return resp

    async def _index(self, request):
        return web.FileResponse(ASSETS / "index.html")

    async def _meta(self, request):
        src = self.source
        summary = None
        path = src.run_dir / "summary.json"
        if src.mode == "replay" and path.is_file():
            try:
                summary = {k: v for k, v in json.loads(path.read_text()).items()
                           if k in ("pass", "status", "error", "criteria")}
            except json.JSONDecodeError:
                summary = None
        return web.json_response({**src.meta, "mode": src.mode, "status": src.status, "summary": summary,
                                  "run_dir": str(src.run_dir), "token_required": bool(self.token),
                                  "control_from": None if self.token else self.host})

    async def _samples(self, request):
        loop = asyncio.get_running_loop()
        samples, events = await loop.run_in_executor(None, self.source.snapshot)
        body = json.dumps({"samples": state.encode(samples) if samples else {}, "events": events,
                           "status": self.source.status})
        resp = web.Response(text=body, content_type="application/json")
        resp.enable_compression()
        return resp

    async def _stars_route(self, request):
        try:
            mag = float(request.query.get("mag", "9"))
        except ValueError:
            raise web.HTTPBadRequest(text="mag must be a number (Hp magnitude limit, up to 9).") from None
        key = min(max(mag, -2.0), 9.0)
        if key not in self._stars:
            loop = asyncio.get_running_loop()
            table = await loop.run_in_executor(None, state.star_table, self.source.meta, key)
            self._stars[key] = json.dumps(table).encode()
        resp = web.Response(body=self._stars[key], content_type="application/json")
        resp.enable_compression()
        return resp

    async def _events(self, request):
        return web.json_response(state.read_events(self.source.run_dir))

    async def _ws(self, request):
        ws = web.WebSocketResponse(heartbeat=20.0)
        await ws.prepare(request)
        self.sockets.add(ws)
        try:
            await ws.send_str(json.dumps({"type": "status", "status": self.source.status}))
            async for msg in ws:
                if msg.type in (WSMsgType.ERROR, WSMsgType.CLOSE):
                    break
        finally:
            self.sockets.discard(ws)
        return ws

    def control_refusal(self, request) -> str | None:
        """Why a control request is refused, or None."""
        if self.token:
            given = request.headers.get("X-Stand-Token", "")
            if not hmac.compare_digest(given.encode(), self.token.encode()):
                return "this view needs its token (X-Stand-Token) to pause, resume or stop the run"
        elif request.remote != self.host:
            return f"control is accepted only from {self.host}, the address the view is bound to"
        origin = request.headers.get("Origin")
        if origin is not None and origin.split("://", 1)[-1] != request.host:
            return f"control must come from the page itself (Origin {origin!r})"
        if request.content_type != "application/json":
            return "control requests are JSON"
        return None

    async def _control(self, request):
        if self.source.mode != "live":
            return web.json_response({"error": "a replay has no run to control"}, status=409)
        why = self.control_refusal(request)
        if why is not None:
            return web.json_response({"error": why}, status=403)
        try:
            command = (await request.json()).get("command")
            status = self.source.request(command)
        except (ValueError, AttributeError) as exc:
            return web.json_response({"error": str(exc)}, status=400)
        return web.json_response({"status": status})


class PipeLink:
    """The feed's end of the pipe to the server process (used from the feed's sender thread only)."""

    def __init__(self, conn):
        self.conn = conn

    def send(self, message) -> None:
        kind, rows = message
        self.conn.send_bytes(b"R" + np.ascontiguousarray(rows, dtype="<f8").tobytes())

    def receive(self) -> list:
        out = []
        while self.conn.poll(0):
            out.append(self.conn.recv())
        return out


def serve_live(conn, run_dir: str, meta: dict, host: str, port: int, token: str | None) -> None:
    """The server process of ``stand run --view``. Messages on ``conn``: ``R`` + rows as float64 bytes, ``F`` + the
    run's status when it ended, ``C`` to end the process; control commands go back as Python objects."""
    # Under contention the run's loop comes first; the page can wait a few milliseconds.
    os.nice(5)
    lock = threading.Lock()

    def control(command):
        with lock:
            conn.send(command)

    source = state.LiveSource(run_dir, meta, control)
    try:
        view = ViewServer(source, host, port, token)
        url = view.start()
    except ViewError as exc:
        conn.send_bytes(b"error " + str(exc).encode())
        return
    conn.send_bytes(b"ready " + url.encode())
    width = None
    try:
        while True:
            if not conn.poll(1.0):
                if os.getppid() == 1:  # the run's process is gone
                    break
                continue
            data = conn.recv_bytes()
            tag, data = data[:1], data[1:]
            if tag == b"F":
                source.finished(data.decode())
                continue
            if tag == b"C":
                break
            if width is None:
                cols = source._schema()
                width = sum(int(c["width"]) for c in cols) if cols else None
            if width:
                source.ingest(np.frombuffer(data, dtype="<f8").reshape(-1, width))
    except (EOFError, OSError):
        pass
    finally:
        view.close(linger_s=0.5 if view.sockets else 0.0)


class LiveSession:
    """``stand run --view``: the live feed (the loop's observer) in the run's process and the server in a process
    of its own, joined by a pipe, so deriving, encoding and serving never take the run's interpreter lock."""

    def __init__(self, host: str, port: int, token: str | None):
        if host != LOCAL and not token:
            raise ViewError(f"--view {host}:{port} is not allowed without a token: pass --view-token or set "
                            "STAND_VIEW_TOKEN (anyone who can reach the page could otherwise stop the run); "
                            "127.0.0.1 needs none.")
        self.host, self.port, self.token = host, port, token
        self.feed: state.LiveFeed | None = None
        self.process = None
        self.conn = None
        self.url: str | None = None

    @classmethod
    def from_args(cls, bind: str, token: str | None) -> LiveSession:
        host, port = parse_bind(bind)
        return cls(host, port, token)

    def start(self, sc, run_dir, duration_s: float | None = None) -> str:
        """Write ``view.json``, start the server process and the feed; returns the page's URL."""
        import multiprocessing

        meta = json.loads(state.write_view_json(sc, run_dir, duration_s).read_text())
        ctx = multiprocessing.get_context("spawn")  # no fork of a process whose buses have threads
        self.conn, child = ctx.Pipe(duplex=True)
        self.process = ctx.Process(target=serve_live, name="stand-view",
                                   args=(child, str(run_dir), meta, self.host, self.port, self.token), daemon=True)
        self.process.start()
        child.close()
        if not self.conn.poll(START_TIMEOUT_S * 3):
            self._end()
            raise ViewError(f"the view server did not start within {START_TIMEOUT_S * 3:g} s.")
        try:
            reply = self.conn.recv_bytes().decode()
        except (EOFError, OSError):
            reply = "error the view server's process ended before it could serve (see its error above)."
        if not reply.startswith("ready "):
            self._end()
            raise ViewError(reply.split(" ", 1)[1])
        self.url = reply.split(" ", 1)[1]
        self.feed = state.LiveFeed(PipeLink(self.conn), meta)
        self.feed.start()
        return self.url

    @property
    def observer(self):
        return self.feed

    def close(self, run_status: str = "completed") -> None:
        """Send what is left, tell the pages the run ended, and stop the server process (bounded waits)."""
        try:
            if self.feed is not None:
                self.feed.finish()
                self.conn.send_bytes(b"F" + run_status.encode())
                self.conn.send_bytes(b"C")
        except (OSError, EOFError, ValueError):
            pass  # the server process already went away
        self._end()

    def _end(self) -> None:
        if self.process is not None:
            self.process.join(timeout=10.0)
            if self.process.is_alive():
                self.process.terminate()
                self.process.join(timeout=5.0)
        if self.conn is not None:
            self.conn.close()
