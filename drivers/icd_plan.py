"""The per-frame loops of the serial ICD codec (:mod:`drivers.icd_codec`): every field of every frame of the gyro,
the sun sensor and the star tracker passes here, encoded and decoded from a plan built once per message.

Plain Python, and compiled by Cython in pure-Python mode where the install has a C compiler (``compiled_paths``
lists it; docs/fast_paths.md): the ``cython.*`` declarations give the compiled build a typed field plan and C
doubles for the f32 range and the scale, and do nothing in plain Python. Both builds do the same IEEE-754 operations
(setup.py compiles without contraction, fast-math and cdivision) and round with Python's ``round`` on a Python
float (half to even; C's ``round`` would take a half away from zero), so they agree to the bit; the tests run both.

These loops take only the plain case: a flag that is True or False, an enumeration name as the table spells it or
an index inside it, a float or int (a tuple element for an indexed field) whose wire value lies inside its field.
They say where the plain case ends (``None`` for a wire value, the position of a refused field) and the codec's own
checks (:func:`drivers.icd_codec.wire_value`) convert the rest or say what is wrong, so every error sentence has one
source. ``drivers.icd_codec`` takes this module through ``compiled_paths.load("drivers.icd_plan")``.
"""

from __future__ import annotations

import cython
from cython.cimports.libc.math import isfinite, sqrt  # C's when compiled, Python's math otherwise: the same

#: A field's kind in its plan.
BITS = 0
ENUM = 1
INT = 2
I24 = 3
F32 = 4


@cython.cclass
class FieldPlan:
    """What the per-frame loops need of one field, built once per message (:func:`drivers.icd_codec.field_plan`).

    ``index`` is -1 for a field that is not a tuple element; ``lo``/``hi`` the field's bounds on the wire (ints for
    an integer field; for an f32 field clipped to the finite floats, so one range test also says a value is
    finite); ``bits`` ``((attribute, mask), ...)`` of a flags field; ``table`` and ``names`` an enumeration and the
    names a value may be given as, exactly as written (name -> index); ``field`` the FieldSpec itself."""

    kind: cython.int
    attr: str
    index: cython.Py_ssize_t
    scale: cython.double
    unscaled: cython.bint
    lo: object
    hi: object
    flo: cython.double
    fhi: cython.double
    bits: tuple
    table: tuple
    names: dict
    field: object

    def __init__(self, kind: cython.int, attr: str, index: cython.Py_ssize_t, scale: cython.double, lo: object,
                 hi: object, bits: tuple, table: tuple, names: dict, field: object) -> None:
        self.kind = kind
        self.attr = attr
        self.index = index
        self.scale = scale
        self.unscaled = scale == 1.0
        self.lo = lo
        self.hi = hi
        self.flo = float(lo)
        self.fhi = float(hi)
        self.bits = bits
        self.table = table
        self.names = names
        self.field = field


def plain_wire_values(plan: tuple, msg: object, byte_order: str, out: list, start: cython.Py_ssize_t) -> int:
    """Append to ``out`` the wire values of ``msg``'s fields from position ``start`` on, as long as they are the
    plain case; the position of the first field that is not (the codec's checks take it), or -1 after the last.
    (One loop without a call per field: in plain Python too, a frame costs a few calls, not a few per field.)"""
    n: cython.Py_ssize_t = len(plan)
    i: cython.Py_ssize_t
    p: FieldPlan
    for i in range(start, n):
        p = plan[i]
        wire: object = None
        if p.kind == BITS:
            wire = _plain_flags(p.bits, msg)
        elif p.kind == ENUM:
            wire = _plain_enum(p, getattr(msg, p.attr))
        else:
            value: object = getattr(msg, p.attr)
            if p.index >= 0:  # an element of a tuple (anything else: the checks)
                try:
                    value = value[p.index] if type(value) is tuple else None
                except IndexError:
                    value = None
            t: object = type(value)
            if p.kind == F32:
                if t is float and p.scale != 0.0:  # a zero scale: the checks raise Python's own ZeroDivisionError
                    x: cython.double = value
                    x = x / p.scale  # x / 1.0 is x: the same bits as without the scale
                    if p.flo <= x <= p.fhi:  # finite bounds: a NaN or inf fails here
                        wire = x
            elif t is int or t is float:
                # a Python float (or Python's own error) when scaled: round is Python's, half to even
                w: object = value if t is int and p.unscaled else value / p.scale
                rounded: object = w if type(w) is int else round(w) if isfinite(w) else None
                if rounded is not None and p.lo <= rounded <= p.hi:
                    wire = rounded if p.kind == INT else rounded.to_bytes(3, byte_order, signed=True)
        if wire is None:
            return i
        out.append(wire)
    return -1


@cython.cfunc
def _plain_enum(p: FieldPlan, value: object) -> object:
    t: object = type(value)
    if t is str:
        return p.names.get(value)
    if t is int and 0 <= value < len(p.table):
        return value
    return None


@cython.cfunc
def _plain_flags(bits: tuple, msg: object) -> object:
    v: object = 0
    for pair in bits:
        bit, mask = pair
        flag: object = getattr(msg, bit)
        if flag is True:
            v |= mask
        elif flag is not False:
            return None
    return v


def decode_plain(plan: tuple, raw: object, kw: dict) -> int:
    """Fill ``kw`` (attribute -> SI value; a tuple attribute's list element by element) from the unpacked wire
    values ``raw`` (as many as the plan has fields; the codec checks the count); -1, or the position of the first
    field whose value is outside its flags, table or range (the codec then says why)."""
    n: cython.Py_ssize_t = min(len(plan), len(raw))
    i: cython.Py_ssize_t
    p: FieldPlan
    for i in range(n):
        p = plan[i]
        v: object = raw[i]
        val: object
        if p.kind == BITS:
            if v < 0 or v > p.hi:  # a bit past the ICD's flags (hi: every defined bit set)
                return i
            for pair in p.bits:
                bit, mask = pair
                kw[bit] = v & mask != 0
            continue
        if p.kind == ENUM:
            if v > p.hi:  # hi: the last entry of the table
                return i
            val = p.table[v]
        elif p.lo <= v <= p.hi:  # an f32 field's bounds are finite: NaN and inf fail here
            val = v * p.scale if not p.unscaled else v
        else:
            return i
        if p.index < 0:
            kw[p.attr] = val
        else:
            kw[p.attr][p.index] = val
    return -1


@cython.locals(total=cython.double, x=cython.double)
def norm2(values: object) -> float:
    """The Euclidean norm of a few numbers, summed in order (the unit-norm check of a quaternion a frame carries, on
    encoding and on decoding). Each is converted with ``float()`` (an int, a numpy scalar or a numeric string is
    taken; anything else raises what ``float()`` raises)."""
    total = 0.0
    for v in values:
        x = float(v)
        total += x * x
    return sqrt(total)
