"""Protocol faults on a link: frames dropped, corrupted, cut, delayed, reordered, duplicated; a babbling or a
silent line; CAN error frames. The transport layer of issue 24's fault seam (``docs/faults.md``).

- :class:`LinkFaults`: the fault engine, frames in and frames out, no port, no clock. Each frame passes the active
  faults of its direction in a fixed order; frames held back (a delay, a reorder) are released by
  :meth:`LinkFaults.advance` with the current time, sim time in the stand, wall time in the proxy.
- :class:`FaultyPort` wraps a serial port object (:class:`~drivers.serial_port.PipePort`,
  :class:`~drivers.serial_port.FdPort`, a ``serial.Serial``); :class:`FaultyBus` wraps a python-can bus. Each sits on
  one side of the link (``side="device"``: what is written or sent goes ``to_host``, what is read or received came
  ``to_device``; ``side="host"`` the other way round).
- :mod:`drivers.fault_proxy` runs the same engine between two real ports or two CAN channels.

With no fault active and nothing held, a wrapper hands every call straight to the wrapped object: the same bytes,
the same frames, in the same order, at the cost of one attribute test per call.

A frame is what one ``write()`` carries (every serial emulator and host of the project writes one whole frame per
call) or, for bytes read from a stream, what ``framing`` cuts out of it: ``"slip"`` (up to and including each
closing END byte), a :class:`~drivers.datagram.DatagramCodec` (identifier byte and fixed length), or None (each
chunk read is one frame). A CAN frame is one :class:`can.Message`.

Faults and their parameters (each also takes ``direction``: ``"to_host"``, ``"to_device"`` or ``"both"``, the
default). Randomness comes only from the ``numpy.random.Generator`` handed to :meth:`LinkFaults.start`, one draw
per frame and fault, so a run is reproducible from its seed and its traffic:

==============  ====================================================================================================
``drop``        ``rate``: probability per frame (0..1) that it is lost.
``burst_drop``  ``frames``: the next so many frames in each direction are lost, then the fault is spent.
``bit_error``   ``rate`` per frame, ``bits`` flipped at distinct random positions (serial: the receiver's CRC
                fires). On CAN the controllers' CRC fires: the frame is replaced by an error frame.
``truncate``    ``rate`` per frame, ``keep_fraction`` (0..1) of its bytes kept (CAN: of its data bytes).
``delay``       ``delay_s``: every frame arrives this much later (order kept).
``jitter``      ``max_s``: a uniform extra delay in [0, max_s) per frame; frames never overtake each other.
``reorder``     ``rate``: the frame is held and goes out after the next frame in its direction.
``duplicate``   ``rate``: the frame arrives twice.
``babble``      ``frames_per_s`` (at most 10000) of garbage: serial ``length`` random bytes or the fixed ``frame_hex``;
                CAN random data of ``length`` bytes (0..8) under the fixed ``frame_id`` or a random 11-bit one.
``silence``     nothing gets through.
``error_frame`` CAN only: ``rate`` per frame; an error frame goes on the bus before it (the frame itself is then
                retransmitted, as a controller does).
==============  ====================================================================================================

``counters``: ``dropped`` (drop, burst_drop), ``corrupted``, ``truncated``, ``delayed``, ``reordered``,
``duplicated``, ``babbled``, ``silenced``, ``error_frames``; each frame counted once per fault that acted on it.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

import compiled_paths

__all__ = ["CAN_KINDS", "COUNTERS", "DIRECTIONS", "KINDS", "PARAMETERS", "SERIAL_KINDS", "TO_DEVICE", "TO_HOST",
           "FaultyBus", "FaultyPort", "LinkFaults", "Splitter", "splitter_for"]

_draws = compiled_paths.load("numpy_draws")  # a draw per frame without the Generator's Python-facing layers

TO_HOST = "to_host"
TO_DEVICE = "to_device"
DIRECTIONS = (TO_HOST, TO_DEVICE, "both")
COUNTERS = ("dropped", "corrupted", "truncated", "delayed", "reordered", "duplicated", "babbled", "silenced",
            "error_frames")

#: kind -> {param: (default or None if required, check, what is allowed)}.
_RATE = (None, lambda v: 0.0 <= v <= 1.0, "a probability per frame from 0 to 1")
_FRACTION = (0.5, lambda v: 0.0 <= v < 1.0, "a fraction from 0 up to (not including) 1")
_DELAY = (None, lambda v: 0.0 <= v <= 3600.0, "seconds from 0 to 3600")
_PARAMS: dict[str, dict[str, tuple[Any, Callable[[float], bool], str]]] = {
    "drop": {"rate": _RATE},
    "burst_drop": {"frames": (None, lambda v: v == int(v) and 1 <= v <= 1_000_000, "a whole number from 1 to 1000000")},
    "bit_error": {"rate": _RATE, "bits": (1, lambda v: v == int(v) and 1 <= v <= 64, "a whole number from 1 to 64")},
    "truncate": {"rate": _RATE, "keep_fraction": _FRACTION},
    "delay": {"delay_s": _DELAY},
    "jitter": {"max_s": _DELAY},
    "reorder": {"rate": _RATE},
    "duplicate": {"rate": _RATE},
    "babble": {"frames_per_s": (None, lambda v: 0.0 < v <= 10000.0, "frames per second above 0, at most 10000"),
               "length": (None, lambda v: v == int(v) and 0 <= v <= 4096, "a whole number of bytes from 0 to 4096"),
               "frame_id": (None, lambda v: v == int(v) and 0 <= v <= 0x7FF, "an 11-bit CAN id, 0 to 2047")},
    "silence": {},
    "error_frame": {"rate": _RATE},
}
KINDS = tuple(_PARAMS)
#: kind -> {parameter: what is allowed} (besides ``direction``, every kind's; babble's ``frame_hex`` is serial only).
PARAMETERS: dict[str, dict[str, str]] = {k: {p: spec[2] for p, spec in v.items()} for k, v in _PARAMS.items()}
CAN_KINDS = KINDS
SERIAL_KINDS = tuple(k for k in KINDS if k != "error_frame")
#: Babble frames one advance() may emit at most (a long pause between calls does not become one huge flood).
MAX_BABBLE_PER_ADVANCE = 256


def _check_params(kind: str, params: dict, kinds: tuple[str, ...], medium: str) -> dict:
    """The parameters of one fault, defaults filled in; ValueError naming the parameter, its value and what is
    allowed."""
    if kind not in kinds:
        if kind in KINDS:
            raise ValueError(f"link fault kind = {kind!r} is not possible on a {medium} link; allowed there: "
                             f"{', '.join(kinds)}.")
        raise ValueError(f"link fault kind = {kind!r} is unknown; allowed: {', '.join(kinds)}.")
    if not isinstance(params, dict):
        raise ValueError(f"{kind} params = {params!r} is not allowed; allowed: a dict of parameters.")
    spec = _PARAMS[kind]
    out: dict[str, Any] = {}
    for name, value in params.items():
        if name == "direction":
            if value not in DIRECTIONS:
                raise ValueError(f"{kind} direction = {value!r} is not allowed; allowed: {', '.join(DIRECTIONS)}.")
            continue
        if kind == "babble" and name == "frame_hex":
            out[name] = _hex_frame(value)
            continue
        if name not in spec:
            allowed = ", ".join([*spec, "direction"] + (["frame_hex"] if kind == "babble" else []))
            raise ValueError(f"{kind} has no parameter {name!r}; allowed: {allowed}.")
        _default, check, text = spec[name]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                or not check(value):
            raise ValueError(f"{kind} {name} = {value!r} is not allowed; allowed: {text}.")
        out[name] = value
    for name, (default, _check, text) in spec.items():
        if name not in out:
            if default is None and not (kind == "babble" and name in ("length", "frame_id")):
                raise ValueError(f"{kind} needs the parameter {name} ({text}).")
            if default is not None:
                out[name] = default
    out["direction"] = params.get("direction", "both")
    if kind == "babble":
        _check_babble(out, medium)
    return out


def _check_babble(params: dict, medium: str) -> None:
    """What a babble frame can be depends on the medium: bytes on a line, an id and at most 8 data bytes on CAN."""
    if medium == "CAN":
        if "frame_hex" in params:
            raise ValueError("babble frame_hex is not allowed on a CAN link; allowed there: frame_id and length.")
        if params.get("length", 0) > 8:
            raise ValueError(f"babble length = {params['length']!r} is not allowed on a CAN link; allowed: 0 to 8 "
                             "data bytes.")
    elif "frame_id" in params:
        raise ValueError("babble frame_id is not allowed on a serial link; allowed there: length or frame_hex.")


def _hex_frame(value: Any) -> bytes:
    try:
        frame = bytes.fromhex(value)
    except (TypeError, ValueError):
        frame = b""
    if not frame:
        raise ValueError(f"babble frame_hex = {value!r} is not allowed; allowed: the bytes of one frame in hex, "
                         "e.g. 'C0 21 01 C0'.")
    return frame


class _Fault:
    __slots__ = ("directions", "emitted", "kind", "left", "params", "rng", "t0_s")

    def __init__(self, kind: str, params: dict, rng: np.random.Generator, t0_s: float) -> None:
        self.kind = kind
        self.params = params
        self.rng = rng
        self.t0_s = t0_s
        d = params["direction"]
        self.directions = (TO_HOST, TO_DEVICE) if d == "both" else (d,)
        self.left = dict.fromkeys(self.directions, int(params.get("frames", 0)))  # burst_drop
        self.emitted = dict.fromkeys(self.directions, 0)  # babble

    def applies(self, direction: str) -> bool:
        return direction in self.directions

    def hit(self) -> bool:
        """One draw of this fault's generator: True with probability ``rate``."""
        return _draws.random(self.rng) < self.params["rate"]


# -- what a fault does to one frame, by medium ---------------------------------------------------------------------


class _SerialFrames:
    """Faults on serial frames (bytes)."""

    medium = "serial"
    kinds = SERIAL_KINDS

    def __init__(self, slip: bool) -> None:
        self.slip = slip

    @staticmethod
    def corrupt(frame: bytes, fault: _Fault) -> Any:
        n_bits = len(frame) * 8
        if n_bits == 0:
            return frame
        k = min(int(fault.params["bits"]), n_bits)
        out = bytearray(frame)
        for bit in fault.rng.choice(n_bits, size=k, replace=False):
            out[int(bit) >> 3] ^= 0x80 >> (int(bit) & 7)
        return bytes(out)

    @staticmethod
    def truncate(frame: bytes, keep_fraction: float) -> Any:
        return frame[:int(len(frame) * keep_fraction)]

    def babble(self, fault: _Fault) -> Any:
        fixed = fault.params.get("frame_hex")
        if fixed is not None:
            return fixed
        length = int(fault.params.get("length", 16))
        return fault.rng.integers(0, 256, size=length, dtype=np.uint8).tobytes()

    @staticmethod
    def error_frame() -> Any:  # pragma: no cover - the kind is refused on a serial link
        raise AssertionError


class _CanFrames:
    """Faults on CAN frames (:class:`can.Message`); a changed frame is a new Message, the sender's is never edited."""

    medium = "CAN"
    kinds = CAN_KINDS

    @staticmethod
    def corrupt(frame: Any, fault: _Fault) -> Any:
        # The receiving controllers' CRC catches a flipped bit: the bus carries an error frame instead of the frame.
        return _CanFrames.error_frame()

    @staticmethod
    def truncate(frame: Any, keep_fraction: float) -> Any:
        import can

        data = bytes(frame.data)[:int(len(frame.data) * keep_fraction)]
        return can.Message(arbitration_id=frame.arbitration_id, data=data, is_extended_id=frame.is_extended_id,
                           is_remote_frame=frame.is_remote_frame, timestamp=frame.timestamp)

    @staticmethod
    def babble(fault: _Fault) -> Any:
        import can

        fid = fault.params.get("frame_id")
        frame_id = int(fault.rng.integers(0, 0x800)) if fid is None else int(fid)
        length = int(fault.params.get("length", 8))
        data = fault.rng.integers(0, 256, size=length, dtype=np.uint8).tobytes()
        return can.Message(arbitration_id=frame_id, data=data, is_extended_id=False)

    @staticmethod
    def error_frame() -> Any:
        import can

        return can.Message(is_error_frame=True, arbitration_id=0, data=b"", is_extended_id=False)


# -- the engine ----------------------------------------------------------------------------------------------------


class LinkFaults:
    """The faults active on one link and the frames they hold back; frames in, frames out (no port, no clock).

    Args:
        medium: ``"serial"`` or ``"can"``.
        slip: serial frames are SLIP frames (a babble frame is then sent between END bytes, as a frame of its own).

    :meth:`process` takes one frame going ``direction`` and returns what goes out now; :meth:`advance` moves the
    time on and returns ``(direction, frame)`` pairs due by then (delayed frames, babble). ``busy`` is False when no
    fault is active and nothing is held: a wrapper then hands frames straight through.
    """

    def __init__(self, medium: str = "serial", *, slip: bool = False) -> None:
        if medium not in ("serial", "can"):
            raise ValueError(f"LinkFaults medium = {medium!r} is not allowed; allowed: serial, can.")
        self._ops: Any = _SerialFrames(slip) if medium == "serial" else _CanFrames()
        self.counters: dict[str, int] = dict.fromkeys(COUNTERS, 0)
        self._faults: dict[int, _Fault] = {}
        self._next_handle = 1
        self.now_s = 0.0
        self._held: list[tuple[float, int, str, Any]] = []  # (release time, order, direction, frame)
        self._order = 0
        self._last_release = {TO_HOST: -math.inf, TO_DEVICE: -math.inf}
        self._n_held = {TO_HOST: 0, TO_DEVICE: 0}
        self._reorder_held: dict[str, list] = {TO_HOST: [], TO_DEVICE: []}
        self.busy = False

    # -- faults ------------------------------------------------------------------------------------------------

    def start(self, kind: str, params: dict, rng: np.random.Generator, t_s: float) -> int:
        """Start fault ``kind`` with ``params`` at time ``t_s``; returns its handle for :meth:`stop`. ValueError
        naming the parameter, its value and what is allowed."""
        checked = _check_params(kind, params, self._ops.kinds, self._ops.medium)
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"{kind} rng = {rng!r} is not allowed; allowed: a numpy.random.Generator.")
        handle = self._next_handle
        self._next_handle += 1
        self._faults[handle] = _Fault(kind, checked, rng, float(t_s))
        self.now_s = max(self.now_s, float(t_s))
        self.busy = True
        return handle

    def stop(self, handle: int) -> None:
        """End a fault; frames it holds for reordering go out at the next :meth:`advance`, delayed frames at their
        time. An unknown or already stopped handle is ignored."""
        fault = self._faults.pop(handle, None)
        if fault is not None and fault.kind == "reorder":
            for direction in fault.directions:
                if not any(f.kind == "reorder" and f.applies(direction) for f in self._faults.values()):
                    for frame in self._reorder_held[direction]:
                        self._hold(direction, frame, self.now_s)
                    self._reorder_held[direction] = []
        self._update_busy()

    @property
    def active(self) -> list[tuple[int, str, dict]]:
        """``(handle, kind, params)`` of every active fault."""
        return [(h, f.kind, dict(f.params)) for h, f in self._faults.items()]

    @property
    def in_flight(self) -> int:
        """Frames held for later release (delayed, or waiting to be reordered)."""
        return len(self._held) + len(self._reorder_held[TO_HOST]) + len(self._reorder_held[TO_DEVICE])

    def _update_busy(self) -> None:
        self.busy = bool(self._faults) or self.in_flight > 0

    # -- frames ------------------------------------------------------------------------------------------------

    def process(self, frame: Any, direction: str) -> list:
        """What goes out now of one ``frame`` going ``direction`` (``to_host`` or ``to_device``)."""
        faults = [f for f in self._faults.values() if f.applies(direction)]
        if not faults:
            if self._held_in(direction):  # frames never overtake the ones delayed before them
                self._hold(direction, frame, self.now_s)
                return []
            return [frame]
        out = self._lose_or_change(frame, faults, direction)
        if not out:
            return []
        out = self._reorder(out, direction, faults)
        if not out:
            return []
        delay_s = self._delay_s(faults)
        if delay_s > 0.0 or self._held_in(direction):
            if delay_s > 0.0:
                self.counters["delayed"] += len(out)
            for each in out:
                self._hold(direction, each, self.now_s + delay_s)
            return []
        return out

    def _lose_or_change(self, frame: Any, faults: list[_Fault], direction: str) -> list:
        c = self.counters
        ops = self._ops
        by_kind: dict[str, list[_Fault]] = {}
        for f in faults:
            by_kind.setdefault(f.kind, []).append(f)
        if "silence" in by_kind:
            c["silenced"] += 1
            return []
        for f in by_kind.get("burst_drop", ()):
            if f.left[direction] > 0:
                f.left[direction] -= 1
                c["dropped"] += 1
                return []
        for f in by_kind.get("drop", ()):
            if f.hit():
                c["dropped"] += 1
                return []
        before = []
        for f in by_kind.get("error_frame", ()):
            if f.hit():
                c["error_frames"] += 1
                before.append(ops.error_frame())
        for f in by_kind.get("bit_error", ()):
            if f.hit():
                c["corrupted"] += 1
                frame = ops.corrupt(frame, f)
        for f in by_kind.get("truncate", ()):
            if f.hit():
                c["truncated"] += 1
                frame = ops.truncate(frame, f.params["keep_fraction"])
        out = [*before, frame]
        for f in by_kind.get("duplicate", ()):
            if f.hit():
                c["duplicated"] += 1
                out.append(frame)
        return out

    def _reorder(self, out: list, direction: str, faults: list[_Fault]) -> list:
        held = self._reorder_held[direction]
        if held:
            self._reorder_held[direction] = []
            return out + held
        for f in faults:
            if f.kind == "reorder" and f.hit():
                self.counters["reordered"] += 1
                self._reorder_held[direction] = out
                return []
        return out

    @staticmethod
    def _delay_s(faults: list[_Fault]) -> float:
        delay_s = 0.0
        for f in faults:
            if f.kind == "delay":
                delay_s += f.params["delay_s"]
            elif f.kind == "jitter":
                delay_s += _draws.random(f.rng) * f.params["max_s"]
        return delay_s

    def _held_in(self, direction: str) -> bool:
        return self._n_held[direction] > 0

    def _hold(self, direction: str, frame: Any, release_s: float) -> None:
        # A serial line or a CAN controller's queue keeps its order: never before a frame held earlier.
        release_s = max(release_s, self._last_release[direction])
        self._last_release[direction] = release_s
        self._order += 1
        self._n_held[direction] += 1
        heapq.heappush(self._held, (release_s, self._order, direction, frame))
        self.busy = True

    def advance(self, t_s: float) -> list[tuple[str, Any]]:
        """Move the link's time to ``t_s``; returns ``(direction, frame)`` due by then, oldest first: delayed
        frames, then babble."""
        self.now_s = max(self.now_s, float(t_s))
        out: list[tuple[str, Any]] = []
        held = self._held
        while held and held[0][0] <= self.now_s:
            _t, _n, direction, frame = heapq.heappop(held)
            self._n_held[direction] -= 1
            if not self._n_held[direction]:
                self._last_release[direction] = -math.inf
            out.append((direction, frame))
        for f in self._faults.values():
            if f.kind == "babble":
                out += self._babble(f)
        self._update_busy()
        return out

    def _babble(self, f: _Fault) -> list[tuple[str, Any]]:
        due = math.floor((self.now_s - f.t0_s) * f.params["frames_per_s"] + 1e-9)
        out = []
        for direction in f.directions:
            n = due - f.emitted[direction]
            f.emitted[direction] = due
            for _ in range(min(max(n, 0), MAX_BABBLE_PER_ADVANCE)):
                frame = self._ops.babble(f)
                if self._ops.medium == "serial" and self._ops.slip and "frame_hex" not in f.params:
                    from drivers.framing import escape

                    frame = escape(frame)
                self.counters["babbled"] += 1
                out.append((direction, frame))
        return out


# -- framing of streams --------------------------------------------------------------------------------------------


class Splitter:
    """Cuts a byte stream into frames: :meth:`feed` returns the complete frames, the rest is kept.

    ``kind``: ``"slip"`` (a frame ends with an END byte after at least one other byte), ``"chunk"`` (each fed chunk
    is one frame), or a datagram codec's identifier -> length table (``lengths``, with its ``byte_order``).
    """

    def __init__(self, kind: str = "chunk", lengths: dict[int, int] | None = None, byte_order: str = "big") -> None:
        self.kind = kind
        self.lengths = lengths or {}
        self.byte_order = byte_order
        self._buf = bytearray()

    @property
    def pending(self) -> int:
        """Bytes kept for the next frame."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[bytes]:
        if self.kind == "chunk":
            return [bytes(data)] if data else []
        self._buf += data
        if self.kind == "slip":
            return self._slip()
        return self._datagrams()

    def _slip(self) -> list[bytes]:
        buf, out, start = self._buf, [], 0
        i = 0
        n = len(buf)
        while i < n:
            if buf[i] == 0xC0 and any(b != 0xC0 for b in buf[start:i]):
                out.append(bytes(buf[start:i + 1]))
                start = i + 1
            i += 1
        del buf[:start]
        return out

    def _datagrams(self) -> list[bytes]:
        from drivers.datagram import take_datagram

        buf, out = self._buf, []
        junk = bytearray()
        for _ in range(len(buf) + 1):  # bounded: each pass consumes at least one byte or stops
            consumed, datagram = take_datagram(buf, self.lengths, self.byte_order)
            if consumed == 0:
                break
            if datagram is None:
                junk += buf[:consumed]
            else:
                if junk:
                    out.append(bytes(junk))
                    junk.clear()
                out.append(datagram)
            del buf[:consumed]
        if junk:
            out.append(bytes(junk))
        return out


def splitter_for(framing: Any, direction: str | None = None) -> Splitter:
    """A :class:`Splitter` for ``framing``: None or ``"chunk"``, ``"slip"``, or a datagram codec (an object with
    ``by_id`` and ``byte_order``, e.g. :class:`drivers.gyro.codec.GyroCodec`), whose identifiers sent ``direction``
    (``to_host``, ``to_device``; None: all) start a datagram."""
    if framing is None or framing == "chunk":
        return Splitter("chunk")
    if framing == "slip":
        return Splitter("slip")
    if hasattr(framing, "by_id") and hasattr(framing, "byte_order"):
        ids = {TO_HOST: getattr(framing, "ids_to_host", None), TO_DEVICE: getattr(framing, "ids_to_device", None)}
        chosen = ids.get(direction) if direction is not None else None
        return Splitter("datagram", {i: s.length for i, s in framing.by_id.items() if chosen is None or i in chosen},
                        framing.byte_order)
    raise ValueError(f"framing = {framing!r} is not allowed; allowed: None, 'chunk', 'slip' or a datagram codec.")


# -- wrappers ------------------------------------------------------------------------------------------------------


def _sides(side: str) -> tuple[str, str]:
    """(direction of what this side writes, direction of what it reads)."""
    if side == "device":
        return TO_HOST, TO_DEVICE
    if side == "host":
        return TO_DEVICE, TO_HOST
    raise ValueError(f"side = {side!r} is not allowed; allowed: device, host.")


class _LinkFaultsFront:
    """What :class:`FaultyPort` and :class:`FaultyBus` share: the engine's start/stop/counters/in_flight."""

    _faults: LinkFaults

    def start(self, kind: str, params: dict, rng: np.random.Generator, t_s: float) -> int:
        """Start a fault (see the module docstring); returns its handle."""
        return self._faults.start(kind, params, rng, t_s)

    def stop(self, handle: int) -> None:
        """End the fault ``handle``."""
        self._faults.stop(handle)

    @property
    def counters(self) -> dict[str, int]:
        return self._faults.counters

    @property
    def in_flight(self) -> int:
        return self._faults.in_flight

    @property
    def faults(self) -> LinkFaults:
        return self._faults


class FaultyPort(_LinkFaultsFront):
    """A serial port object with protocol faults (module docstring); every other attribute is the wrapped port's.

    Args:
        port: the port to wrap (``read``, ``write``, ``in_waiting``; ``fileno``, ``timeout`` ... passed through).
        side: ``"device"`` (an emulator's port: writes go to the host) or ``"host"`` (a host driver's port).
        framing: how bytes read are cut into frames: None (each read chunk), ``"slip"`` or a datagram codec.
            Writes are taken as one frame each.

    Call :meth:`advance` with the current time while a fault is active (the stand's tick, in sim time): delayed
    frames and babble go out then. While a fault is active or frames are held the wrapper offers no ``fileno``, so
    :func:`drivers.serial_port.write_available` (the emulators' non-blocking write) goes through :meth:`write`.
    """

    _OWN = frozenset({"_port", "_faults", "_out_dir", "_in_dir", "_splitter", "_rx"})

    def __init__(self, port: Any, *, side: str = "device", framing: Any = None) -> None:
        object.__setattr__(self, "_port", port)
        out_dir, in_dir = _sides(side)
        object.__setattr__(self, "_out_dir", out_dir)
        object.__setattr__(self, "_in_dir", in_dir)
        object.__setattr__(self, "_faults", LinkFaults("serial", slip=framing == "slip"))
        object.__setattr__(self, "_splitter", splitter_for(framing, in_dir))
        object.__setattr__(self, "_rx", bytearray())  # bytes read from the port, after the faults, for the reader

    def __getattr__(self, name: str) -> Any:
        if name == "fileno" and self._faults.busy:
            # drivers.serial_port.write_available writes straight to a port's descriptor when it has one: while a
            # fault is active the port has none, so an emulator's writes come through write() and its faults.
            raise AttributeError("fileno")
        return getattr(self._port, name)

    def __setattr__(self, name: str, value: Any) -> None:
        if name in self._OWN:
            object.__setattr__(self, name, value)
        else:  # e.g. a host driver setting the port's timeout
            setattr(self._port, name, value)

    def __repr__(self) -> str:
        return f"FaultyPort({self._port!r})"

    @property
    def wrapped(self) -> Any:
        return self._port

    # -- writing -------------------------------------------------------------------------------------------------

    def write(self, data: bytes) -> int:
        link = self._faults
        if not link.busy:
            return self._port.write(data)
        for frame in link.process(bytes(data), self._out_dir):
            self._write_out(frame)
        return len(data)

    def _write_out(self, frame: bytes) -> None:
        from drivers.serial_port import write_available

        write_available(self._port, frame)  # a fault never makes the writer wait for the line

    # -- reading -------------------------------------------------------------------------------------------------

    def _pump(self, block: bool) -> None:
        """Read what the port holds, through the faults of the reading direction, into the reader's buffer."""
        port = self._port
        n = port.in_waiting
        data = port.read(n) if n else (port.read(1) if block else b"")
        if not data:
            return
        link = self._faults
        for frame in self._splitter.feed(data):
            for out in link.process(frame, self._in_dir):
                self._rx += out

    def _clean(self) -> bool:
        """No fault, nothing held, nothing read and not yet handed over: reads go straight to the port."""
        return not self._faults.busy and not self._rx and not self._splitter.pending

    @property
    def in_waiting(self) -> int:
        if self._clean():
            return self._port.in_waiting
        self._pump(False)
        return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        if self._clean():
            return self._port.read(size)
        if len(self._rx) < size:
            self._pump(not self._rx and getattr(self._port, "timeout", 0) != 0)
        out = bytes(self._rx[:size])
        del self._rx[:size]
        return out

    # -- time ----------------------------------------------------------------------------------------------------

    def advance(self, t_s: float) -> None:
        """Move the link's time to ``t_s``: frames due go out (written) or in (readable)."""
        for direction, frame in self._faults.advance(t_s):
            if direction == self._out_dir:
                self._write_out(frame)
            else:
                self._rx += frame


class FaultyBus(_LinkFaultsFront):
    """A python-can bus with protocol faults (module docstring); every other attribute is the wrapped bus's.

    ``send``/``send_data`` go ``to_host`` from a device's bus (``side="device"``), ``recv`` takes what came
    ``to_device``. While no fault is active and nothing is held, ``rx_ready`` and ``send_data`` are the wrapped
    bus's fast paths (the stand's in-process bus), so a node on it works exactly as on the bare bus.
    """

    _OWN = frozenset({"_bus", "_faults", "_out_dir", "_in_dir", "_rx", "_send_data"})

    def __init__(self, bus: Any, *, side: str = "device") -> None:
        object.__setattr__(self, "_bus", bus)
        out_dir, in_dir = _sides(side)
        object.__setattr__(self, "_out_dir", out_dir)
        object.__setattr__(self, "_in_dir", in_dir)
        object.__setattr__(self, "_faults", LinkFaults("can"))
        object.__setattr__(self, "_rx", deque())
        object.__setattr__(self, "_send_data", getattr(bus, "send_data", None))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._bus, name)

    def __setattr__(self, name: str, value: Any) -> None:
        if name in self._OWN:
            object.__setattr__(self, name, value)
        else:
            setattr(self._bus, name, value)

    def __repr__(self) -> str:
        return f"FaultyBus({self._bus!r})"

    @property
    def wrapped(self) -> Any:
        return self._bus

    @property
    def rx_ready(self) -> Any:
        """The wrapped bus's receive queue while the link is clean, else None (frames then come through recv)."""
        if self._faults.busy or self._rx:
            return None
        return getattr(self._bus, "rx_ready", None)

    def send(self, msg: Any, timeout: float | None = None) -> None:
        link = self._faults
        if not link.busy:
            self._bus.send(msg, timeout)
            return
        for frame in link.process(msg, self._out_dir):
            self._bus.send(frame, timeout)

    def send_data(self, frame_id: int, payload: bytes) -> None:
        """One data frame (the in-process bus's fast path while the link is clean)."""
        if not self._faults.busy and self._send_data is not None:
            self._send_data(frame_id, payload)
            return
        from drivers.can_bus import data_frame

        self.send(data_frame(frame_id, payload))

    def recv(self, timeout: float | None = None) -> Any:
        link = self._faults
        if not link.busy and not self._rx:
            return self._bus.recv(timeout)
        rx = self._rx
        for _ in range(4096):  # bounded: a flooded bus cannot hold the caller here
            if rx:
                break
            msg = self._bus.recv(timeout if not rx else 0.0)
            if msg is None:
                break
            rx.extend(link.process(msg, self._in_dir))
            timeout = 0.0
        return rx.popleft() if rx else None

    def advance(self, t_s: float) -> None:
        """Move the link's time to ``t_s``: frames due are sent (from this side) or made receivable."""
        for direction, frame in self._faults.advance(t_s):
            if direction == self._out_dir:
                self._bus.send(frame)
            else:
                self._rx.append(frame)
