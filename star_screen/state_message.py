"""Time-tagged attitude state for a display node: a small versioned binary message.

The sim PC sends state, not pixels (docs/architecture.md, "Stimulators"): a display PC renders
locally with its own catalog, bench geometry and vsync, so a message is ~200 bytes, lossless by
construction, and the frame it produces is bit-identical to the one the sim PC would render.

Layout, version 1, little-endian, no padding (``struct`` formats in brackets)::

    offset size  field
      0     4    magic            b"SSST" [4s]
      4     2    version          1 [H]
      6     2    flags            bit 0: omega_SN_S present, bit 1: sun_N, bit 2: moon_N,
                                  bit 3: hmac trailer [H]
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
    +4    32     hmac (flag bit 3 only): HMAC-SHA256 of every byte before it, under a shared key [32s]

The whole message is 120 bytes plus 24 per optional block, plus 32 when it is authenticated. Flag
bit 3 is an addition within version 1: a message without it is byte for byte what it was.

:func:`decode` refuses, with a :class:`StateMessageError` whose ``field`` names what was wrong (the
message also gives the value and what is allowed):

* a wrong magic, version, flags, length or checksum;
* a non-finite number anywhere, a non-unit quaternion or Sun/Moon direction;
* values outside what the renderer can draw truthfully (physical ranges, see the constants):
  the instant outside 1900-2100 (the range of ``sim.time``, the ephemerides and the catalog's
  proper-motion propagation) or a split date whose parts exceed ``MAX_SPLIT_DAYS`` (digits lost),
  ``|dut1_s| > 1 s``, a speed at or above ``MAX_SPEED_M_S`` (far below c: beyond it no spacecraft
  flies, and at c aberration has no answer), an angular rate above ``MAX_RATE_RAD_S``;
* with a ``key``: a message without the HMAC trailer, or whose tag does not match (``hmac``).
"""

from __future__ import annotations

import hashlib
import hmac
import math
import struct
import zlib
from dataclasses import dataclass

import numpy as np

from sim.time import Epoch

__all__ = [
    "MAGIC",
    "MAX_RATE_RAD_S",
    "MAX_SPEED_M_S",
    "MAX_SPLIT_DAYS",
    "VERSION",
    "DisplayState",
    "StateMessageError",
    "decode",
    "encode",
    "message_size",
]

MAGIC = b"SSST"
VERSION = 1
_HEAD = struct.Struct("<4sHHIQq ddqd 4d 3d")
_VEC = struct.Struct("<3d")
_CRC = struct.Struct("<I")
_OPTIONAL = ("omega_SN_S", "sun_N", "moon_N")  # flag bit i <-> _OPTIONAL[i]
_BLOCK_FLAGS = (1 << len(_OPTIONAL)) - 1
#: Flag bit of the HMAC-SHA256 trailer.
FLAG_HMAC = 1 << len(_OPTIONAL)
_KNOWN_FLAGS = _BLOCK_FLAGS | FLAG_HMAC
_TAG = hashlib.sha256().digest_size
#: A quaternion further than this from unit norm is refused (it was not normalised by the sender).
Q_NORM_TOL = 1e-9
#: Sun/Moon directions must be unit vectors to this tolerance.
U_NORM_TOL = 1e-6
#: Speed of the spacecraft relative to the Earth above which a state is refused (m/s): 300 km/s,
#: above any spacecraft's (the fastest, Parker Solar Probe, peaks near 190 km/s around the Sun) and
#: 1/1000 of c, where the aberration formula is still exact.
MAX_SPEED_M_S = 3.0e5
#: Angular rate above which a state is refused (rad/s): one turn per second. A tracker has long lost
#: its stars (they smear over hundreds of pixels); the renderer's own smear cap is tighter still.
MAX_RATE_RAD_S = 2.0 * math.pi
#: Largest magnitude of either part of the split TAI date (days). Parts this size add with an error
#: below 0.2 ms; a sender that splits 2.46e6 days as 1e300 - (1e300 - 2.46e6) loses every digit.
MAX_SPLIT_DAYS = 1.0e7
#: The instant must lie in [1900-01-01, 2101-01-01) UTC, as TAI Julian dates (the span of sim.time).
_JD_TAI_MIN = Epoch.from_iso("1900-01-01T00:00:00Z").jd_tai
_JD_TAI_MAX = Epoch.from_iso("2100-12-31T23:59:59Z").jd_tai
#: |UT1 - UTC| is kept below 0.9 s by IERS; sim.time allows 1 s.
MAX_DUT1_S = 1.0
#: Shortest shared key accepted for the HMAC (bytes).
MIN_KEY_BYTES = 16


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
    size = _HEAD.size + _VEC.size * bin(flags & _BLOCK_FLAGS).count("1") + _CRC.size
    return size + (_TAG if flags & FLAG_HMAC else 0)


def _check_key(key) -> bytes:
    if not isinstance(key, bytes | bytearray) or len(key) < MIN_KEY_BYTES:
        n = len(key) if isinstance(key, bytes | bytearray) else type(key).__name__
        raise StateMessageError("key", f"key = {n} bytes; a shared key must be bytes, at least {MIN_KEY_BYTES} long.")
    return bytes(key)


def _physical(epoch_parts, q, v, opt: dict) -> None:
    """Refuse values the renderer cannot draw truthfully (see the module docstring)."""
    tai1, tai2, off_ns, dut1 = epoch_parts
    if not (abs(tai1) <= MAX_SPLIT_DAYS and abs(tai2) <= MAX_SPLIT_DAYS):
        raise StateMessageError("epoch", f"epoch tai1, tai2 = {tai1!r}, {tai2!r} d; each part of the split date "
                                f"must be within +-{MAX_SPLIT_DAYS:g} days.")
    jd = (tai1 - _JD_TAI_MIN[0]) + tai2 + off_ns / 86_400e9
    span = (_JD_TAI_MAX[0] - _JD_TAI_MIN[0]) + _JD_TAI_MAX[1]
    if not 0.0 <= jd <= span:
        raise StateMessageError("epoch", f"epoch = TAI JD {tai1!r} + {tai2!r} + {off_ns} ns is outside the supported "
                                "years 1900 to 2100 (JD TAI 2415020.5 to 2488434.5).")
    if not abs(dut1) <= MAX_DUT1_S:
        raise StateMessageError("epoch", f"epoch dut1_s = {dut1!r} s; UT1 - UTC must be within +-{MAX_DUT1_S:g} s.")
    speed = math.hypot(*v)
    if not speed < MAX_SPEED_M_S:
        raise StateMessageError("v_sc_gcrs_m_s", f"v_sc_gcrs_m_s = {tuple(v)} has speed {speed:.6g} m/s; allowed "
                                f"below {MAX_SPEED_M_S:g} m/s.")
    w = opt.get("omega_SN_S")
    if w is not None:
        rate = math.hypot(*w)
        if not rate <= MAX_RATE_RAD_S:
            raise StateMessageError("omega_SN_S", f"omega_SN_S = {tuple(w)} has rate {rate:.6g} rad/s; allowed up "
                                    f"to {MAX_RATE_RAD_S:.6g} rad/s (one turn per second).")


def _vec(name: str, value, n: int) -> tuple:
    a = np.asarray(value, dtype=float).reshape(-1)
    if a.size != n or not np.all(np.isfinite(a)):
        raise StateMessageError(name, f"{name} = {value!r}; it must be {n} finite numbers.")
    return tuple(float(x) for x in a)


def encode(state: DisplayState, key: bytes | None = None) -> bytes:
    """The bytes of ``state`` (see the module docstring for the layout); with ``key`` (bytes, at least
    16) the HMAC-SHA256 trailer is appended. Refuses what :func:`decode` would refuse."""
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
    flags, blocks, opt = 0, b"", {}
    for bit, name in enumerate(_OPTIONAL):
        value = getattr(state, name)
        if value is not None:
            vec = _vec(name, value, 3)
            if name != "omega_SN_S" and abs(math.sqrt(sum(x * x for x in vec)) - 1.0) > U_NORM_TOL:
                raise StateMessageError(name, f"{name} = {vec} is not a unit vector (within {U_NORM_TOL}).")
            flags |= 1 << bit
            blocks += _VEC.pack(*vec)
            opt[name] = vec
    _physical((ep[0], ep[1], int(e.offset_ns), ep[2]), q, v, opt)
    if key is not None:
        key = _check_key(key)
        flags |= FLAG_HMAC
    body = _HEAD.pack(MAGIC, VERSION, flags, int(state.stream_id), int(state.sequence), int(state.sim_time_ns),
                      ep[0], ep[1], int(e.offset_ns), ep[2], *q, *v) + blocks
    data = body + _CRC.pack(zlib.crc32(body))
    if key is not None:
        data += hmac.digest(key, data, "sha256")
    return data


def decode(data: bytes, key: bytes | None = None) -> DisplayState:
    """Parse a message; raises :class:`StateMessageError` naming the first field that is wrong.

    With ``key`` the message must carry a valid HMAC-SHA256 trailer; without one, a trailer is
    length-checked but not verified (there is nothing to verify it with)."""
    data = bytes(data)
    flags, end = _check_frame(data)
    if key is not None:
        _check_hmac(data, flags, end, key)
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
    opt = _optional_vectors(data, flags)
    _physical((tai1, tai2, off_ns, dut1), q, v, opt)
    return DisplayState(sequence, t_ns, Epoch(tai1, tai2, off_ns, dut1), q, v, stream_id=stream_id, **opt)


def _check_frame(data: bytes) -> tuple[int, int]:
    """Length, magic, version, flags and CRC of a message; returns its flags and where its HMAC trailer starts."""
    if len(data) < _HEAD.size + _CRC.size:
        raise StateMessageError("length", f"message length = {len(data)} bytes; a version-{VERSION} state "
                                f"message has at least {_HEAD.size + _CRC.size}.")
    magic, version, flags = struct.unpack_from("<4sHH", data)
    if magic != MAGIC:
        raise StateMessageError("magic", f"magic = {magic!r}; a state message starts with {MAGIC!r}.")
    if version != VERSION:
        raise StateMessageError("version", f"version = {version}; this node reads version {VERSION} only.")
    if flags & ~_KNOWN_FLAGS:
        raise StateMessageError("flags", f"flags = {flags:#06x}; only bits 0-{len(_OPTIONAL)} "
                                f"({', '.join(_OPTIONAL)}, hmac) are defined.")
    want = message_size(flags)
    if len(data) != want:
        raise StateMessageError("length", f"message length = {len(data)} bytes; flags {flags:#06x} "
                                f"need exactly {want}.")
    end = want - (_TAG if flags & FLAG_HMAC else 0)
    (crc,) = _CRC.unpack_from(data, end - _CRC.size)
    computed = zlib.crc32(data[: end - _CRC.size])
    if crc != computed:
        raise StateMessageError("crc32", f"crc32 = {crc:#010x} but the bytes give {computed:#010x}; "
                                "the datagram is corrupt.")
    return flags, end


def _check_hmac(data: bytes, flags: int, end: int, key: bytes) -> None:
    key = _check_key(key)
    if not flags & FLAG_HMAC:
        raise StateMessageError("hmac", "the message carries no HMAC (flag bit 3 clear); this node has a "
                                "shared key and accepts authenticated messages only.")
    if not hmac.compare_digest(hmac.digest(key, data[:end], "sha256"), data[end:]):
        raise StateMessageError("hmac", "the message's HMAC does not match this node's key; it was "
                                "forged, corrupted, or sent with another key.")


def _optional_vectors(data: bytes, flags: int) -> dict:
    """The optional 3-vectors the flags announce, in their order after the head, each checked."""
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
    return opt
