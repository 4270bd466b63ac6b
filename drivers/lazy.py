"""Lazy names of a device package: ``from drivers.gyro import GyroHost`` works without importing the host, emulator
and their transports when only the codec is wanted (a package imports its codec at once, the rest on first use)."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_getattr"]


def lazy_getattr(package: str, modules: Mapping[str, str]) -> Callable[[str], Any]:
    """The module ``__getattr__`` (PEP 562) of ``package`` that imports each name of ``modules`` (name -> the module
    defining it) on first use; AttributeError naming the package for any other name."""
    where = dict(modules)

    def __getattr__(name: str) -> Any:
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(module), name)

    return __getattr__
