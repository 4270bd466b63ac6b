"""Display node: a screen PC that receives time-tagged attitude state over UDP and renders locally.

The sim PC sends state, not pixels (``star_screen.state_message``: ~120-190 bytes per frame); each
display PC renders with its own catalog, bench geometry and vsync and hands the frame to its output
(a :class:`star_screen.window.ScreenWindow`, a :class:`star_screen.outputs.FrameQueue` for
emulators, or PNG files). UDP because the state of the newest frame is all that matters: a lost
datagram is replaced by the next one, and nothing queues behind a slow receiver.

Policy of :meth:`DisplayNode.serve`: every datagram waiting when the node is ready is read (at most
4096 per frame); nothing a datagram holds can stop the node. A datagram is refused, counted in
``NodeStats.errors`` under its kind and skipped when:

* its sender is not on the allow-list (``sender``; default: loopback only);
* it is not a valid state message (the field :func:`star_screen.state_message.decode` names:
  ``magic``, ``length``, ``crc32``, ``q_SN``, ``epoch``, ``v_sc_gcrs_m_s``, ``omega_SN_S``...; also
  counted as ``corrupt``), or, when the node has a shared key, lacks a valid HMAC (``hmac``);
* it starts a new ``stream_id`` while the current stream spoke less than ``stream_hold_s`` ago
  (``stream``: a second sender cannot take over a live screen; a restarted sender is adopted once
  the old stream has been quiet that long);
* its smear is longer than the renderer draws (``smear``), or rendering it fails in any other way
  (``render``; the exception is kept in ``last_error``).

A sequence number not above the newest one accepted from the same stream is dropped as
``duplicate`` or ``out_of_order`` (a late datagram must never move the sky backwards); of the rest
only the newest is rendered and the older ones count as ``superseded``. Every rendered frame
carries the state's ``sim_time_ns`` as its time tag.

The shared key (HMAC-SHA256, at least 16 bytes) comes from ``--key-file PATH`` (a file only its
owner can read) or the environment variable ``STAND_DISPLAY_KEY``, never from the command line,
where other users can read it in the process list.

    stand display-node --bind 127.0.0.1:PORT [--window [--display N] [--windowed] | --out DIR]
                       [--screen WxH] [--max-frames N] [--timeout S] [--aberration on|off]
                       [--allow ADDR[/PREFIX] | --allow any ...] [--key-file PATH]
                       [--collimator-focal-m F] [--collimator-distortion K1,K2,P1,P2,K3] [--axis-px X,Y]

The collimator and axis options pre-distort the frames for the bench's calibration
(``star_screen.calibration.calibrate_screen``); without them the nominal bench is drawn.

Exit codes: 0 after a normal stop (max frames, idle timeout, window closed), 2 for a usage error.
"""

from __future__ import annotations

import argparse
import ipaddress
import math
import os
import secrets
import socket
import stat
import sys
import time
from collections import deque
from dataclasses import asdict, dataclass, field

from sim.time import Epoch
from star_screen.state_message import MIN_KEY_BYTES, DisplayState, StateMessageError, decode, encode

__all__ = ["StateSender", "DisplayNode", "NodeStats", "DirectoryOutput", "KEY_ENV", "load_key", "register", "run"]

#: A UDP datagram can never be longer; a state message is far shorter.
_MAX_DATAGRAM = 65_535
#: Datagrams read in one drain before rendering; bounds the work per frame under a flood.
_MAX_DRAIN = 4_096
#: Environment variable holding the shared key of authenticated state messages.
KEY_ENV = "STAND_DISPLAY_KEY"
#: Senders a node accepts unless told otherwise.
LOOPBACK = ("127.0.0.0/8", "::1/128")


def load_key(key_file=None, environ=None) -> bytes | None:
    """The shared key: the contents of ``key_file`` (surrounding whitespace removed), else the
    environment variable :data:`KEY_ENV`, else None. Refuses a key shorter than 16 bytes and a key
    file that other users can read (ValueError naming the file or variable)."""
    environ = os.environ if environ is None else environ
    if key_file is not None:
        try:
            st = os.stat(key_file)
            with open(key_file, "rb") as f:
                key = f.read(4096).strip()
        except OSError as exc:
            raise ValueError(f"--key-file {key_file!r} cannot be read ({exc.strerror}).") from None
        if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
            raise ValueError(f"--key-file {key_file!r} can be read by other users (mode "
                             f"{stat.S_IMODE(st.st_mode):o}); make it private: chmod 600.")
        where = f"--key-file {key_file!r}"
    elif environ.get(KEY_ENV):
        key, where = environ[KEY_ENV].strip().encode(), f"{KEY_ENV}"
    else:
        return None
    if len(key) < MIN_KEY_BYTES:
        raise ValueError(f"{where} holds a key of {len(key)} bytes; a shared key needs at least {MIN_KEY_BYTES}.")
    return key


def _networks(allow) -> tuple | None:
    """``allow`` as ip networks; None (or "any" among them) accepts every sender."""
    if allow is None:
        return None
    nets = []
    for text in allow:
        if str(text).strip().lower() == "any":
            return None
        try:
            nets.append(ipaddress.ip_network(str(text).strip(), strict=False))
        except ValueError:
            raise ValueError(f"--allow {text!r} is not an address or network; write 192.0.2.7, 192.0.2.0/24, "
                             "::1 or any.") from None
    return tuple(nets)


class StateSender:
    """Sim side: sends one state datagram per frame to a display node at ``(host, port)``.

    ``scenario_epoch`` lets :meth:`send` derive each frame's instant from its sim time;
    ``stream_id`` (default random) tells the node that a restarted sender starts a new sequence;
    ``key`` (bytes, from :func:`load_key`) signs every message with HMAC-SHA256.

    A per-frame :meth:`send` never stops the sim: a state outside the message's physical ranges
    (a tumble faster than one turn per second, say) is not sent and counts in ``refused``, and a
    socket error (the node is down: ECONNREFUSED from an earlier datagram) counts in
    ``send_errors``; ``last_error`` keeps the newest sentence.
    """

    def __init__(self, host: str, port: int, *, scenario_epoch: Epoch | None = None, stream_id: int | None = None,
                 key: bytes | None = None):
        if not 0 < int(port) < 65536:
            raise ValueError(f"port = {port}; allowed 1 to 65535.")
        if key is not None and (not isinstance(key, bytes | bytearray) or len(key) < MIN_KEY_BYTES):
            raise ValueError(f"key must be bytes of at least {MIN_KEY_BYTES}; see load_key().")
        self.key = None if key is None else bytes(key)
        self.address = (str(host), int(port))
        self.scenario_epoch = scenario_epoch
        self.stream_id = secrets.randbits(32) if stream_id is None else int(stream_id)
        self.sequence = 0
        self.sent = 0
        self.refused = 0
        self.send_errors = 0
        self.last_error = ""
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.connect(self.address)

    def send(
        self,
        q_SN,
        sim_time_ns: int,
        *,
        epoch: Epoch | None = None,
        v_sc_gcrs_m_s=(0.0, 0.0, 0.0),
        omega_SN_S=None,
        sun_N=None,
        moon_N=None,
    ) -> DisplayState | None:
        """Send the state of the frame at ``sim_time_ns``; ``epoch`` is the frame's instant (default
        ``scenario_epoch + sim_time_ns``). Returns what was sent (with its sequence number), or None
        when the state was refused (counted, see the class docstring)."""
        if epoch is None:
            if self.scenario_epoch is None:
                raise ValueError("epoch = None and no scenario_epoch was given; pass one of them.")
            epoch = self.scenario_epoch.add_ns(int(sim_time_ns))
        state = DisplayState(self.sequence, int(sim_time_ns), epoch, tuple(float(x) for x in q_SN),
                             tuple(float(x) for x in v_sc_gcrs_m_s),
                             None if omega_SN_S is None else tuple(float(x) for x in omega_SN_S),
                             None if sun_N is None else tuple(float(x) for x in sun_N),
                             None if moon_N is None else tuple(float(x) for x in moon_N),
                             stream_id=self.stream_id)
        try:
            data = encode(state, self.key)
        except StateMessageError as exc:
            self.refused += 1
            self.last_error = str(exc)
            return None
        self.send_bytes(data)
        self.sequence += 1
        return state

    def send_state(self, state: DisplayState) -> int:
        """Send a prepared state as is (its own sequence and stream id); returns the bytes sent."""
        return self.send_bytes(encode(state, self.key))

    def send_bytes(self, data: bytes) -> int:
        """Send one datagram; a socket error is counted (``send_errors``), not raised: returns 0."""
        try:
            n = self._sock.send(data)
        except OSError as exc:
            self.send_errors += 1
            self.last_error = f"sending to {self.address[0]}:{self.address[1]} failed: {exc}"
            return 0
        self.sent += 1
        return n

    def close(self) -> None:
        self._sock.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


@dataclass
class NodeStats:
    """Counters of a display node (cumulative over :meth:`DisplayNode.serve` calls)."""

    received: int = 0
    corrupt: int = 0
    duplicate: int = 0
    out_of_order: int = 0
    superseded: int = 0
    rendered: int = 0
    stream_restarts: int = 0
    stop_reason: str = ""
    last_error: str = ""
    errors: dict = field(default_factory=dict)  #: refused datagrams by kind (see the module docstring)

    def count(self, kind: str, message: str) -> None:
        self.errors[kind] = self.errors.get(kind, 0) + 1
        self.last_error = message


@dataclass(frozen=True)
class NodeFrame:
    """Log record of one rendered frame: its state's sequence and time tag, and clock readings (ns)."""

    sequence: int
    sim_time_ns: int
    received_ns: int
    pushed_ns: int


class DirectoryOutput:
    """Writes each frame as ``DIR/NNNNNN/{screen.png, detector.png, truth.json}`` (debugging; slow)."""

    def __init__(self, out_dir, renderer):
        from pathlib import Path

        self.out = Path(out_dir)
        self.renderer = renderer
        self.count = 0

    def push(self, frame) -> None:
        from star_screen.outputs import write_frame

        if frame.time_tag_ns is None:
            raise ValueError("every frame handed to an output must carry time_tag_ns (sim time in ns).")
        write_frame(self.out / f"{self.count:06d}", frame, self.renderer)
        self.count += 1


class DisplayNode:
    """Screen side: receives state datagrams on ``bind`` and renders the newest into ``output``.

    ``output`` has ``push(frame)`` (ScreenWindow, FrameQueue, DirectoryOutput). ``detector``: also
    render the detector image (for emulators). ``copy=False`` hands out the renderer's persistent
    arrays (fine for a window, which shows them at once). ``clock`` (ns) stamps the log and times the
    stream hold. ``allow``: addresses or networks (``"192.0.2.0/24"``) whose datagrams are read
    (default loopback only; None or ``"any"``: every sender). ``key``: accept only messages signed
    with it. ``stream_hold_s``: how long the current stream must be silent before another
    ``stream_id`` is adopted.
    """

    def __init__(self, bind=("127.0.0.1", 0), renderer=None, output=None, *, detector: bool = False,
                 copy: bool = True, clock=time.monotonic_ns, log_length: int = 100_000, allow=LOOPBACK,
                 key: bytes | None = None, stream_hold_s: float = 0.5):
        if renderer is None or output is None:
            raise ValueError("a DisplayNode needs a renderer and an output (an object with push(frame)).")
        if key is not None and (not isinstance(key, bytes | bytearray) or len(key) < MIN_KEY_BYTES):
            raise ValueError(f"key must be bytes of at least {MIN_KEY_BYTES}; see load_key().")
        if not (isinstance(stream_hold_s, int | float) and 0 <= stream_hold_s < 3600):
            raise ValueError(f"stream_hold_s = {stream_hold_s!r}; allowed 0 to 3600 s.")
        self.allow = _networks(allow)
        self.key = None if key is None else bytes(key)
        self.stream_hold_ns = int(stream_hold_s * 1e9)
        self.renderer = renderer
        self.output = output
        self.detector = bool(detector)
        self.copy = bool(copy)
        self.clock = clock
        self.stats = NodeStats()
        self.log: deque[NodeFrame] = deque(maxlen=int(log_length))
        self._stream: int | None = None
        self._stream_heard_ns = 0
        self._last_seq = -1
        self._allowed_cache: dict = {}
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind((str(bind[0]), int(bind[1])))
        except OSError as exc:
            self._sock.close()
            raise ValueError(f"bind = {bind[0]}:{bind[1]} cannot be bound ({exc.strerror}); give a local "
                             "address and a free port (0 picks one).") from None
        self.address = self._sock.getsockname()

    # ------------------------------------------------------------------ receiving
    def _sender_allowed(self, addr) -> bool:
        if self.allow is None:
            return True
        host = addr[0] if isinstance(addr, tuple) else addr
        ok = self._allowed_cache.get(host)
        if ok is None:
            try:
                ip = ipaddress.ip_address(host)
            except ValueError:
                ok = False
            else:
                ok = any(ip in net for net in self.allow if net.version == ip.version)
            if len(self._allowed_cache) > 1024:  # a spoofing flood must not grow it without bound
                self._allowed_cache.clear()
            self._allowed_cache[host] = ok
        return ok

    def _accept(self, data: bytes, newest: DisplayState | None, addr=None) -> DisplayState | None:
        st = self.stats
        st.received += 1
        if addr is not None and not self._sender_allowed(addr):
            st.count("sender", f"datagram from {addr[0]}:{addr[1]} refused: the sender is not on the allow-list "
                     "(--allow).")
            return newest
        try:
            state = decode(data, self.key)
        except StateMessageError as exc:
            st.corrupt += 1
            st.count(exc.field, str(exc))
            return newest
        now = self.clock()
        if state.stream_id != self._stream:
            if self._stream is not None and now - self._stream_heard_ns < self.stream_hold_ns:
                st.count("stream", f"stream_id {state.stream_id} refused: stream {self._stream} is live (heard "
                         f"{(now - self._stream_heard_ns) / 1e9:.3g} s ago; another is adopted after "
                         f"{self.stream_hold_ns / 1e9:g} s of silence).")
                return newest
            if self._stream is not None:
                st.stream_restarts += 1
                if newest is not None:
                    st.superseded += 1
                    newest = None
            self._stream, self._last_seq = state.stream_id, -1
        self._stream_heard_ns = now
        if state.sequence <= self._last_seq:
            if state.sequence == self._last_seq:
                st.duplicate += 1
            else:
                st.out_of_order += 1
            return newest
        if newest is not None:
            st.superseded += 1
        self._last_seq = state.sequence
        return state

    def _drain(self, first: bytes, addr=None) -> DisplayState | None:
        newest = self._accept(first, None, addr)
        self._sock.setblocking(False)
        try:
            for _ in range(_MAX_DRAIN):
                try:
                    data, addr = self._sock.recvfrom(_MAX_DATAGRAM)
                except BlockingIOError:
                    break
                newest = self._accept(data, newest, addr)
        finally:
            self._sock.setblocking(True)
        return newest

    def render_state(self, state: DisplayState):
        """Render one state exactly as the node does (also what a local reference calls)."""
        frame = self.renderer.render(
            state.q_SN, state.epoch, v_sc_gcrs_m_s=state.v_sc_gcrs_m_s, omega_SN_S=state.omega_SN_S,
            time_tag_ns=state.sim_time_ns, detector=self.detector, copy=self.copy,
        )
        if state.sun_N is not None or state.moon_N is not None:
            frame.bodies = {**frame.bodies, "sender_u_N": {"sun": state.sun_N, "moon": state.moon_N}}
        return frame

    def _render_safely(self, state: DisplayState):
        """Render ``state``; a failure is counted (``smear`` or ``render``) and the frame skipped."""
        from star_screen.render import SmearTooLong

        try:
            return self.render_state(state)
        except SmearTooLong as exc:
            self.stats.count("smear", f"sequence {state.sequence} not rendered: {exc}")
        except Exception as exc:  # noqa: BLE001 - whatever a datagram holds, the node keeps serving
            self.stats.count("render", f"sequence {state.sequence} not rendered: {type(exc).__name__}: {exc}")
        return None

    def serve(self, max_frames: int | None = None, timeout_s: float | None = 5.0,
              duration_s: float | None = None) -> NodeStats:
        """Receive and render until ``max_frames`` frames were rendered in this call, no new state came
        for ``timeout_s`` seconds, ``duration_s`` passed, or the window asked to quit. ``None``
        removes that bound (a bench node runs with ``timeout_s=None`` until its window is closed)."""
        for name, v in (("max_frames", max_frames), ("timeout_s", timeout_s), ("duration_s", duration_s)):
            if v is not None and not v > 0:
                raise ValueError(f"{name} = {v}; give a positive number or None for no bound.")
        quit_requested = getattr(self.output, "quit_requested", None)
        end = None if duration_s is None else time.monotonic() + duration_s
        idle_end = None if timeout_s is None else time.monotonic() + timeout_s
        rendered = 0
        while max_frames is None or rendered < max_frames:
            now = time.monotonic()
            waits = [t - now for t in (end, idle_end) if t is not None]
            # Without any bound the node still wakes every 0.2 s to service the window.
            wait = min(waits) if waits else 0.2
            if waits and wait <= 0:
                self.stats.stop_reason = "duration" if end is not None and now >= end else "timeout"
                return self.stats
            self._sock.settimeout(min(wait, 0.2) if quit_requested is not None else wait)
            try:
                data, addr = self._sock.recvfrom(_MAX_DATAGRAM)
            except TimeoutError:
                if quit_requested is not None and quit_requested():
                    self.stats.stop_reason = "window closed"
                    return self.stats
                continue
            except OSError as exc:  # e.g. an ICMP error reported on the socket: never fatal
                self.stats.count("socket", f"receive failed: {exc}")
                continue
            received_ns = self.clock()
            state = self._drain(data, addr)
            if state is None:
                continue
            frame = self._render_safely(state)
            if frame is None:
                continue
            self.output.push(frame)
            self.log.append(NodeFrame(state.sequence, state.sim_time_ns, received_ns, self.clock()))
            self.stats.rendered += 1
            rendered += 1
            if timeout_s is not None:
                idle_end = time.monotonic() + timeout_s
            if quit_requested is not None and quit_requested():
                self.stats.stop_reason = "window closed"
                return self.stats
        self.stats.stop_reason = "max_frames"
        return self.stats

    def close(self) -> None:
        self._sock.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# ---------------------------------------------------------------------- command line
def _fail(message: str) -> int:
    print(f"stand: error: {message}", file=sys.stderr)
    return 2


def parse_hostport(text: str, field: str = "--bind") -> tuple[str, int]:
    host, sep, port = str(text).rpartition(":")
    try:
        port_i = int(port)
    except ValueError:
        port_i = -1
    if not sep or not host or not 0 <= port_i <= 65535:
        raise ValueError(f"{field} {text!r} is not HOST:PORT; write it like 127.0.0.1:5600 (port 0 to 65535).")
    return host, port_i


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "display-node",
        help="receive attitude state over UDP and render the star screen locally (window, PNG or memory)",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("--bind", required=True, help="HOST:PORT to listen on, e.g. 127.0.0.1:5600")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--window", action="store_true", help="show frames in a fullscreen window (display extra)")
    where.add_argument("--out", help="write every frame as PNG + truth.json into this directory (slow)")
    p.add_argument("--display", type=int, default=0, help="monitor index for --window (default 0)")
    p.add_argument("--windowed", action="store_true", help="with --window: a plain window, not fullscreen")
    p.add_argument("--no-corner-code", action="store_true", help="with --window: do not draw the frame counter")
    p.add_argument("--screen", default="1920x1080", help="screen resolution WxH (default 1920x1080)")
    p.add_argument("--aberration", choices=("on", "off"), default="on", help="apparent places (default) or not")
    cal = p.add_argument_group("pre-distortion: the bench's ChArUco calibration (star_screen.calibration)")
    cal.add_argument("--collimator-focal-m", type=float, default=None, help="calibrated collimator focal length, m")
    cal.add_argument("--collimator-distortion", default=None, metavar="K1,K2,P1,P2,K3",
                     help="calibrated collimator distortion (OpenCV's 5 terms)")
    cal.add_argument("--axis-px", default=None, metavar="X,Y", help="screen pixel on the collimator axis")
    p.add_argument("--max-frames", type=int, default=None, help="stop after N rendered frames")
    p.add_argument("--timeout", type=float, default=None,
                   help="stop after S seconds without a new state (default: run until stopped)")
    p.add_argument("--allow", action="append", default=None, metavar="ADDR[/PREFIX]",
                   help="accept state from this address or network (repeatable; 'any' for every sender; "
                        "default: loopback only)")
    p.add_argument("--key-file", default=None,
                   help=f"accept only state signed with the key in this file (owner-readable only); "
                        f"or set {KEY_ENV}")
    p.set_defaults(func=run)
    return p


def _numbers(text, flag: str, n: int) -> list[float]:
    try:
        values = [float(v) for v in str(text).split(",")]
    except ValueError:
        values = []
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{flag} {text!r} is not {n} numbers separated by commas.")
    return values


def _calibrated(bench, args):
    """The bench with the calibration the command line gives (collimator and axis), so frames are pre-distorted."""
    import dataclasses

    from star_screen.geometry import BrownConrady, Collimator

    focal = getattr(args, "collimator_focal_m", None)
    dist = getattr(args, "collimator_distortion", None)
    axis = getattr(args, "axis_px", None)
    if focal is not None and not (math.isfinite(focal) and 0.05 <= focal <= 20.0):
        raise ValueError(f"--collimator-focal-m {focal!r} is not allowed; give 0.05 to 20 m.")
    col = bench.collimator
    if focal is not None or dist is not None:
        k = BrownConrady(*_numbers(dist, "--collimator-distortion", 5)) if dist is not None else col.distortion
        col = Collimator(col.focal_length_m if focal is None else focal, k)
    sx0, sy0 = (bench.sx0, bench.sy0) if axis is None else _numbers(axis, "--axis-px", 2)
    return dataclasses.replace(bench, collimator=col, sx0=sx0, sy0=sy0)


def run(args) -> int:
    try:
        host, port = parse_hostport(args.bind)
        w_txt, _, h_txt = str(args.screen).lower().partition("x")
        try:
            width, height = int(w_txt), int(h_txt)
        except ValueError:
            raise ValueError(f"--screen {args.screen!r} is not a resolution; write it as WIDTHxHEIGHT, "
                             "e.g. 1920x1080.") from None
        if args.max_frames is not None and args.max_frames < 1:
            raise ValueError(f"--max-frames {args.max_frames}; give a whole number >= 1.")
        if args.timeout is not None and not args.timeout > 0:
            raise ValueError(f"--timeout {args.timeout}; give a positive number of seconds.")
        from star_screen.geometry import default_bench
        from star_screen.outputs import FrameQueue
        from star_screen.render import Renderer

        bench = _calibrated(default_bench(width, height), args)
        problems = bench.check_fits()
        if problems:
            raise ValueError(f"--screen {args.screen}: the default tracker field does not fit: " + "; ".join(problems))
        renderer = Renderer(bench, aberration=(args.aberration == "on"))
        if args.window:
            from star_screen.window import ScreenWindow

            output = ScreenWindow((width, height), display=args.display, fullscreen=not args.windowed,
                                  corner_code=not args.no_corner_code, clock=time.monotonic_ns)
        elif args.out:
            output = DirectoryOutput(args.out, renderer)
        else:
            output = FrameQueue(1)
        key = load_key(getattr(args, "key_file", None))
        allow = getattr(args, "allow", None) or LOOPBACK
        node = DisplayNode((host, port), renderer, output, copy=not args.window, allow=allow, key=key)
    except (ValueError, RuntimeError) as exc:
        return _fail(str(exc))
    print(f"display node listening on {node.address[0]}:{node.address[1]} (UDP)", file=sys.stderr)
    try:
        with node:
            stats = node.serve(max_frames=args.max_frames, timeout_s=args.timeout)
    except KeyboardInterrupt:
        stats = node.stats
        stats.stop_reason = "interrupted"
    finally:
        close = getattr(output, "close", None)
        if close is not None:
            close()
    counts = {k: v for k, v in asdict(stats).items() if k not in ("last_error", "errors")}
    errors = " ".join(f"{k}={v}" for k, v in sorted(stats.errors.items())) or "none"
    print("display node stopped: " + ", ".join(f"{k} {v}" for k, v in counts.items()) + f"; refused: {errors}")
    if stats.last_error:
        print(f"last refused datagram: {stats.last_error}", file=sys.stderr)
    return 0
