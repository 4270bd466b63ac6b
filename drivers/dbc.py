"""A fast codec for CAN messages defined in a DBC file.

cantools reads the DBC (once) and stays the reference; for every message whose signals are all
little-endian (Intel) integers without multiplexing, :class:`DbcCodec` builds a pure-Python bit
codec (one ``int.from_bytes``, then a shift, a mask, a sign extension and the DBC's scale and
offset per signal). It gives the same bytes and the same values as cantools, bit for bit (a
Hypothesis test checks every message), at a fraction of the cost: cantools' encode + decode is
about 20 us per message, and the stand's loop exchanges several frames every 0.1 s of sim time at
thousands of times real time. Anything the fast path does not cover (big-endian, multiplexed,
float or container messages) goes through cantools.

The fast path itself is one :class:`drivers.bitpack.Packer` per message, built when the DBC is loaded
(the message's shifts, masks, scales and ranges as C numbers where the install compiled ``drivers.bitpack``,
see ``compiled_paths``). It only takes the common case (numbers within range); anything else (enum names,
numpy scalars, missing or unknown signals, out-of-range values) goes to the descriptor loop
:meth:`DbcCodec._encode_general`, which is the reference and raises the errors. A message the packer does not
cover (over 8 bytes, a signal over 52 bits) goes through cantools.

Device codecs that run every tick take :meth:`DbcCodec.packer`: the same fast path on positional values in the
codec's own order (no dict per frame).

Conventions (the same as cantools with ``decode_choices=False``, ``scaling=True``):

- physical value = raw * scale + offset; raw = round((physical - offset) / scale), rounding half
  to even as Python's ``round`` (cantools' exact arithmetic, including its integer-scale path);
- enum (``VAL_``) signals decode to numbers; ``encode`` also accepts the enum's names;
- ``encode`` needs every signal of the message and refuses unknown ones; a value outside the
  DBC's ``[min|max]`` (with cantools' tolerance of 1e-6 LSB) or outside what the signal's bits can
  hold raises :class:`~drivers.errors.EncodeError` naming the signal, the value and the allowed
  range. Nothing wraps silently;
- ``decode`` refuses an unknown id or a payload whose length differs from the DBC's with a
  :class:`~drivers.errors.ProtocolError` that carries the frame in hex.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import compiled_paths
from drivers.bitpack import IDENTITY as _IDENTITY
from drivers.bitpack import LINEAR as _LINEAR
from drivers.bitpack import LINEAR_INT as _LINEAR_INT
from drivers.errors import EncodeError, ProtocolError, frame_hex

#: The bit packer: compiled where the install could (compiled_paths), the same to the bit.
_bitpack = compiled_paths.load("drivers.bitpack")

__all__ = ["DbcCodec"]

# Conversion kinds (drivers.bitpack's), chosen by the same rule as cantools' BaseConversion.factory.


def _is_integer(value: float) -> bool:
    return isinstance(value, int) or (isinstance(value, float) and value.is_integer())


class _Signal:
    """One little-endian integer signal, pre-computed for the fast path."""

    __slots__ = (
        "name",
        "start",
        "mask",
        "sign_bit",
        "kind",
        "scale",
        "offset",
        "lo",
        "hi",
        "raw_lo",
        "raw_hi",
        "choices",
        "choice_raw",
        "unit",
        "minimum",
        "maximum",
    )

    def __init__(self, sig: Any) -> None:
        self.name: str = sig.name
        self.start: int = sig.start
        self.mask: int = (1 << sig.length) - 1
        self.sign_bit: int = (1 << (sig.length - 1)) if sig.is_signed else 0
        scale, offset = sig.conversion.scale, sig.conversion.offset
        if scale == 1 and offset == 0:
            self.kind = _IDENTITY
            self.scale, self.offset = 1, 0
        elif _is_integer(scale) and _is_integer(offset):
            self.kind = _LINEAR_INT
            self.scale, self.offset = int(scale), int(offset)
        else:
            self.kind = _LINEAR
            self.scale, self.offset = scale, offset
        if sig.is_signed:
            self.raw_lo, self.raw_hi = -(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1
        else:
            self.raw_lo, self.raw_hi = 0, self.mask
        # What the bits can hold, in physical units (for a DBC that gives no [min|max]).
        ends = (self.raw_lo * self.scale + self.offset, self.raw_hi * self.scale + self.offset)
        self.minimum = sig.minimum if sig.minimum is not None else min(ends)
        self.maximum = sig.maximum if sig.maximum is not None else max(ends)
        tol = abs(self.scale) * 1e-6  # cantools' tolerance
        self.lo = self.minimum - tol
        self.hi = self.maximum + tol
        self.choices: dict[str, int] = {str(v): int(k) for k, v in (sig.choices or {}).items()}
        self.choice_raw = frozenset(self.choices.values())
        self.unit: str = f" {sig.unit}" if sig.unit else ""


class _Message:
    __slots__ = ("name", "frame_id", "length", "signals", "signal_names", "fast", "cantools_message", "packer",
                 "_packers")

    def __init__(self, msg: Any, fast: bool) -> None:
        self.name: str = msg.name
        self.frame_id: int = msg.frame_id
        self.length: int = msg.length
        self.cantools_message = msg
        self.signals: tuple[_Signal, ...] = tuple(_Signal(s) for s in msg.signals) if fast else ()
        self.signal_names: frozenset[str] = frozenset(s.name for s in msg.signals)
        #: The fast path in DBC order (values -> payload or None; payload -> values), None through cantools.
        self.packer = _packer(self, tuple(s.name for s in self.signals)) if fast else None
        self.fast = self.packer is not None
        self._packers: dict[tuple[str, ...], Any] = {}

    def packer_in(self, order: tuple[str, ...]) -> Any:
        """``_packer(self, order)``, made once per signal order: a packer holds nothing but this message's signals
        (fixed with the file version this message was compiled from), so every codec of the file shares it (each
        built its own: a twelfth of a scene's build)."""
        try:
            return self._packers[order]
        except KeyError:
            return self._packers.setdefault(order, _packer(self, order))


def _is_literal(x: Any) -> bool:
    """True for the numbers whose ``repr`` reads back as the same value and type."""
    return type(x) is int or (type(x) is float and math.isfinite(x))


def _fast_path_supported(msg: Any) -> bool:
    if msg.is_multiplexed() or getattr(msg, "is_container", False):
        return False
    return all(s.byte_order == "little_endian" and not s.is_float and s.length > 0
               and _is_literal(s.conversion.scale) and _is_literal(s.conversion.offset) for s in msg.signals)


def _packer(entry: _Message, order: tuple[str, ...]) -> Any:
    """The bit packer of ``entry``'s signals in ``order``, or None for a message beyond it (it goes through
    cantools)."""
    by_name = {sig.name: sig for sig in entry.signals}
    rows = tuple((sig.start, sig.mask.bit_length(), bool(sig.sign_bit), sig.kind, sig.scale, sig.offset, sig.lo,
                  sig.hi, sig.raw_lo, sig.raw_hi) for sig in (by_name[name] for name in order))
    try:
        return _bitpack.Packer(entry.length, rows)
    except ValueError:  # over 8 bytes, a signal over 52 bits, an integer scale over 1024
        return None


class MessagePacker:
    """One message's per-tick codec on positional values, for device codecs that run every tick.

    ``pack(*values)`` (physical values in DBC units, in ``order``) is the payload, or None where
    :meth:`DbcCodec.encode` must decide (anything but plain numbers within range; it raises the error naming the
    field); ``unpack(payload)`` of exactly ``length`` bytes is the tuple of physical values in ``order``.
    A message outside the fast path (big-endian, multiplexed, float signals, beyond the packer) goes through
    cantools.
    """

    __slots__ = ("name", "frame_id", "length", "order", "pack", "unpack")

    def __init__(self, codec: DbcCodec, entry: _Message, order: tuple[str, ...]) -> None:
        self.name, self.frame_id, self.length, self.order = entry.name, entry.frame_id, entry.length, order
        packer = entry.packer_in(order) if entry.fast else None
        if packer is not None:
            self.pack, self.unpack = packer.pack, packer.unpack
        else:
            self.pack = lambda *values: None  # noqa: E731 - DbcCodec.encode takes every case
            self.unpack = lambda data: tuple(codec.decode(entry.frame_id, data)[1][n] for n in order)  # noqa: E731



@functools.lru_cache(maxsize=32)
def _load(path: str, mtime_ns: int, size: int) -> tuple[Any, tuple[_Message, ...]]:
    """The parsed DBC file and its compiled messages, once per file version: a scenario with four wheels on one
    ICD, a campaign's cases and the scenario fuzzing read the same file again and again (about 10 ms to parse and
    2 ms to compile each time). Both are only read after this."""
    import cantools  # lazily: a stand without CAN devices never pays for it

    database = cantools.database.load_file(path, database_format="dbc")
    return database, tuple(_Message(msg, _fast_path_supported(msg)) for msg in database.messages)

class DbcCodec:
    """Encode and decode the messages of one DBC file.

    >>> codec = DbcCodec(fixture_path("devices/magnetorquer.dbc"))   # doctest: +SKIP
    >>> codec.encode("MTQ_MODE_CMD", {"mode": "DIPOLE", "reset_counters": 0, "seq": 7})
    (145, b'\\x01\\x07\\x00\\x00\\x00\\x00\\x00\\x00')
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        stat = self.path.stat()  # FileNotFoundError as it is
        try:
            self.database, messages = _load(str(self.path.resolve()), stat.st_mtime_ns, stat.st_size)
        except Exception as exc:  # cantools raises a variety of parse errors
            raise ValueError(f"Cannot load DBC file {self.path}: {type(exc).__name__}: {exc}") from exc
        self._by_name: dict[str, _Message] = {entry.name: entry for entry in messages}
        self._by_id: dict[int, _Message] = {entry.frame_id: entry for entry in messages}
        self.names: tuple[str, ...] = tuple(self._by_name)

    # -- look-ups -------------------------------------------------------------------------------

    def _message(self, name: str) -> _Message:
        try:
            return self._by_name[name]
        except KeyError:
            raise KeyError(
                f"Unknown message {name!r} in {self.path.name}; known: {', '.join(self.names)}."
            ) from None

    def frame_id(self, name: str) -> int:
        """The frame id of message ``name``."""
        return self._message(name).frame_id

    def name_of(self, frame_id: int) -> str | None:
        """The name of the message with ``frame_id``, or None."""
        entry = self._by_id.get(frame_id)
        return None if entry is None else entry.name

    def length(self, name: str) -> int:
        """The payload length in bytes of message ``name``."""
        return self._message(name).length

    def is_fast(self, name: str) -> bool:
        """True when message ``name`` is handled by the pure-Python fast path."""
        return self._message(name).fast

    def signal_names(self, name: str) -> tuple[str, ...]:
        """The signals of message ``name``, in DBC order."""
        return tuple(s.name for s in self._message(name).cantools_message.signals)

    def signal_range(self, name: str, signal: str) -> tuple[float, float]:
        """The physical ``(min, max)`` that ``encode`` accepts for one signal (DBC units)."""
        sig = self._message(name).cantools_message.get_signal_by_name(signal)
        s = _Signal(sig)
        return s.minimum, s.maximum

    def signal_scale(self, name: str, signal: str) -> float:
        """The physical value of one LSB of a signal (DBC units)."""
        return self._message(name).cantools_message.get_signal_by_name(signal).conversion.scale

    def choices(self, name: str, signal: str) -> dict[int, str]:
        """The ``VAL_`` table of one signal, raw value -> name (empty when there is none)."""
        sig = self._message(name).cantools_message.get_signal_by_name(signal)
        return {int(k): str(v) for k, v in (sig.choices or {}).items()}

    def senders(self, name: str) -> tuple[str, ...]:
        """The nodes that transmit message ``name``."""
        return tuple(self._message(name).cantools_message.senders)

    def cycle_time_s(self, name: str) -> float | None:
        """The DBC's ``GenMsgCycleTime`` of message ``name`` in seconds, or None."""
        ms = self._message(name).cantools_message.cycle_time
        return None if not ms else ms / 1000.0

    # -- encode ---------------------------------------------------------------------------------

    def packer(self, name: str, order: tuple[str, ...]) -> MessagePacker:
        """Message ``name``'s per-tick codec on positional values in ``order`` (every signal of the message, each
        once): see :class:`MessagePacker`."""
        entry = self._message(name)
        if sorted(order) != sorted(s.name for s in entry.cantools_message.signals):
            raise ValueError(f"{name}: order {order!r} must name each of {', '.join(self.signal_names(name))} once.")
        return MessagePacker(self, entry, tuple(order))

    def encode(self, name: str, values: Mapping[str, Any]) -> tuple[int, bytes]:
        """Encode ``values`` (physical, DBC units) as message ``name``: returns (frame id, payload).

        Raises :class:`~drivers.errors.EncodeError`, and nothing else, for anything it cannot encode."""
        entry = self._by_name.get(name) if isinstance(name, str) else None
        if entry is None:
            raise EncodeError(
                f"Unknown message {name!r} in {self.path.name}; known: {', '.join(self.names)}."
            )
        if type(values) is not dict and not isinstance(values, Mapping):  # a dict skips the slow ABC check
            raise EncodeError(f"Cannot encode {name}: values = {values!r} must be a mapping of signal name to value; "
                              f"the message has {', '.join(self.signal_names(name))}.")
        if not entry.fast:
            return entry.frame_id, self._encode_cantools(entry, values)
        try:
            payload = self._encode_fast(entry, values)
            if payload is None:
                payload = self._encode_general(entry, values)
        except EncodeError:
            raise
        except (TypeError, ValueError, ArithmeticError) as exc:  # an object no number check foresaw
            raise EncodeError(f"Cannot encode {name}: {type(exc).__name__}: {exc} (DBC {self.path.name}).") from None
        return entry.frame_id, payload

    @staticmethod
    def _encode_fast(entry: _Message, values: Mapping[str, Any]) -> bytes | None:
        """The packer's payload for every signal of ``entry`` given, or None for the descriptor loop to decide."""
        if len(values) != len(entry.signals):
            return None
        try:
            ordered = [values[sig.name] for sig in entry.signals]
        except KeyError:
            return None
        return entry.packer.pack(*ordered)

    def _encode_general(self, entry: _Message, values: Mapping[str, Any]) -> bytes:
        """The fast path as a loop over signal descriptors: every case, and every error."""
        word = 0
        for sig in entry.signals:
            try:
                value = values[sig.name]
            except KeyError:
                raise self._missing(entry, values) from None
            tv = type(value)
            if tv is not float and tv is not int and tv is not bool:
                value = self._coerce(entry, sig, value)
                if type(value) is str:
                    word |= (self._choice(entry, sig, value) & sig.mask) << sig.start
                    continue
            if sig.choice_raw and self._in_choices(sig, value):
                pass  # cantools skips the range check for values in the VAL_ table
            elif not sig.lo <= value <= sig.hi:  # also refuses NaN
                raise self._out_of_range(entry, sig, value)
            raw = self._raw_of(sig, value)
            if not sig.raw_lo <= raw <= sig.raw_hi:
                raise self._out_of_range(entry, sig, value)
            word |= (raw & sig.mask) << sig.start
        if len(values) != len(entry.signals):
            raise self._unknown_signals(entry, values)
        return word.to_bytes(entry.length, "little")

    @classmethod
    def _in_choices(cls, sig: _Signal, value: float) -> bool:
        try:
            return cls._raw_of(sig, value) in sig.choice_raw
        except (ValueError, OverflowError):  # NaN, infinity
            return False

    @staticmethod
    def _raw_of(sig: _Signal, value: float) -> int:
        """cantools' physical -> raw, for every conversion kind (used off the hot path too)."""
        if sig.kind == _IDENTITY:
            return round(value)
        if sig.kind == _LINEAR:
            return round((value - sig.offset) / sig.scale)
        raw = value - sig.offset  # cantools' integer-scale path: avoid a division when exact
        quotient, remainder = divmod(raw, sig.scale)
        return round(quotient if remainder == 0 else raw / sig.scale)

    def _coerce(self, entry: _Message, sig: _Signal, value: Any) -> Any:
        if isinstance(value, str):
            return value
        if isinstance(value, (int, float)):  # subclasses (numpy.float64 is a float)
            return float(value) if isinstance(value, float) else int(value)
        if hasattr(value, "__index__"):  # numpy integers (an array has the method but refuses)
            try:
                return int(value.__index__())
            except (TypeError, ValueError):
                pass
        if hasattr(value, "__float__") and not isinstance(value, complex):
            try:
                return float(value)
            except (TypeError, ValueError, ArithmeticError):
                pass
        raise EncodeError(
            f"Cannot encode {entry.name}.{sig.name} = {value!r}: expected a number"
            + (f" or one of {', '.join(sig.choices)}" if sig.choices else "")
            + f", got {type(value).__name__}."
        )

    def _choice(self, entry: _Message, sig: _Signal, value: str) -> int:
        try:
            return sig.choices[value]
        except KeyError:
            allowed = ", ".join(f"{k} ({v})" for k, v in sig.choices.items()) or "none (numbers only)"
            raise EncodeError(
                f"Cannot encode {entry.name}.{sig.name} = {value!r}: not a name in its value table; "
                f"allowed names: {allowed}."
            ) from None

    def _out_of_range(self, entry: _Message, sig: _Signal, value: Any) -> EncodeError:
        what = "is not a finite number" if isinstance(value, float) and not math.isfinite(value) else (
            "is out of range"
        )
        return EncodeError(
            f"Cannot encode {entry.name}.{sig.name} = {value!r}{sig.unit}: the value {what}; allowed "
            f"{sig.minimum}{sig.unit} to {sig.maximum}{sig.unit} (DBC {self.path.name})."
        )

    def _missing(self, entry: _Message, values: Mapping[str, Any]) -> EncodeError:
        names = self.signal_names(entry.name)
        missing = [s for s in names if s not in values]
        return EncodeError(
            f"Cannot encode {entry.name}: missing signal(s) {', '.join(missing)}; the message needs "
            f"all of {', '.join(names)}."
        )

    def _unknown_signals(self, entry: _Message, values: Mapping[str, Any]) -> EncodeError:
        unknown = [str(k) for k in values if k not in entry.signal_names]
        return EncodeError(
            f"Cannot encode {entry.name}: unknown signal(s) {', '.join(unknown)}; the message has "
            f"{', '.join(self.signal_names(entry.name))}."
        )

    def _encode_cantools(self, entry: _Message, values: Mapping[str, Any]) -> bytes:
        from cantools.database.errors import EncodeError as CantoolsEncodeError

        try:
            return bytes(entry.cantools_message.encode(dict(values), scaling=True, strict=True))
        except (CantoolsEncodeError, KeyError, ValueError, TypeError, ArithmeticError) as exc:
            raise EncodeError(f"Cannot encode {entry.name}: {exc} (DBC {self.path.name}).") from exc

    # -- decode ---------------------------------------------------------------------------------

    def decode(self, frame_id: int, data: bytes | bytearray) -> tuple[str, dict[str, int | float]]:
        """Decode one payload: returns (message name, {signal: physical value in DBC units})."""
        entry = self._by_id.get(frame_id)
        if entry is None:
            raise ProtocolError(
                f"unknown frame id 0x{frame_id:03X} for {self.path.name}",
                frame_hex=frame_hex(frame_id, data, extended=frame_id > 0x7FF),
                expected="one of " + ", ".join(f"0x{i:03X}" for i in self._by_id),
                computed=f"0x{frame_id:03X}",
            )
        if len(data) != entry.length:
            raise ProtocolError(
                f"wrong payload length for {entry.name}",
                frame_hex=frame_hex(frame_id, data),
                expected=f"{entry.length} bytes",
                computed=f"{len(data)} bytes",
            )
        if not entry.fast:
            return entry.name, self._decode_cantools(entry, data)
        return entry.name, dict(zip([sig.name for sig in entry.signals], entry.packer.unpack(data), strict=True))

    def _decode_cantools(self, entry: _Message, data: bytes | bytearray) -> dict[str, int | float]:
        try:
            decoded = entry.cantools_message.decode(
                bytes(data), decode_choices=False, scaling=True, allow_excess=False
            )
            return dict(decoded)
        except Exception as exc:  # cantools' DecodeError and bitstruct errors
            raise ProtocolError(
                f"cannot decode {entry.name}: {exc}", frame_hex=frame_hex(entry.frame_id, data)
            ) from exc
