"""The hot paths compiled by Cython: the one list of them, how a module takes its build, and which builds run.

Each module in :data:`MODULES` is ordinary, readable Python, and the only source of its code. Where the install
has a C compiler, ``setup.py`` also compiles that same file under a twin name (``sim.body_step`` ->
``sim._body_step_compiled``) with Cython in pure-Python mode; the plain module stays importable beside it, so
``STAND_NATIVE=0`` runs the plain Python on an install that has the compiled twins. Both give the same results to
the bit (docs/fast_paths.md).

A module that runs a hot path never imports it directly: it takes ``compiled_paths.load(name)``. Adding a module is
one line in :data:`MODULES` (and ``load`` where it is used); the build, :func:`active` (which every run's
``summary.json`` records) and ``stand bench loop``'s note follow from the list.

This module is on its own at the top of the package tree because ``sim`` and ``drivers`` may not import each other
nor ``stand``, and both take their hot paths from here. It imports nothing of the stand.
"""

from __future__ import annotations

import importlib
import importlib.machinery
import importlib.util
import os
from pathlib import Path
from types import ModuleType

#: The modules compiled where a C compiler exists, in the order they are built.
MODULES: tuple[str, ...] = (
    "sim.body_step",  # the attitude step (RK4 with magnetic and gravity-gradient torque, the wheels' gyrostat terms)
    "sim.wheel_step",  # the reaction wheels' motor and rotor step
    "drivers.bitpack",  # the DBC codec's per-message bit packing
    "star_screen.tracking.nearest",  # the star tracker's radius matching (lost in space and tracking)
    "drivers.icd_plan",  # the serial ICD codec's per-field encode and decode (gyro, sun sensor, star tracker)
    "drivers.star_tracker.exposure_math",  # the emulated star tracker's exposure: truth check, exclusion, noise
    "drivers.can_frames",  # the CAN nodes' drain and send, the in-process bus's delivery of a data frame
    "star_screen.tracking.lis_steps",  # the star tracker's lost-in-space decisions: cone, pattern keys, pair attitude
    "numpy_draws",  # single random draws of the emulated devices, through numpy's own C distributions
)

_chosen: dict[str, ModuleType] = {}


def twin(name: str) -> str:
    """The compiled twin's module name of ``name``: ``pkg.mod`` -> ``pkg._mod_compiled``."""
    package, _, module = name.rpartition(".")
    return f"{package}._{module}_compiled" if package else f"_{module}_compiled"


def native_allowed() -> bool:
    """False when ``STAND_NATIVE=0`` asks for the plain Python of every module."""
    return os.environ.get("STAND_NATIVE", "1").strip() != "0"


def load(name: str) -> ModuleType:
    """The module ``name`` (one of :data:`MODULES`) as this process runs it: its compiled twin when the install built
    it and ``STAND_NATIVE`` is not ``0``, else the plain module. Chosen once per process."""
    module = _chosen.get(name)
    if module is None:
        if name not in MODULES:
            raise ValueError(f"{name!r} is not a compiled path; compiled_paths.MODULES lists {', '.join(MODULES)}.")
        module = None
        if native_allowed():
            try:
                module = importlib.import_module(twin(name))
            except ImportError:  # no C compiler at install: the plain module, the same to the bit
                module = None
        module = module or importlib.import_module(name)
        _chosen[name] = module
    return module


def is_compiled(module: ModuleType) -> bool:
    """True for a compiled twin (a Cython extension module), False for plain Python."""
    return not str(getattr(module, "__file__", "")).endswith(".py")


def active() -> dict[str, str]:
    """Each compiled path and what this process runs for it: ``"compiled"`` or ``"python"``.

    A path the process has not loaded is reported by what :func:`load` would find, without importing it: its package
    may be heavy and the run may not need it (a detumble never loads the star tracker's matching, whose package
    costs 0.3 s to import)."""
    return {name: "compiled" if (is_compiled(_chosen[name]) if name in _chosen else _twin_installed(name))
            else "python" for name in MODULES}


def _twin_installed(name: str) -> bool:
    """Whether :func:`load` would take the compiled twin of ``name``: ``STAND_NATIVE`` allows it and its extension
    file is installed (looked up in the top-level package's folders, so no package is imported)."""
    if not native_allowed():
        return False
    top, *inner = twin(name).split(".")
    spec = importlib.util.find_spec(top)
    if not inner:  # a module at the top of the tree (numpy_draws): its own spec says what it is
        return spec is not None and not str(spec.origin).endswith(".py")
    folders = (spec.submodule_search_locations or []) if spec is not None else []
    return any(Path(folder, *inner[:-1], inner[-1] + suffix).is_file()
               for folder in folders for suffix in importlib.machinery.EXTENSION_SUFFIXES)


def summary() -> str:
    """One line for a report: ``sim.body_step: compiled, drivers.bitpack: compiled (STAND_NATIVE=0 runs ...)``."""
    return ", ".join(f"{name}: {how}" for name, how in active().items()) + " (STAND_NATIVE=0 runs the Python of all)"
