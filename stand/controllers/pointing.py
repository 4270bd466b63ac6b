"""``controller.kind = "pointing"``: the reference pointing ADCS (:class:`stand.adcs.pointing.PointingController`).

Its ``[controller.options]`` name the devices it reads and commands (checked here to exist, be of the right kind
and have a host driver in the stand); ``[controller.datasheet.NAME]`` of its star tracker and gyro, times
``datasheet_margin``, tune its filter (never the simulated devices' own noise: docs/adcs.md); the rest is checked
by its constructor, over unopened devices, when the scenario is loaded.
"""

from __future__ import annotations

import math
import re
from dataclasses import fields
from pathlib import Path

import numpy as np

from stand.adcs import PluginError
from stand.adcs.metrics import FAULT_METRICS, METRICS
from stand.adcs.modes import ModeConfig
from stand.adcs.pointing import OPTIONS, PointingController
from stand.checks import MISSING, ScenarioError, Table, unusable
from stand.controllers import ControllerKind, not_opened
from stand.devices.sun_sensor import FACE_NORMALS

#: Devices the reference pointing ADCS takes by name: option -> device kind.
POINTING_DEVICES = {"star_tracker": "star_tracker", "gyro": "gyro", "magnetorquer": "magnetorquer",
                    "sun_sensor": "sun_sensor"}


def _pointing(t: Table, devices) -> dict:
    """The options of the reference pointing ADCS: the devices it reads and commands must exist, be of the right
    kind and have a host driver in the stand (not served); the rest is checked by its constructor."""
    options = t.raw("options", {})
    if not isinstance(options, dict):
        raise t.error("options", options, "a table of options of stand.adcs.pointing.PointingController")
    opt = Table(options, t._name("options"), t.source)
    opt.check_unknown(tuple(OPTIONS))

    for key, value in options.items():
        if unusable(value):
            raise opt.error(key, value, "finite numbers of normal size (no subnormals) and text without NUL bytes")
    if "modes" in options:
        opt.table("modes").check_unknown(tuple(f.name for f in fields(ModeConfig)))
    by_name = {d.name: d for d in devices}

    def check(key: str, name, kind: str) -> None:
        d = by_name.get(name) if isinstance(name, str) else None
        if d is None or d.kind != kind:
            have = [x.name for x in devices if x.kind == kind]
            raise opt.error(key, name, f"the name of a [[devices]] entry of kind {kind!r} "
                          f"({', '.join(have) or 'none in this scenario'})")
        if d.link == "served":
            raise opt.error(key, name, "a device the stand's controller can use: this one is served to a "
                          "flight computer outside (link = 'served'); use controller.kind = 'external'")

    if "gyro" not in options:
        raise opt.error("gyro", MISSING, "the name of the gyro the pointing controller reads")
    for key, kind in POINTING_DEVICES.items():
        if key in options:
            check(key, options[key], kind)
    wheels = options.get("wheels", [d.name for d in devices if d.kind == "reaction_wheel"])
    if not isinstance(wheels, list) or len(wheels) < 3:
        raise opt.error("wheels", wheels, "a list of at least three reaction wheel device names")
    for name in wheels:
        check("wheels", name, "reaction_wheel")
    return {**options, "wheels": list(wheels), **_datasheets(t, options, by_name)}


ARCSEC_RAD = math.radians(1.0 / 3600.0)
DEG_H_RAD_S = math.radians(1.0) / 3600.0
#: What each datasheet gives, per device kind: key -> (default or MISSING if required, lo, hi), datasheet units.
DATASHEET_KEYS = {
    # 1-sigma noise of a solution, about the boresight's cross axes and about the boresight (roll).
    "star_tracker": {"noise_cross_arcsec": (MISSING, 0.0, 3600.0), "noise_roll_arcsec": (MISSING, 0.0, 3600.0)},
    # Angle random walk, rate random walk and the bound on the turn-on bias (taken as 3 sigma): what the MEKF's
    # model holds. A bias instability is a bounded, correlated wander its random-walk bias cannot represent (turned
    # into a random walk it made the bias estimate noisy and the knowledge through a 900 s tracker outage 50 %
    # worse): the filter does not take it, and the simulated gyro's instability stays an unmodelled error.
    "gyro": {"arw_deg_sqrt_h": (MISSING, 0.0, 100.0), "rrw_deg_h_sqrt_h": (MISSING, 0.0, 1e4),
             "turn_on_bias_deg_h": (MISSING, 0.0, 1e5)},
}
#: The filter options each kind's datasheet sets (they cannot be given beside it).
DATASHEET_OPTIONS = {"star_tracker": ("tracker_sigma_rad",),
                     "gyro": ("gyro_arw_rad_s05", "gyro_rrw_rad_s15", "sigma_bias_rad_s")}
#: The smallest tracker noise handed to the filter (arcsec): a noiseless tracker still quantises its quaternion.
MIN_TRACKER_SIGMA_ARCSEC = 0.5


def _datasheets(t: Table, options: dict, by_name: dict) -> dict:
    """The reference ADCS's filter tuning from the datasheets the scenario declares, ``[controller.datasheet.NAME]``
    for the star tracker and the gyro it uses, each noise figure times ``controller.datasheet_margin``: what a
    flight team knows, never the simulated device's own settings (which may differ; docs/adcs.md)."""
    sheets = t.table("datasheet", required=False)
    margin = t.number("datasheet_margin", 1.0, lo=1.0, hi=10.0)
    out: dict = {}
    for role, kind in (("star_tracker", "star_tracker"), ("gyro", "gyro")):
        name = options.get(role)
        if name is None:
            continue
        given = [k for k in DATASHEET_OPTIONS[kind] if k in options]
        if not sheets.has(name):
            if len(given) < len(DATASHEET_OPTIONS[kind]):
                raise sheets.error(name, MISSING, f"the datasheet of the {kind.replace('_', ' ')} the ADCS is tuned "
                                   f"from: a table [controller.datasheet.{name}] of "
                                   f"{', '.join(DATASHEET_KEYS[kind])} (or the options "
                                   f"{', '.join(DATASHEET_OPTIONS[kind])})")
            continue
        if given:
            raise sheets.error(name, sheets.raw(name), f"a datasheet or the option {given[0]}, not both (the datasheet "
                               "sets it)")
        sheet = sheets.table(name)
        v = {k: sheet.number(k, d, lo=lo, hi=hi) for k, (d, lo, hi) in DATASHEET_KEYS[kind].items()}
        sheet.check_unknown()
        if kind == "star_tracker":
            out["tracker_sigma_rad"] = [max(v[k], MIN_TRACKER_SIGMA_ARCSEC) * ARCSEC_RAD * margin
                                        for k in ("noise_cross_arcsec", "noise_roll_arcsec")]
        else:
            out.update(_gyro_tuning(v, margin))
    sheets.check_unknown()
    if not out:
        t.refuse_unused("datasheet_margin", "a controller without datasheets", "remove it, or declare the "
                        "datasheets of the tracker and the gyro in [controller.datasheet.NAME] tables")
    return out


def _gyro_tuning(v: dict, margin: float) -> dict:
    """MEKF noise from a gyro datasheet, each figure times the margin."""
    arw = v["arw_deg_sqrt_h"] * math.radians(1.0) / 60.0
    rrw = v["rrw_deg_h_sqrt_h"] * DEG_H_RAD_S / 60.0
    # Floors far below any real gyro keep the covariance from collapsing to zero with a perfect datasheet.
    return {"gyro_arw_rad_s05": max(arw * margin, 1e-12), "gyro_rrw_rad_s15": max(rrw * margin, 1e-15),
            "sigma_bias_rad_s": max(v["turn_on_bias_deg_h"] * DEG_H_RAD_S / 3.0 * margin, 1e-12)}


def pointing_options(sc) -> dict:
    """The options of ``controller.kind = "pointing"`` with what the scenario already says filled in (an option
    the scenario gives wins): the spacecraft inertia, each device's mount, the wheels' axes, inertias and torque
    limit, the coarse sun heads' normals, and for nadir, target and sun guidance the orbit at t = 0 and the
    epoch. The filter's noise comes from the datasheets the scenario declares (:func:`_datasheets`), never from the
    simulated devices' own noise settings."""
    opts = dict(sc.controller.params["options"])
    specs = {d.name: d for d in sc.devices}
    opts.setdefault("inertia_kg_m2", np.asarray(sc.spacecraft.inertia_kg_m2, dtype=float).tolist())
    wheels = [specs[n] for n in opts["wheels"]]
    opts.setdefault("wheel_axes_B", [list(w.spin_axis_B) for w in wheels])
    opts.setdefault("wheel_inertia_kg_m2", [w.inertia_kg_m2 for w in wheels])
    opts.setdefault("max_wheel_torque_Nm", min(w.max_torque_Nm for w in wheels))
    if opts.get("fdir", True) is True:
        opts.setdefault("max_wheel_speed_rad_s", min(w.max_speed_rad_s for w in wheels))  # its wheel check's bound
    if "star_tracker" in opts:
        st = specs[opts["star_tracker"]]
        opts.setdefault("star_tracker_q_TB", st.q_SB.tolist())
    opts.setdefault("gyro_q_SB", specs[opts["gyro"]].q_SB.tolist())
    for key in ("magnetorquer", "sun_sensor"):
        if key in opts:
            opts.setdefault(f"{key}_q_SB", specs[opts[key]].q_SB.tolist())
    if "sun_sensor" in opts and specs[opts["sun_sensor"]].type == "coarse":
        # The controller solves for the Sun in the heads' own axes and then turns it through the mount.
        opts.setdefault("sun_sensor_normals_B", FACE_NORMALS.tolist())
    guidance = opts.get("guidance", "inertial")
    if guidance in ("nadir", "target"):
        r, v = sc.orbit.initial_state()
        opts.setdefault("orbit_r_N_m", r.tolist())
        opts.setdefault("orbit_v_N_m_s", v.tolist())
    if guidance in ("sun", "target"):
        opts.setdefault("epoch", sc.epoch.iso)
    return opts


class PointingKind(ControllerKind):
    name = "pointing"
    keys = ("rate_hz", "budget_s", "options", "datasheet", "datasheet_margin")
    row_floats = 25
    column_meanings = {
        "adcs_q_BN_est": "the attitude estimate, body relative to inertial, scalar first (NaN before the filter)",
        "adcs_bias_est_B": "the gyro bias estimate, body axes",
        "adcs_sigma3_B": "the estimate's 3-sigma attitude uncertainty about each body axis",
        "adcs_mode": "the mode (0 detumble, 1 Sun acquisition, 2 fine pointing)",
        "adcs_gyro_only": "1 while the estimate propagates on the gyro alone (no valid tracker solution)",
        "adcs_q_RN": "the commanded (reference) attitude, relative to inertial, scalar first",
        "adcs_wheel_torque_cmd": "the torque commanded to each wheel, in the order of the scenario's wheels",
        "adcs_dipole_cmd_B": "the dipole commanded for momentum dumping, body axes",
        "adcs_fdir": "the FDIR's flags (1 a wheel isolated, 2 the gyro failed: rate from the tracker, 4 a tracker "
                     "solution rejected, 8 a device lost; docs/faults.md)"}
    # Read from the controller's telemetry columns by convention (stand.adcs.metrics): a plug-in that records the
    # same columns gets them too. They all take at_s, the settle time.
    metrics = {**METRICS, **FAULT_METRICS}  # the fault metrics name their fault, not a time
    metrics_at = tuple(METRICS)

    def parse_params(self, t: Table, rate_hz: float, step_s: float, devices, params: dict) -> None:
        params["options"] = _pointing(t, devices)

    def check_scenario(self, scenario) -> None:
        """Construct the controller over unopened devices, so a bad option is a ScenarioError at load."""
        try:
            self.check(scenario, None)
        except PluginError as exc:
            text = str(exc).removeprefix("controller.kind = 'pointing': ").rstrip(".")
            m = re.match(r"options\.(\w+)", text)
            options = scenario.controller.params["options"]
            key = m.group(1) if m else None
            if key and "; " in text:
                text = text.split("; ", 1)[1]  # the rule only: the value is shown once, shortened, by the error
            text = " ".join(text.split())[:300]
            raise ScenarioError(f"controller.options.{key}" if key else "controller.options",
                                options.get(key, MISSING) if key else sorted(options)[:20],
                                f"an option PointingController accepts ({text})", scenario.source) from None

    def build(self, scenario, devices: dict, base: Path | None):
        return self._construct(scenario, {name: d.host for name, d in devices.items()})

    def check(self, scenario, base: Path | None) -> None:
        self._construct(scenario, not_opened(scenario))

    @staticmethod
    def _construct(scenario, hosts: dict) -> PointingController:
        try:
            return PointingController(hosts, 1.0 / scenario.controller.rate_hz, **pointing_options(scenario))
        except Exception as exc:  # options of any type reach the constructor: every refusal is one sentence
            raise PluginError(f"controller.kind = 'pointing': {exc}") from None


KIND = PointingKind()
