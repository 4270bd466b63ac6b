"""ADCS controllers in the loop, and the plug-in API for flight-software engineers.

A controller sees the spacecraft only through host drivers, exactly as flight software sees its devices: every
measurement it reads and every command it sends crosses the device protocol. It never touches the truth model.

Plug-in API (``[controller] kind = "plugin"``, ``module = "package.module:ClassName"``, ``options = {...}``, and
``path = "folder"`` when the module is not in an installed package): the class is built as
``ClassName(devices, period_s, **options)`` where ``devices`` maps **every** scenario device name to its host
driver, whatever its link (``take_sample``/``command_dipole`` for a magnetorquer, ``take_solution`` for a star
tracker, ``take_sun`` for a sun sensor), and is called once per control period as ``update(t_s)``. Optional:
``telemetry_columns()`` -> ``[(name, width, unit), ...]`` and ``telemetry()`` -> a tuple of floats recorded with
every telemetry row, and ``close()`` at the end. Anything raised in ``update`` or ``telemetry`` (``sys.exit`` too;
``os._exit`` is turned into an exception while the run is on), and a call over ``controller.budget_s`` of wall
time, ends the run "aborted" (exit 3) with the traceback in ``events.jsonl`` and the summary and plots written
(stand.loop); Ctrl-C alone means the operator. At import or construction, the same is a PluginError (exit 2).
``examples/plugin_template.py`` is a complete template; ``docs/plugins.md`` documents the API. The reference
B-dot below is written against the same API (``BDot.from_devices``), and so is the reference pointing ADCS,
:class:`stand.adcs.pointing.PointingController` (gyro ``take_rate``, reaction wheels
``take_speed``/``command_torque``; docs/adcs.md).

This package is flight code: it depends on the host drivers' API and on ``sim`` (rotations, frames), never on
the scenario loader or composition. What builds it from a scenario is the controller registry
(:mod:`stand.controllers`: one kind each for B-dot, pointing and plug-ins).
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import inspect
import os
import re
import sys
from importlib.metadata import packages_distributions
from pathlib import Path

import numpy as np

from sim.rotations import dcm

#: ``package.module:ClassName`` with plain identifiers only (no relative imports, no attribute paths).
PLUGIN_SPEC = re.compile(r"([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*):([A-Za-z_]\w*)")


class PluginError(ValueError):
    """A plug-in that cannot be found, imported or constructed; the message is one sentence."""


class BDot:
    """B-dot detumbling: m = -k dB/dt, by finite difference of successive magnetometer samples.

    The derivative is taken in body axes (the sensor mount ``q_SB`` is known to the flight software, as on a
    real spacecraft). Each command is clipped per axis to ``max_dipole_A_m2`` and keeps the coils on for
    ``duty_cycle`` of the control period; the board's watchdog turns them off when that expires. Samples flagged
    ``coil_active`` are skipped when ``skip_coil_active`` is set (the coils corrupt the magnetometer while they
    are driven).
    """

    def __init__(self, board, period_s: float, gain_A_m2_s_per_T: float, max_dipole_A_m2: float,
                 q_SB=(1.0, 0.0, 0.0, 0.0), skip_coil_active: bool = True, duty_cycle: float = 1.0, sensor=None):
        self.board = board
        #: Where the field is read (``take_sample()``): a magnetometer of its own, else the board's (``q_SB`` is
        #: that sensor's mount).
        self.sensor = board if sensor is None else sensor
        self.period_s = period_s
        self.gain = gain_A_m2_s_per_T
        self.max_dipole = max_dipole_A_m2
        self.dcm_BS = dcm(np.asarray(q_SB, dtype=float)).T.tolist()
        self.skip_coil_active = skip_coil_active
        self.duration_s = period_s * duty_cycle
        self._prev = None  # (t_s, b_B)
        self.last_command = (0.0, 0.0, 0.0)
        self.samples_used = 0
        self.samples_skipped = 0

    def telemetry_columns(self) -> list[tuple[str, int, str]]:
        return [("dipole_cmd_B", 3, "A m^2")]

    def telemetry(self) -> tuple:
        return self.last_command

    def update(self, t_s: float) -> None:
        sample = self.sensor.take_sample()  # polls the bus
        if sample is not None:
            self.command_for(sample, t_s)

    def command_for(self, sample, t_s: float) -> None:
        """Use one magnetometer sample taken at ``t_s`` (an external flight program calls this directly)."""
        if self.skip_coil_active and sample.coil_active or not sample.valid:
            self.samples_skipped += 1
            self._prev = None
            return
        # Component by component on floats: this runs every control tick, and indexing or a generator over
        # three components costs more than the arithmetic.
        sx, sy, sz = sample.b_T
        (c00, c01, c02), (c10, c11, c12), (c20, c21, c22) = self.dcm_BS
        bx = c00 * sx + c01 * sy + c02 * sz
        by = c10 * sx + c11 * sy + c12 * sz
        bz = c20 * sx + c21 * sy + c22 * sz
        self.samples_used += 1
        prev, self._prev = self._prev, (t_s, (bx, by, bz))
        if prev is None or t_s <= prev[0]:
            return
        t_prev, (px, py, pz) = prev
        k = -self.gain / (t_s - t_prev)
        lim = self.max_dipole
        m = (max(-lim, min(lim, k * (bx - px))), max(-lim, min(lim, k * (by - py))),
             max(-lim, min(lim, k * (bz - pz))))
        self.board.command_dipole(m, self.duration_s)
        self.last_command = m


@functools.cache
def _installed_top_levels() -> dict:
    """The top-level names of the installed distributions: scanning them costs about 0.2 s, once per process."""
    return packages_distributions()


def _check_installed(top: str, spec: str) -> None:
    """Refuse a plug-in whose top-level package no installed distribution provides."""
    if top in _installed_top_levels():
        return
    _installed_top_levels.cache_clear()  # installed since this process first looked?
    if top not in _installed_top_levels():
        raise PluginError(
            f"controller.module = {spec!r} is not allowed: {top!r} is not an installed package; install it "
            "(pip install -e your_package) or give controller.path = 'folder' holding it (the working directory "
            "is never searched by itself).")


def load_plugin(spec: str, path: str | Path | None = None, base: Path | None = None):
    """The class named by ``package.module:ClassName``: from the folder ``path`` (relative to ``base``, the
    scenario's folder) when given, else from an installed distribution. Never from the working directory by
    accident. Raises PluginError with one sentence."""
    m = PLUGIN_SPEC.fullmatch(spec) if isinstance(spec, str) else None
    if m is None:
        raise PluginError(f"controller.module = {spec!r} is not allowed: give 'package.module:ClassName' with plain "
                          "names (no relative imports).")
    module_name, attr = m.groups()
    top = module_name.split(".")[0]
    if path is not None:
        folder = (Path(base or ".") / path).resolve()
        if not folder.is_dir():
            raise PluginError(f"controller.path = {str(path)!r} is not allowed: a folder holding {top!r} is expected "
                              f"({folder} is not a folder).")
        module = _import_from(folder, module_name, spec)
    else:
        _check_installed(top, spec)
        module = _import_installed(module_name, spec)
    cls = getattr(module, attr, None)
    if not inspect.isclass(cls):
        raise PluginError(f"controller.module = {spec!r} is not allowed: {module_name!r} has no class {attr!r}.")
    return cls


def _import_installed(module_name: str, spec: str):
    saved = list(sys.path)
    cwd = os.getcwd()
    # `python -m stand.cli` puts the working directory first on sys.path: a stray file there must not load.
    sys.path[:] = [p for p in sys.path if p not in ("", ".", cwd)]
    try:
        return importlib.import_module(module_name)
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # sys.exit() and the like too: one sentence, not a silent exit
        raise PluginError(f"controller.module = {spec!r}: {module_name!r} cannot be imported "
                          f"({type(exc).__name__}: {exc}).") from None
    finally:
        sys.path[:] = saved


#: Top-level plug-in modules imported from a scenario's folder, and the folder each came from.
_PLUGIN_FOLDERS: dict[str, Path] = {}


def _import_from(folder: Path, module_name: str, spec: str):
    top = module_name.split(".")[0]
    if top in sys.modules:
        if _PLUGIN_FOLDERS.get(top) not in (None, folder):
            # The same name from another scenario's folder, earlier in this process: this folder's module is meant.
            for name in [n for n in sys.modules if n == top or n.startswith(top + ".")]:
                del sys.modules[name]
        elif top not in _PLUGIN_FOLDERS:
            where = getattr(sys.modules[top], "__file__", None) or "built in"
            raise PluginError(f"controller.module = {spec!r} is not allowed: {top!r} is already imported from {where}; "
                              f"give the plug-in's module a name of its own.")
    sys.path.insert(0, str(folder))
    try:
        module = importlib.import_module(module_name)
        _PLUGIN_FOLDERS[top] = folder
        return module
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # sys.exit() and the like too: one sentence, not a silent exit
        raise PluginError(f"controller.module = {spec!r}: {module_name!r} cannot be imported from {folder} "
                          f"({type(exc).__name__}: {exc}).") from None
    finally:
        if sys.path and sys.path[0] == str(folder):
            sys.path.pop(0)
