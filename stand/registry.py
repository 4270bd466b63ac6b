"""Things found by name: the shipped ones (``name -> "module:attribute"``, imported on first use) and those of
installed packages (an entry-point group), as python-can finds its interfaces. The device kinds
(:mod:`stand.devices`) and the controller kinds (:mod:`stand.controllers`) are two such registries; the core
names neither a kind nor a controller, it asks them."""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points
from typing import Any


def installed_names(group: str, shipped: dict[str, str]) -> tuple[str, ...]:
    """The names an installed package adds under entry-point ``group`` (sorted; a shipped name is not replaced).
    Scanning the installed distributions takes milliseconds: a caller caches it for the process, so a package
    installed while the process runs is seen by the next one."""
    return tuple(sorted(ep.name for ep in entry_points(group=group) if ep.name not in shipped))


def load_named(name: str, shipped: dict[str, str], group: str, loaded: dict[str, Any]) -> Any:
    """The object called ``name``: a shipped one imported from its ``"module:attribute"``, else an installed
    package's entry point under ``group``; kept in ``loaded``. KeyError for an unknown name."""
    if name in loaded:
        return loaded[name]
    if name in shipped:
        module, _, attr = shipped[name].partition(":")
        obj = getattr(importlib.import_module(module), attr)
    else:
        found = [ep for ep in entry_points(group=group) if ep.name == name]
        if not found:
            raise KeyError(name)
        obj = found[0].load()
    loaded[name] = obj
    return obj
