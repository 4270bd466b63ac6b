"""The operator page's server: aiohttp on its own thread and event loop, so the run's loop never waits on it.

Routes: ``/`` the page; ``/assets/...`` its script and style (shipped in the wheel, nothing from the network);
``/api/meta`` the run's devices and epoch; ``/api/samples`` every sample so far (the decimated replay, or what a
live run has pushed); ``/api/stars`` the catalog; ``/api/events`` the event log; ``/ws`` a websocket on which a
live run pushes new samples, events and status; ``POST /api/control`` pause, resume or stop a live run;
``GET /api/faults`` the faults injected so far (from the event log), the scenario's own and the fault types;
``POST /api/faults`` inject or clear a fault in a live run (:meth:`ViewServer._faults_post`); ``/api/frame?device=NAME``
the newest detector frame of an image tracker in a live run (PNG, :mod:`stand.view.frames`).

Every request that names a host (browsers always do) must name one the server listens on: the address the
connection reached, ``localhost`` when that is a loopback address, the bound host as given, and the machine's
own name when bound to every interface; anything else is refused (403), so a page of another site whose name was
re-pointed at this machine (DNS rebinding) reads nothing and controls nothing. Control is accepted only from the
address the server is bound to, unless a token is configured; then only with the token (header
``X-Stand-Token``), from anywhere that can reach the server. Binding anywhere but 127.0.0.1 requires a token. A
control request (``/api/control`` and ``POST /api/faults``) must name the host, be JSON and, when the browser sends
an Origin, come from the page itself (``http://`` and the same host), so another site open in the operator's
browser cannot pause the run or inject a fault into it.

Every JSON the server sends is strict JSON (:func:`state.dumps`: NaN and infinities become null).
"""

from __future__ import annotations

import asyncio
import collections
import hmac
import ipaddress
import json
import logging
import math
import os
import socket
import threading
import time
from pathlib import Path

import numpy as np
from aiohttp import WSMsgType, web

from . import state

log = logging.getLogger(__name__)

ASSETS = Path(__file__).with_name("assets")
LOCAL = "127.0.0.1"
#: Longest wait for the server thread to bind (or fail to).
START_TIMEOUT_S = 10.0
#: ``/api/stars?mag=M``: the magnitude limits served (the catalog's faintest is Hp 9; nothing is brighter than
#: -2), rounded to this step, and how many distinct tables are kept (each about 1.2 MB at Hp 9).
STAR_MAG_RANGE = (-2.0, 9.0)
STAR_MAG_STEP = 0.1
STAR_CACHE_TABLES = 4
#: The server process of ``stand run --view`` tells the run it is alive (and how many pages are open) this often.
HEARTBEAT_S = 1.0
WILDCARD_HOSTS = ("0.0.0.0", "::", "")
#: In a run folder while ``stand run --view`` serves: the page's address and token, for ``stand fault`` (mode 0600,
#: removed when the run ends).
VIEW_URL_FILE = "view_url.json"


def _json(data, status: int = 200) -> web.Response:
    return web.Response(text=state.dumps(data), status=status, content_type="application/json")


def _loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host.split("%", 1)[0]).is_loopback
    except ValueError:
        return host.lower() == "localhost"


def _plain_address(address: str) -> str:
    """A socket's local address as a browser would write it in Host (no zone, IPv4 for an IPv4-mapped one)."""
    address = address.split("%", 1)[0].lower()
    try:
        mapped = ipaddress.ip_address(address)
    except ValueError:
        return address
    return str(mapped.ipv4_mapped) if mapped.version == 6 and mapped.ipv4_mapped else address


def _split_host(value: str) -> tuple[str, int | None]:
    """``Host`` header -> (lower-case name without brackets, port or None when absent)."""
    value = value.strip().lower()
    if value.startswith("["):
        name, _, rest = value[1:].partition("]")
        port = rest[1:] if rest.startswith(":") else ""
    else:
        name, _, port = value.rpartition(":") if value.count(":") == 1 else (value, "", "")
    try:
        return name, int(port) if port else None
    except ValueError:
        return name, -1


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
        self.frames: dict = {}  # a replay has no tracker frames (they are shown live only)

    def snapshot(self):
        return (state.replay_samples(self.run_dir, self.meta, self.max_samples, self.sky),
                state.read_events(self.run_dir))


class ViewServer:
    """Serve ``source`` (a :class:`ReplaySource` or a :class:`state.LiveFeed`) on ``host:port``."""

    def __init__(self, source, host: str = LOCAL, port: int = 0, token: str | None = None,
                 token_flag: str = "--view-token"):
        # token_flag: the option that gives the token in the command serving (stand run --view-token, stand view
        # --token), so the refusal names the flag the user can pass.
        if host != LOCAL and not token:
            raise ViewError(f"binding the view to {host!r} is not allowed without a token: pass {token_flag} or set "
                            "STAND_VIEW_TOKEN (anyone who can reach the page could otherwise stop the run); "
                            "127.0.0.1 needs none.")
        self.source, self.host, self.port, self.token = source, host, port, token
        self.sockets: set = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._runner: web.AppRunner | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._stars: collections.OrderedDict[float, bytes] = collections.OrderedDict()  # LRU
        self._own_names: set[str] | None = None
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
        log.info("operator page on %s (%s)", self.url, self.source.mode)
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
        text = state.dumps(message)
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
        app.router.add_get("/api/frame", self._frame)
        app.router.add_get("/ws", self._ws)
        app.router.add_post("/api/control", self._control)
        app.router.add_get("/api/faults", self._faults_get)
        app.router.add_post("/api/faults", self._faults_post)
        return app

    def host_refusal(self, request) -> str | None:
        """Why the request's Host header does not name this server (DNS rebinding), or None."""
        given = request.headers.get("Host")
        if given is None:
            return "the request names no host"
        sock = request.transport.get_extra_info("sockname") if request.transport is not None else None
        if not sock:
            return "the connection's local address is unknown"
        local, port = _plain_address(str(sock[0])), int(sock[1])
        names = {local} | ({self.host.lower()} if self.host not in WILDCARD_HOSTS else set())
        if _loopback(local):
            names |= {"localhost", "127.0.0.1", "::1"}
        if self.host in WILDCARD_HOSTS:
            if self._own_names is None:  # getfqdn may ask the DNS: once per server, not per request
                self._own_names = {socket.gethostname().lower(), socket.getfqdn().lower()}
            names |= self._own_names
        name, given_port = _split_host(given)
        if name in names and given_port in (port, None if port == 80 else port):
            return None
        return (f"Host {given!r} is not an address this view listens on (it answers as "
                f"{local if ':' not in local else '[' + local + ']'}:{port}"
                f"{' or localhost:' + str(port) if _loopback(local) else ''})")

    @web.middleware
    async def _headers(self, request, handler):
        if "Host" in request.headers:
            why = self.host_refusal(request)
            if why is not None:
                return _json({"error": why}, status=403)
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
        if (src.mode == "replay" or src.status == "finished") and path.is_file():
            try:
                summary = {k: v for k, v in json.loads(path.read_text()).items()
                           if k in ("pass", "status", "error", "criteria")}
            except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
                summary = None
        return _json({**src.meta, "mode": src.mode, "status": src.status, "summary": summary,
                      "run_dir": str(src.run_dir), "token_required": bool(self.token),
                      "mode_meaning": state.column_meaning(src.run_dir, "adcs_mode"),
                      "control_from": None if self.token else self.host})

    async def _samples(self, request):
        loop = asyncio.get_running_loop()
        samples, events = await loop.run_in_executor(None, self.source.snapshot)
        body = state.dumps({"samples": state.encode(samples) if samples else {}, "events": events,
                            "status": self.source.status})
        resp = web.Response(text=body, content_type="application/json")
        resp.enable_compression()
        return resp

    async def _stars_route(self, request):
        lo, hi = STAR_MAG_RANGE
        text = request.query.get("mag", "9")
        try:
            mag = float(text)
        except ValueError:
            mag = math.nan
        if not lo <= mag <= hi:  # NaN too
            return _json({"error": f"mag {text!r} is not allowed: an Hp magnitude limit from {lo:g} to {hi:g}."},
                         status=400)
        key = round(round(mag / STAR_MAG_STEP) * STAR_MAG_STEP, 3)
        body = self._stars.get(key)
        if body is None:
            loop = asyncio.get_running_loop()
            table = await loop.run_in_executor(None, state.star_table, self.source.meta, key)
            body = self._stars[key] = state.dumps(table).encode()
            while len(self._stars) > STAR_CACHE_TABLES:
                self._stars.popitem(last=False)
        self._stars.move_to_end(key)
        resp = web.Response(body=body, content_type="application/json")
        resp.enable_compression()
        return resp

    async def _events(self, request):
        return _json(state.read_events(self.source.run_dir))

    async def _frame(self, request):
        """``GET /api/frame?device=NAME[&seq=N]``: the newest detector frame of an image tracker, or frame ``N`` when it
        is among the last ``state.RECENT_FRAMES`` (PNG; its time and solution in the ``X-Stand-Frame`` header, JSON);
        400 without a device, 404 for a device that renders no image, no frame yet (a replay has none: frames are
        shown live only) or a frame number not kept."""
        name = request.query.get("device")
        if not name:
            return _json({"error": "device is missing: /api/frame?device=NAME, NAME a tracker whose source is "
                                   "image"}, status=400)
        rendering = [d["name"] for d in self.source.meta.get("devices", ())
                     if isinstance(d.get("image"), dict) and d["image"].get("renders")]
        if name not in rendering:
            return _json({"error": f"device {name[:100]!r} is not allowed: it is not a device of this run that renders "
                                   f"an image ({', '.join(rendering) or 'none does'})"}, status=404)
        latest = self.source.frames.get(name)
        if latest is None:
            why = "a replay has no frames (they are shown live only)" if self.source.mode == "replay" else \
                "it has sent no frame yet (frames are taken while a page is open)"
            return _json({"error": f"no frame of {name!r}: {why}"}, status=404)
        if "seq" in request.query:  # the frame the page was told of (the newest may have moved on meanwhile)
            text = request.query["seq"]
            latest = self.source.frame_numbered(name, int(text)) if text.isdigit() else None
            if latest is None:
                return _json({"error": f"seq {text[:20]!r} is not allowed: the number of one of the last "
                                       f"{state.RECENT_FRAMES} frames of {name!r} (the newest is "
                                       f"{self.source.frames[name][0]['seq']})"}, status=404)
        info, png = latest
        return web.Response(body=png, content_type="image/png", headers={"X-Stand-Frame": state.dumps(info)})

    async def _ws(self, request):
        ws = web.WebSocketResponse(heartbeat=20.0)
        await ws.prepare(request)
        self.sockets.add(ws)
        self.source.pages = len(self.sockets)
        try:
            await ws.send_str(state.dumps({"type": "status", "status": self.source.status}))
            for info, _ in list(self.source.frames.values()):  # the newest frame of each tracker, for a new page
                await ws.send_str(state.dumps({"type": "frame", **info}))
            async for msg in ws:
                if msg.type in (WSMsgType.ERROR, WSMsgType.CLOSE):
                    break
        finally:
            self.sockets.discard(ws)
            self.source.pages = len(self.sockets)
        return ws

    def control_refusal(self, request) -> str | None:
        """Why a control request is refused, or None."""
        host = self.host_refusal(request)
        if host is not None:
            return host
        if self.token:
            given = request.headers.get("X-Stand-Token", "")
            if not hmac.compare_digest(given.encode(), self.token.encode()):
                return "this view needs its token (X-Stand-Token) to control the run (pause, resume, stop, faults)"
        elif request.remote != self.host:
            return f"control is accepted only from {self.host}, the address the view is bound to"
        origin = request.headers.get("Origin")
        if origin is not None and origin.lower() != "http://" + request.headers["Host"].strip().lower():
            return f"control must come from the page itself (Origin {origin!r}, Host {request.headers['Host']!r})"
        if request.content_type != "application/json":
            return "control requests are JSON"
        return None

    def _refused(self, request, what: str):
        """The answer refusing a control request (409 on a replay, 403 as ``control_refusal`` says), or None."""
        if self.source.mode != "live":
            return _json({"error": f"a replay has no run to {what}"}, status=409)
        why = self.control_refusal(request)
        if why is None:
            return None
        log.info("a request to %s refused: %s", what, why)  # an operator's typo, or someone else knocking
        return _json({"error": why}, status=403)

    async def _control(self, request):
        refused = self._refused(request, "control")
        if refused is not None:
            return refused
        try:
            command = (await request.json()).get("command")
            status = self.source.request(command)
        except (ValueError, AttributeError) as exc:
            return _json({"error": str(exc)}, status=400)
        return _json({"status": status})

    async def _faults_get(self, request):
        src = self.source
        loop = asyncio.get_running_loop()
        if src.mode == "live":
            faults = await loop.run_in_executor(None, src.faults)
        else:
            faults = state.fault_list(await loop.run_in_executor(None, state.read_events, src.run_dir))
        return _json({"live": src.mode == "live", "status": src.status, "faults": faults,
                      "scheduled": src.meta.get("faults", []), "types": state.fault_types()})

    async def _faults_post(self, request):
        """``{"action": "inject", "fault": {a [[faults]] table}}`` or ``{"action": "clear", "name": NAME}``: 200
        ``{"action", "name"}`` once the run's fault schedule took it (it acts from the next tick); 400 a table the
        schedule refuses or a malformed request, 404 a clear of a fault it does not know, 409 a replay or a run
        that takes no (more) faults, 403 as for /api/control, 504 no answer from the run in time (one sentence in
        ``error`` each)."""
        refused = self._refused(request, "inject faults into")
        if refused is not None:
            return refused
        try:
            command = fault_command(await request.json())
        except ValueError as exc:  # invalid JSON too (json.JSONDecodeError is a ValueError)
            return _json({"error": str(exc)}, status=400)
        loop = asyncio.get_running_loop()
        answer = await loop.run_in_executor(None, self.source.fault, command)
        if not answer.get("ok"):
            return _json({"error": answer.get("error", "the run refused the fault command")},
                         status=int(answer.get("status", 400)))
        return _json({"action": command["action"], "name": answer["name"]})


def fault_command(body) -> dict:
    """A ``POST /api/faults`` body checked for shape (the fault table itself is the run's schedule's to judge)."""
    if not isinstance(body, dict):
        raise ValueError(f"a fault command is a JSON object, not {type(body).__name__}")
    action = body.get("action")
    if action == "inject":
        table = body.get("fault")
        if not isinstance(table, dict) or not table:
            raise ValueError(f"fault = {state.dumps(table)[:200]} is not allowed: inject needs \"fault\", a "
                             "non-empty object as a [[faults]] table (device, type, parameters, duration_s)")
        return {"action": "inject", "fault": table}
    if action == "clear":
        name = body.get("name")
        if not isinstance(name, str) or not name:
            raise ValueError(f"name = {state.dumps(name)[:200]} is not allowed: clear needs \"name\", the name "
                             "of an injected fault")
        return {"action": "clear", "name": name}
    raise ValueError(f"action = {state.dumps(action)[:200]} is not allowed: \"inject\" or \"clear\"")


class PipeLink:
    """The feed's end of the pipe to the server process (used from the feed's sender thread only)."""

    def __init__(self, conn):
        self.conn = conn

    def send(self, message) -> None:
        kind, data = message
        if kind == "status":
            self.conn.send_bytes(b"S" + data.encode())
        elif kind == "fault":
            self.conn.send_bytes(b"A" + state.dumps(data).encode())
        elif kind == "frame":  # an image tracker's frame: its header (JSON), a newline, its 8-bit pixels
            header, pixels = data
            self.conn.send_bytes(b"I" + state.dumps(header).encode() + b"\n" + pixels)
        else:
            self.conn.send_bytes(b"R" + np.ascontiguousarray(data, dtype="<f8").tobytes())

    def receive(self) -> list:
        out = []
        while self.conn.poll(0):
            out.append(self.conn.recv())
        return out


def serve_live(conn, run_dir: str, meta: dict, host: str, port: int, token: str | None) -> None:
    """The server process of ``stand run --view``. Messages on ``conn``: ``R`` + rows as float64 bytes, ``S`` + a
    status the run's side set by itself (a pause it released), ``A`` + the run's answer to a fault command (JSON),
    ``I`` + an image tracker's frame (its header as JSON, a newline, its 8-bit pixels),
    ``F`` + the run's status when it ended, ``V`` once its ``summary.json`` is written (the pages fetch the verdict),
    ``C`` to end the process (after the run's linger, :meth:`LiveSession.linger`); back go control commands
    (``"pause"``, ``"stop"``, None, ``("fault", payload)``) and, every ``HEARTBEAT_S`` until the run's end,
    ``{"pages": n}`` (the run's side releases a pause when these stop)."""
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
    try:
        _relay(conn, source, lambda: control({"pages": source.pages}), lambda: control({"summary": "shown"}))
    except (EOFError, OSError):
        pass
    finally:
        view.close(linger_s=0.5 if view.sockets else 0.0)


def _relay(conn, source, heartbeat, shown) -> None:
    """serve_live's loop: rows and statuses in, a heartbeat out every HEARTBEAT_S, until told to end; ``shown()``
    once the pages have the finished run's verdict (the run's side waits for it before it says the run ended)."""
    width = None
    beat = 0.0
    while True:
        # After the run's end nobody reads the heartbeats (the run only lingers): none are sent.
        if source.status != "finished" and time.monotonic() - beat >= HEARTBEAT_S:
            beat = time.monotonic()
            heartbeat()
        if not conn.poll(HEARTBEAT_S):
            if os.getppid() == 1:  # the run's process is gone
                return
            continue
        data = conn.recv_bytes()
        tag, data = data[:1], data[1:]
        if tag == b"F":
            source.finished(data.decode())
        elif tag == b"S":
            source.released(data.decode())
        elif tag == b"A":
            source.answered(json.loads(data))
        elif tag == b"V":
            source.summary_ready()
            shown()
        elif tag == b"I":
            _frame(source, data)
        elif tag == b"C":
            return
        else:
            if width is None:
                cols = source._schema()
                width = sum(int(c["width"]) for c in cols) if cols else None
            if width:
                source.ingest(np.frombuffer(data, dtype="<f8").reshape(-1, width))


def _frame(source, data: bytes) -> None:
    """An image tracker's frame from the pipe (header JSON, a newline, pixels) to the pages; one that cannot be read
    or encoded is left out, logged, and the page goes on."""
    header, _, pixels = data.partition(b"\n")
    try:
        source.frame(json.loads(header), pixels)
    except (ValueError, KeyError, TypeError) as exc:
        log.warning("a tracker frame was left out of the page: %s", exc)


def write_view_url(run_dir, url: str, host: str, token: str | None) -> Path:
    """``RUN_DIR/view_url.json``: where ``stand fault RUN_DIR`` finds the live page, ``{"url", "connect", "token",
    "pid"}`` (``connect``: the URL to reach it from this machine, 127.0.0.1 or ::1 when bound to every interface).
    Readable by the user only (it may hold the token): created 0600, written whole and renamed into place."""
    connect = url
    if host in WILDCARD_HOSTS:
        connect = url.replace(f"//{host}:", "//127.0.0.1:") if host != "::" else url.replace("//[::]:", "//[::1]:")
    path = Path(run_dir) / VIEW_URL_FILE
    tmp = path.with_name(f".{VIEW_URL_FILE}.{os.getpid()}")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_NOFOLLOW", 0), 0o600)
    try:
        try:
            os.fchmod(fd, 0o600)  # a file left by an earlier run may have had other bits
            os.write(fd, json.dumps({"url": url, "connect": connect, "token": token, "pid": os.getpid()}).encode())
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise
    return path


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
        self.url_file: Path | None = None
        self._finished = self._closed = False
        self.run_dir: Path | None = None

    @classmethod
    def from_args(cls, bind: str, token: str | None) -> LiveSession:
        host, port = parse_bind(bind)
        return cls(host, port, token)

    def start(self, sc, run_dir, duration_s: float | None = None) -> str:
        """Write ``view.json``, start the server process and the feed; returns the page's URL."""
        import multiprocessing

        self.run_dir = Path(run_dir)
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
        try:
            self.url_file = write_view_url(run_dir, self.url, self.host, self.token)
        except OSError as exc:  # the run has not started: end the server, say why in one sentence
            try:
                self.conn.send_bytes(b"C")
            except OSError:
                pass  # it went away already
            self._end()
            raise ViewError(f"the live page's address cannot be written into {Path(run_dir) / VIEW_URL_FILE} "
                            f"for `stand fault`: {exc.strerror or exc}.") from None
        self.feed = state.LiveFeed(PipeLink(self.conn), meta, events_path=Path(run_dir) / "events.jsonl")
        self.feed.start()
        return self.url

    @property
    def observer(self):
        return self.feed

    def finish(self, run_status: str = "completed") -> None:
        """The run ended: send what is left and tell the pages (the server goes on serving until :meth:`close`);
        ``stand fault`` is told there is no live run any more (``view_url.json`` goes). Idempotent."""
        if self._finished:
            return
        self._finished = True
        if self.url_file is not None:
            self.url_file.unlink(missing_ok=True)
            self.url_file = None
        try:
            if self.feed is not None:
                self.feed.finish()
                self.conn.send_bytes(b"F" + run_status.encode())
        except (OSError, EOFError, ValueError):
            pass  # the server process already went away

    def summary_ready(self, timeout_s: float = START_TIMEOUT_S) -> None:
        """``summary.json`` is written: the pages may show the verdict. Returns once the server has taken in the
        run's end and its summary (at most ``timeout_s``), so whatever the console says next (the verdict, that the
        page stays) is already what the page serves; a run whose drawing was left out gets here milliseconds after
        its last sample."""
        try:
            if self.feed is None:
                return
            self.conn.send_bytes(b"V")
            deadline = time.monotonic() + timeout_s
            while self.conn.poll(max(0.0, deadline - time.monotonic())):
                if self.conn.recv() == {"summary": "shown"}:  # heartbeats and late commands: dropped, the run is over
                    return
                if time.monotonic() >= deadline:
                    return
        except (OSError, EOFError, ValueError):
            pass  # the server process went away: nothing to wait for

    def linger(self, seconds: float | None, say=print) -> str:
        """Keep serving the finished run's page for ``seconds`` (None or infinity: until SIGINT or SIGTERM), saying
        on the console how to stop it; returns why serving ended (``"time"``, a signal's name, ``"server"`` when its
        process went away). Called from the main thread (it sets the two signals' handlers for the wait)."""
        import signal as signals

        if self.process is None or not self.process.is_alive():
            return "server"
        forever = seconds is None or math.isinf(seconds)
        if not forever and seconds <= 0:
            return "time"
        stop = threading.Event()
        why = ["time"]

        def on_signal(signum, frame):
            why[0] = signals.Signals(signum).name
            stop.set()

        old = {sig: signals.signal(sig, on_signal) for sig in (signals.SIGINT, signals.SIGTERM)}
        try:
            say(f"stand: the run has ended; its page stays at {self.url} "
                + ("until you press Ctrl-C (or send SIGTERM)" if forever else
                   f"for {seconds:g} s (--view-linger-s; Ctrl-C stops serving sooner)"), flush=True)
            deadline = math.inf if forever else time.monotonic() + seconds
            while not stop.is_set() and time.monotonic() < deadline:
                try:  # the server's heartbeats: read and dropped, so its pipe never fills
                    while self.conn.poll(min(0.25, max(0.0, deadline - time.monotonic()))):
                        self.conn.recv()
                except (EOFError, OSError):
                    return "server"
                if not self.process.is_alive():
                    return "server"
            return why[0]
        finally:
            for sig, handler in old.items():
                signals.signal(sig, handler)

    def close(self, run_status: str = "completed") -> None:
        """Send what is left, tell the pages the run ended, and stop the server process (bounded waits)."""
        self.finish(run_status)
        try:
            if self.feed is not None and not self._closed:
                self.conn.send_bytes(b"C")
        except (OSError, EOFError, ValueError):
            pass  # the server process already went away
        self._closed = True
        self._end()

    def _end(self) -> None:
        if self.url_file is not None:
            self.url_file.unlink(missing_ok=True)
        if self.process is not None:
            self.process.join(timeout=10.0)
            if self.process.is_alive():
                self.process.terminate()
                self.process.join(timeout=5.0)
        if self.conn is not None:
            self.conn.close()
