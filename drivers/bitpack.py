"""The DBC codec's per-message fast path: little-endian integer signals packed from and unpacked to positional
values. The one source of the CAN chain's bit packing (:mod:`drivers.dbc` builds a :class:`Packer` per message).

Plain Python, and compiled by Cython in pure-Python mode where the install has a C compiler (``compiled_paths``
lists it; docs/fast_paths.md): the ``cython.*`` declarations give the compiled build C integers and doubles and do
nothing in plain Python. Both builds give the same payloads and values, of the same types, to the bit; the tests run
both.

What a packer takes is the common case of cantools' arithmetic (``drivers.dbc`` is the reference):

* ``pack(*values)``: per signal exactly a float, an int (at most 2**52 in magnitude) or a bool, within the DBC's
  ``[lo, hi]`` (NaN is not), ``raw = round((value - offset) / scale)`` (half to even, as Python's ``round``; an int
  with an integer scale and offset stays exact), a raw value the bits hold. Anything else returns None and the
  caller's checked path decides (and raises the error that names the field).
* ``unpack(payload)``: ``raw * scale + offset`` per signal, an int for the integer kinds, a float otherwise.

A message the packer does not cover (over 8 bytes, a signal over 52 bits, an integer scale over 1024) raises
ValueError when it is built, and the caller takes cantools. The signal table is a tuple of tuples (a list raises
TypeError): nothing the packer reads can change while it reads it.
"""

from __future__ import annotations

import math

import cython
from cython.cimports.libc.math import floor  # C's when compiled, Python's math otherwise

#: Conversion kinds (drivers.dbc chooses them by cantools' rule).
IDENTITY = cython.declare(cython.int, 0)  # scale 1, offset 0: physical is the raw integer
LINEAR_INT = cython.declare(cython.int, 1)  # integer scale and offset: physical stays an int
LINEAR = cython.declare(cython.int, 2)  # anything else: physical is a float
#: Ints up to this magnitude convert to a double exactly, and their differences too.
EXACT_INT = cython.declare(cython.longlong, 1 << 52)
MAX_SIGNAL_BITS = 52
MAX_LENGTH = 8  # bytes: classic CAN
MAX_INT_SCALE = 1024  # an integer scale's raw * scale + offset stays within 64 bits


@cython.cfunc
@cython.inline
def _round_half_even(x: cython.double) -> cython.double:
    """Python's ``round(x)`` (to the nearest integer, a tie to the even one), as a float: x - floor(x) is exact."""
    r = floor(x)
    d = x - r
    if d > 0.5 or (d == 0.5 and r % 2 != 0):
        r = r + 1
    return r


@cython.cclass
class Signal:
    """One signal's constants: start bit, mask, sign bit, conversion kind, scale, offset, physical and raw range."""

    start: cython.int
    kind: cython.int
    mask: cython.ulonglong
    sign_bit: cython.ulonglong
    scale: cython.double
    offset: cython.double
    iscale: cython.longlong
    ioffset: cython.longlong
    lo: cython.double
    hi: cython.double
    raw_lo: cython.longlong
    raw_hi: cython.longlong

    def __init__(self, row, length_bits: cython.int):
        if type(row) is not tuple or len(row) != 10:
            raise TypeError(f"a signal is a tuple (start, bits, signed, kind, scale, offset, lo, hi, raw_lo, raw_hi); "
                            f"got {row!r}.")
        start, bits, signed, kind, scale, offset, lo, hi, raw_lo, raw_hi = row
        if not (type(start) is int and type(bits) is int and type(signed) is bool and type(kind) is int
                and type(raw_lo) is int and type(raw_hi) is int
                and all(type(x) is float or type(x) is int for x in (scale, offset, lo, hi))):
            raise TypeError(f"signal {row!r}: start, bits, kind, raw_lo and raw_hi must be ints, signed a bool, "
                            "scale, offset, lo and hi numbers.")
        if not (1 <= bits <= MAX_SIGNAL_BITS and 0 <= start and start + bits <= length_bits and 0 <= kind <= 2
                and all(math.isfinite(x) for x in (scale, offset, lo, hi)) and scale != 0
                and -EXACT_INT <= raw_lo <= raw_hi <= EXACT_INT
                and not (type(offset) is int and abs(offset) > EXACT_INT)):
            raise ValueError(f"signal {row!r} is beyond the packer (at most {MAX_SIGNAL_BITS} bits within the "
                             "payload, a finite nonzero scale, a finite range).")
        if kind == LINEAR_INT and not (scale == int(scale) and offset == int(offset) and abs(scale) <= MAX_INT_SCALE
                                       and abs(offset) <= EXACT_INT):
            raise ValueError(f"signal {row!r}: an integer scale and offset must be within {MAX_INT_SCALE} and 2**52.")
        self.start, self.kind = start, kind
        self.mask = (1 << bits) - 1
        self.sign_bit = (1 << (bits - 1)) if signed else 0
        self.scale, self.offset, self.lo, self.hi = scale, offset, lo, hi
        self.iscale, self.ioffset = int(scale), int(offset)
        self.raw_lo, self.raw_hi = raw_lo, raw_hi

    @cython.cfunc
    def field(self, v: object) -> tuple[cython.bint, cython.ulonglong]:
        """(True, the signal's bits in place), or (False, 0) where the checked path must decide."""
        t = type(v)
        x: cython.double
        iv: cython.longlong = 0
        if t is float:
            x = v
        elif t is int or t is bool:
            try:
                iv = v
            except OverflowError:  # beyond 64 bits (compiled); plain Python refuses it just below
                return (False, 0)
            if not -EXACT_INT <= iv <= EXACT_INT:
                return (False, 0)
            x = iv
        else:
            return (False, 0)
        if not self.lo <= x <= self.hi:  # also refuses NaN
            return (False, 0)
        if self.kind == IDENTITY and t is not float:
            r = iv
        elif self.kind == LINEAR_INT and t is not float:
            r = _round_half_even((iv - self.ioffset) / self.iscale)  # exact: both ints are exact doubles
        else:
            r = _round_half_even((x - self.offset) / self.scale)
        if not self.raw_lo <= r <= self.raw_hi:
            return (False, 0)
        raw: cython.longlong = cython.cast(cython.longlong, r)
        return (True, (cython.cast(cython.ulonglong, raw) & self.mask) << self.start)

    @cython.cfunc
    def value(self, word: cython.ulonglong) -> object:
        """The signal's physical value in ``word`` (the payload, little-endian)."""
        u: cython.ulonglong = (word >> self.start) & self.mask
        r: cython.longlong = cython.cast(cython.longlong, u ^ self.sign_bit) - cython.cast(cython.longlong,
                                                                                          self.sign_bit)
        if self.kind == IDENTITY:
            return r
        if self.kind == LINEAR_INT:
            return r * self.iscale + self.ioffset
        return r * self.scale + self.offset


@cython.cclass
class Packer:
    """``Packer(length, signals)``: one message of ``length`` bytes (1 to 8); ``signals`` is a tuple of
    ``(start, bits, signed, kind, scale, offset, lo, hi, raw_lo, raw_hi)``, one per value, in the order the values
    are passed."""

    length: cython.int
    signals: tuple

    def __init__(self, length, signals):
        if type(length) is not int or type(signals) is not tuple:
            raise TypeError(f"Packer(length, signals) takes an int and a tuple; got {length!r}, {signals!r}.")
        if not 1 <= length <= MAX_LENGTH:
            raise ValueError(f"Packer: length = {length} bytes; 1 to {MAX_LENGTH} (classic CAN).")
        self.length = length
        self.signals = tuple([Signal(row, 8 * length) for row in signals])

    def pack(self, *values):
        """The payload of ``values`` (physical, one per signal), or None where the checked path must decide."""
        if len(values) != len(self.signals):
            raise TypeError(f"pack() takes {len(self.signals)} values; got {len(values)}.")
        word: cython.ulonglong = 0
        bits: cython.ulonglong
        ok: cython.bint
        i: cython.Py_ssize_t
        for i in range(len(values)):
            ok, bits = cython.cast(Signal, self.signals[i]).field(values[i])
            if not ok:
                return None
            word |= bits
        return word.to_bytes(self.length, "little")

    def unpack(self, data):
        """The physical values in payload ``data`` (exactly ``length`` bytes), as a tuple in the signals' order."""
        if type(data) is not bytes and type(data) is not bytearray:
            data = bytes(data)  # a memoryview or any other buffer: a copy that cannot change while it is read
        if len(data) != self.length:
            raise ValueError(f"unpack() takes {self.length} bytes; got {len(data)}.")
        p: cython.p_uchar = data
        word: cython.ulonglong = 0
        b: cython.int
        for b in range(self.length):  # little-endian
            word |= cython.cast(cython.ulonglong, p[b]) << (8 * b)
        return tuple([cython.cast(Signal, s).value(word) for s in self.signals])
