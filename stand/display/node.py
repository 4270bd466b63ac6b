"""The display node: a screen PC that receives time-tagged attitude state over UDP and renders locally.

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

The shared key: :mod:`stand.display.keys`.
"""

from __future__ import annotations

import ipaddress
import socket
import time
from collections import deque
from dataclasses import dataclass, field

from star_screen.state_message import DisplayState, StateMessageError, decode

from .keys import check_key

#: A UDP datagram can never be longer; a state message is far shorter.
_MAX_DATAGRAM = 65_535
#: Datagrams read in one drain before rendering; bounds the work per frame under a flood.
_MAX_DRAIN = 4_096
#: Senders a node accepts unless told otherwise.
LOOPBACK = ("127.0.0.0/8", "::1/128")


def parse_hostport(text: str, field: str = "--bind") -> tuple[str, int]:
    host, sep, port = str(text).rpartition(":")
    try:
        port_i = int(port)
    except ValueError:
        port_i = -1
    if not sep or not host or not 0 <= port_i <= 65535:
        raise ValueError(f"{field} {text!r} is not HOST:PORT; write it like 127.0.0.1:5600 (port 0 to 65535).")
    return host, port_i


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
        if not (isinstance(stream_hold_s, int | float) and 0 <= stream_hold_s < 3600):
            raise ValueError(f"stream_hold_s = {stream_hold_s!r}; allowed 0 to 3600 s.")
        self.allow = _networks(allow)
        self.key = check_key(key)
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
