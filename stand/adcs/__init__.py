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
"""

from __future__ import annotations

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
                 q_SB=(1.0, 0.0, 0.0, 0.0), skip_coil_active: bool = True, duty_cycle: float = 1.0):
        self.board = board
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
        sample = self.board.take_sample()  # polls the bus
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
        if top not in packages_distributions():
            raise PluginError(
                f"controller.module = {spec!r} is not allowed: {top!r} is not an installed package; install it "
                "(pip install -e your_package) or give controller.path = 'folder' holding it (the working directory "
                "is never searched by itself).")
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


def pointing_options(sc) -> dict:
    """The options of ``controller.kind = "pointing"`` with what the scenario already says filled in (an option
    the scenario gives wins): the spacecraft inertia, each device's mount, the wheels' axes, inertias and torque
    limit, the coarse sun heads' normals, and for nadir, target and sun guidance the orbit at t = 0 and the
    epoch. The filter's noise comes from the datasheets the scenario declares (stand.scenario), never from the
    simulated devices' own noise settings."""
    opts = dict(sc.controller.params["options"])
    specs = {d.name: d for d in sc.devices}
    opts.setdefault("inertia_kg_m2", np.asarray(sc.spacecraft.inertia_kg_m2, dtype=float).tolist())
    wheels = [specs[n] for n in opts["wheels"]]
    opts.setdefault("wheel_axes_B", [list(w.spin_axis_B) for w in wheels])
    opts.setdefault("wheel_inertia_kg_m2", [w.inertia_kg_m2 for w in wheels])
    opts.setdefault("max_wheel_torque_Nm", min(w.max_torque_Nm for w in wheels))
    if "star_tracker" in opts:
        st = specs[opts["star_tracker"]]
        opts.setdefault("star_tracker_q_TB", st.q_SB.tolist())
    opts.setdefault("gyro_q_SB", specs[opts["gyro"]].q_SB.tolist())
    for key in ("magnetorquer", "sun_sensor"):
        if key in opts:
            opts.setdefault(f"{key}_q_SB", specs[opts[key]].q_SB.tolist())
    if "sun_sensor" in opts and specs[opts["sun_sensor"]].type == "coarse":
        from stand.devices.sun_sensor import FACE_NORMALS

        # The controller solves for the Sun in the heads' own axes and then turns it through the mount.
        opts.setdefault("sun_sensor_normals_B", FACE_NORMALS.tolist())
    guidance = opts.get("guidance", "inertial")
    if guidance in ("nadir", "target"):
        from stand.compose import initial_state

        r, v = initial_state(sc)
        opts.setdefault("orbit_r_N_m", r.tolist())
        opts.setdefault("orbit_v_N_m_s", v.tolist())
    if guidance in ("sun", "target"):
        opts.setdefault("epoch", sc.epoch.iso)
    return opts


def build_controller(sc, devices: dict, base: Path | None = None):
    """The scenario's controller over the scene's devices (name -> Device), or None. Plug-in failures at
    construction are PluginError (a scenario error)."""
    ctl = sc.controller
    period = 1.0 / ctl.rate_hz
    p = ctl.params
    if ctl.kind == "bdot":
        spec = next(d for d in sc.devices if d.name == p["device"])
        return BDot(devices[spec.name].host, period, p["gain_A_m2_s_per_T"], p["max_dipole_A_m2"], q_SB=spec.q_SB,
                    skip_coil_active=p["skip_coil_active"], duty_cycle=p.get("duty_cycle", 1.0))
    if ctl.kind == "pointing":
        from .pointing import PointingController

        hosts = {name: d.host for name, d in devices.items()}
        try:
            return PointingController(hosts, period, **pointing_options(sc))
        except Exception as exc:  # options of any type reach the constructor: every refusal is one sentence
            raise PluginError(f"controller.kind = 'pointing': {exc}") from None
    if ctl.kind != "plugin":
        return None
    cls = load_plugin(p["module"], p.get("path"), base)
    hosts = {name: d.host for name, d in devices.items()}
    try:
        return cls(hosts, period, **p["options"])
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # sys.exit() and the like too: one sentence, not a silent exit
        raise PluginError(f"controller.module = {p['module']!r}: constructing {cls.__name__}(devices, {period:g}, "
                          f"**options) failed: {type(exc).__name__}: {exc}.") from None


class _NotOpened:
    """What ``stand check`` hands a plug-in for each device: nothing is opened, so any use says so."""

    def __init__(self, name: str):
        self._name = name

    def __getattr__(self, attr):
        raise RuntimeError(f"device {self._name!r} is not opened by `stand check` (the plug-in used .{attr} in its "
                           "constructor; devices are only for update())")


def check_controller(sc, base: Path | None = None) -> None:
    """What ``stand check`` does for the controller: import the plug-in and construct it over unopened devices,
    so a missing module, a wrong path or bad options fail here in one sentence, not at t = 0."""
    ctl = sc.controller
    if ctl.kind == "pointing":
        from .pointing import PointingController

        try:
            PointingController({d.name: _NotOpened(d.name) for d in sc.devices}, 1.0 / ctl.rate_hz,
                               **pointing_options(sc))
        except Exception as exc:  # options of any type reach the constructor: every refusal is one sentence
            raise PluginError(f"controller.kind = 'pointing': {exc}") from None
        return
    if ctl.kind != "plugin":
        return
    p = ctl.params
    cls = load_plugin(p["module"], p.get("path"), base)
    try:
        obj = cls({d.name: _NotOpened(d.name) for d in sc.devices}, 1.0 / ctl.rate_hz, **p["options"])
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # sys.exit() and the like too: one sentence, not a silent exit
        raise PluginError(f"controller.module = {p['module']!r}: constructing {cls.__name__}(devices, "
                          f"{1.0 / ctl.rate_hz:g}, **options) failed: {type(exc).__name__}: {exc}.") from None
    if not callable(getattr(obj, "update", None)):
        raise PluginError(f"controller.module = {p['module']!r}: {cls.__name__} has no update(t_s) method.")
