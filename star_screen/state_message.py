"""Time-tagged attitude state for a display node: a small versioned binary message.

The sim PC sends state, not pixels (docs/architecture.md, "Stimulators"): a display PC renders
locally with its own catalog, bench geometry and vsync, so a message is ~200 bytes, lossless by
construction, and the frame it produces is bit-identical to the one the sim PC would render.

Layout, version 1, little-endian, no padding (``struct`` formats in brackets)::

    offset size  field
      0     4    magic            b"SSST" [4s]
      4     2    version          1 [H]
      6     2    flags            bit 0: omega_SN_S present, bit 1: sun_N, bit 2: moon_N [H]
      8     4    stream_id        chosen by the sender per run; a new id restarts sequencing [I]
     12     8    sequence         per stream, +1 per message [Q]
     20     8    sim_time_ns      sim time of the frame (its time tag), ns since the scenario epoch [q]
     28    32    epoch            the frame's instant as sim.time.Epoch fields:
                                  tai1, tai2 (split TAI Julian date, d) [dd], offset_ns [q], dut1_s [d]
     60    32    q_SN             tracker attitude, scalar-first, v_S = dcm(q_SN) @ v_N, N = GCRS [4d]
     92    24    v_sc_gcrs_m_s    spacecraft velocity relative to the Earth, GCRS, m/s (aberration) [3d]
    116   24*k   optional blocks in flag order: omega_SN_S (rad/s, S frame; smear),
                 sun_N and moon_N (unit vectors from the spacecraft, GCRS)           [3d each]
    end    4     crc32            zlib.crc32 of every byte before it [I]

The whole message is 120 bytes plus 24 per optional block. :func:`decode` refuses a wrong
magic, version, length, checksum, a non-unit quaternion or a non-finite number with a
:class:`StateMessageError` naming the field, the value and what is allowed.
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass

import numpy as np

from sim.time import Epoch

__all__ = ["MAGIC", "VERSION", "DisplayState", "StateMessageError", "encode", "decode", "message_size"]

MAGIC = b"SSST"
VERSION = 1
_HEAD = struct.Struct("<4sHHIQq ddqd 4d 3d")
_VEC = struct.Struct("<3d")
_CRC = struct.Struct("<I")
_OPTIONAL = ("omega_SN_S", "sun_N", "moon_N")  # flag bit i <-> _OPTIONAL[i]
_KNOWN_FLAGS = (1 << len(_OPTIONAL)) - 1
#: A quaternion further than this from unit norm is refused (it was not normalised by the sender).
Q_NORM_TOL = 1e-9
#: Sun/Moon directions must be unit vectors to this tolerance.
U_NORM_TOL = 1e-6


class StateMessageError(ValueError):
    """A datagram that is not a valid state message; ``field`` names what was wrong."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


@dataclass(frozen=True)
class DisplayState:
    """What a display node needs to render one frame (SI units; frames in the names)."""

    sequence: int
    sim_time_ns: int
    epoch: Epoch
    q_SN: tuple
    v_sc_gcrs_m_s: tuple = (0.0, 0.0, 0.0)
    omega_SN_S: tuple | None = None
    sun_N: tuple | None = None
    moon_N: tuple | None = None
    stream_id: int = 0


def message_size(flags: int) -> int:
    """Bytes of a version-1 message with these optional-block flags."""
    return _HEAD.size + _VEC.size * bin(flags & _KNOWN_FLAGS).count("1") + _CRC.size


def _vec(name: str, value, n: int) -> tuple:
    a = np.asarray(value, dtype=float).reshape(-1)
    if a.size != n or not np.all(np.isfinite(a)):
        raise StateMessageError(name, f"{name} = {value!r}; it must be {n} finite numbers.")
    return tuple(float(x) for x in a)


def encode(state: DisplayState) -> bytes:
    """The bytes of ``state`` (see the module docstring for the layout)."""
    for name, lo, hi, v in (
        ("sequence", 0, 2**64 - 1, state.sequence),
        ("stream_id", 0, 2**32 - 1, state.stream_id),
        ("sim_time_ns", -(2**63), 2**63 - 1, state.sim_time_ns),
        ("epoch.offset_ns", -(2**63), 2**63 - 1, state.epoch.offset_ns),
    ):
        if not isinstance(v, int | np.integer) or not lo <= int(v) <= hi:
            raise StateMessageError(name, f"{name} = {v!r}; it must be a whole number in [{lo}, {hi}].")
    q = _vec("q_SN", state.q_SN, 4)
    if abs(math.sqrt(sum(x * x for x in q)) - 1.0) > Q_NORM_TOL:
        raise StateMessageError("q_SN", f"q_SN = {q} has norm {math.sqrt(sum(x * x for x in q))!r}; "
                                f"it must be a unit quaternion (within {Q_NORM_TOL}).")
    v = _vec("v_sc_gcrs_m_s", state.v_sc_gcrs_m_s, 3)
    e = state.epoch
    ep = _vec("epoch", (e.tai1, e.tai2, e.dut1_s), 3)
    flags, blocks = 0, b""
    for bit, name in enumerate(_OPTIONAL):
        value = getattr(state, name)
        if value is not None:
            vec = _vec(name, value, 3)
            if name != "omega_SN_S" and abs(math.sqrt(sum(x * x for x in vec)) - 1.0) > U_NORM_TOL:
                raise StateMessageError(name, f"{name} = {vec} is not a unit vector (within {U_NORM_TOL}).")
            flags |= 1 << bit
            blocks += _VEC.pack(*vec)
    body = _HEAD.pack(MAGIC, VERSION, flags, int(state.stream_id), int(state.sequence), int(state.sim_time_ns),
                      ep[0], ep[1], int(e.offset_ns), ep[2], *q, *v) + blocks
    return body + _CRC.pack(zlib.crc32(body))


def decode(data: bytes) -> DisplayState:
    """Parse a message; raises :class:`StateMessageError` naming the first field that is wrong."""
    data = bytes(data)
    if len(data) < _HEAD.size + _CRC.size:
        raise StateMessageError("length", f"message length = {len(data)} bytes; a version-{VERSION} state "
                                f"message has at least {_HEAD.size + _CRC.size}.")
    magic, version, flags = struct.unpack_from("<4sHH", data)
    if magic != MAGIC:
        raise StateMessageError("magic", f"magic = {magic!r}; a state message starts with {MAGIC!r}.")
    if version != VERSION:
        raise StateMessageError("version", f"version = {version}; this node reads version {VERSION} only.")
    if flags & ~_KNOWN_FLAGS:
        raise StateMessageError("flags", f"flags = {flags:#06x}; only bits 0-{len(_OPTIONAL) - 1} "
                                f"({', '.join(_OPTIONAL)}) are defined.")
    want = message_size(flags)
    if len(data) != want:
        raise StateMessageError("length", f"message length = {len(data)} bytes; flags {flags:#06x} "
                                f"need exactly {want}.")
    (crc,) = _CRC.unpack_from(data, want - _CRC.size)
    computed = zlib.crc32(data[: want - _CRC.size])
    if crc != computed:
        raise StateMessageError("crc32", f"crc32 = {crc:#010x} but the bytes give {computed:#010x}; "
                                "the datagram is corrupt.")
    f = _HEAD.unpack_from(data)
    stream_id, sequence, t_ns, tai1, tai2, off_ns, dut1 = f[3:10]
    q, v = f[10:14], f[14:17]
    for name, vals in (("epoch", (tai1, tai2, dut1)), ("q_SN", q), ("v_sc_gcrs_m_s", v)):
        if not all(math.isfinite(x) for x in vals):
            raise StateMessageError(name, f"{name} = {vals}; every number must be finite.")
    norm = math.sqrt(sum(x * x for x in q))
    if abs(norm - 1.0) > Q_NORM_TOL:
        raise StateMessageError("q_SN", f"q_SN = {q} has norm {norm!r}; it must be a unit quaternion "
                                f"(within {Q_NORM_TOL}).")
    opt = {}
    pos = _HEAD.size
    for bit, name in enumerate(_OPTIONAL):
        if flags & (1 << bit):
            vec = _VEC.unpack_from(data, pos)
            pos += _VEC.size
            if not all(math.isfinite(x) for x in vec):
                raise StateMessageError(name, f"{name} = {vec}; every number must be finite.")
            if name != "omega_SN_S" and abs(math.sqrt(sum(x * x for x in vec)) - 1.0) > U_NORM_TOL:
                raise StateMessageError(name, f"{name} = {vec} is not a unit vector (within {U_NORM_TOL}).")
            opt[name] = vec
    return DisplayState(sequence, t_ns, Epoch(tai1, tai2, off_ns, dut1), q, v, stream_id=stream_id, **opt)
