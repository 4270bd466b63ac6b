"""Making a frozen, slotted dataclass without its generated ``__init__``: for the messages built on every frame.

A frozen dataclass's ``__init__`` sets each field with ``object.__setattr__`` (a global look-up, an attribute
look-up and a call per field: most of what making a decoded SOLUTION or a wheel's torque command costs). Here each
field's slot descriptor sets it, which is what ``object.__setattr__`` does in the end, so the object is the same:
equal, hashed, printed and frozen alike (``tests/drivers/test_frozen_build.py``). A class whose ``__init__`` does more
than store (a ``__post_init__``) or that has no slot per field is not built around its ``__init__``.

The serial ICD codec makes its messages from a dict of every field (:func:`keyword_maker`); the CAN codecs make
their three-field commands positionally (:func:`positional_maker3`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

__all__ = ["keyword_maker", "positional_maker3", "slot_setters"]


def slot_setters(cls: type) -> tuple[tuple[str, Callable[[Any, Any], None]], ...] | None:
    """``(field name, slot setter)`` of every field of the dataclass ``cls`` in field order, or None when ``cls``
    cannot be built by its slots: it has a ``__post_init__``, or its own ``__slots__`` are not exactly its fields."""
    names = tuple(f.name for f in dataclasses.fields(cls))
    slots = cls.__dict__.get("__slots__")
    if slots is None or set(slots) != set(names) or hasattr(cls, "__post_init__"):
        return None
    return tuple((name, cls.__dict__[name].__set__) for name in names)


def keyword_maker(cls: type) -> Callable[[dict[str, Any]], Any]:
    """``make(kw)``: the same object as ``cls(**kw)`` for a dict ``kw`` that holds every field of ``cls``; made by
    ``cls(**kw)`` when ``cls`` cannot be built by its slots (:func:`slot_setters`)."""
    setters = slot_setters(cls)
    if setters is None:
        return lambda kw: cls(**kw)
    new = object.__new__

    def make(kw: dict[str, Any]) -> Any:
        obj = new(cls)
        for name, set_slot in setters:
            set_slot(obj, kw[name])
        return obj

    return make


def positional_maker3(cls: type) -> Callable[[Any, Any, Any], Any]:
    """``build(a, b, c)``: the same object as ``cls(a, b, c)`` for a dataclass of three fields that can be built by
    its slots; TypeError for any other class (its ``__init__`` checks something, or it has another field count)."""
    setters = slot_setters(cls)
    if setters is None or len(setters) != 3:
        raise TypeError(f"{cls.__name__}: positional_maker3 takes a slots dataclass of three fields without "
                        "__post_init__.")
    new = object.__new__
    (_, set_a), (_, set_b), (_, set_c) = setters

    def build(a: Any, b: Any, c: Any) -> Any:
        obj = new(cls)
        set_a(obj, a)
        set_b(obj, b)
        set_c(obj, c)
        return obj

    build.__doc__ = f"{cls.__name__}(a, b, c), each field stored as given."
    return build
