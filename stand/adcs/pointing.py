"""The reference pointing ADCS as a plug-in: ``PointingController(devices, period_s, **options)``.

Written only against host drivers, by the names the options give (the plug-in API of :mod:`stand.adcs`):

* star tracker ``take_solution()`` -> None or a solution with ``.q_TN`` (tracker frame in GCRS; ``.q`` is
  accepted too) and ``.valid``;
* gyro ``take_rate()`` -> None or a sample with ``.omega_rad_s`` (sensor axes) and ``.valid``;
* reaction wheels ``take_speed()`` -> None, a speed in rad/s, or a sample with ``.speed_rad_s``; and
  ``command_torque(torque_Nm)`` (motor torque on the rotor about its spin axis);
* magnetorquer (optional) ``take_sample()`` (``.b_T`` sensor axes, ``.valid``, ``.coil_active``) and
  ``command_dipole(m_A_m2, duration_s)``;
* sun sensor (optional) ``take_sun()`` -> a fine sample (``.angles_rad`` = atan2(s_x, s_z), atan2(s_y, s_z)) or a
  coarse one (``.currents_A``, with ``sun_sensor_normals_B`` given), and ``.valid``.

Each ``update(t_s)``: read the sensors, propagate the MEKF on the gyro and update it with a valid tracker
solution (:mod:`.determination`), run the mode manager (:mod:`.modes`), compute the reference
(:mod:`.guidance`) and the control torque (:mod:`.control`), and command the wheels (and the
magnetorquer for momentum dumping). Options (SI units; mounts are ``q_SB``: sensor frame relative to body):

``inertia_kg_m2`` (required), ``star_tracker``, ``star_tracker_q_TB``, ``tracker_sigma_rad`` (cross, roll),
``gyro``, ``gyro_q_SB``, ``gyro_arw_rad_s05``, ``gyro_rrw_rad_s15``, ``wheels`` (names), ``wheel_axes_B``
(one 3-vector per wheel; default body x, y, z for three wheels, the 54.74 deg pyramid about +z for
four), ``wheel_inertia_kg_m2``, ``max_wheel_torque_Nm``, ``wheel_speed_target_rad_s``,
``null_gain_per_s``, ``magnetorquer``, ``magnetorquer_q_SB``, ``dump_gain_per_s``, ``max_dipole_A_m2``,
``h_target_B``, ``sun_sensor``, ``sun_sensor_q_SB``, ``sun_sensor_normals_B``, ``sun_axis_B``,
``guidance`` (``"inertial"`` with ``q_RN``; ``"nadir"`` with ``orbit_r_N_m``, ``orbit_v_N_m_s`` at t = 0;
``"sun"`` with ``epoch`` (ISO UTC) and ``secondary_N``; ``"target"`` with the orbit, ``epoch`` and
``target_itrs_m``), ``law`` (``"mrp"`` or ``"quaternion"``), ``natural_frequency_rad_s``,
``damping_ratio``, ``detumble_gain_N_m_s``, ``initial_mode``, ``modes`` (a dict of
:class:`~.modes.ModeConfig` fields), ``gate_sigma``, ``wheel_coulomb_Nm`` and ``wheel_viscous_Nm_s`` (datasheet
friction fed forward), and the FDIR's (:mod:`.fdir`): ``fdir`` (default true), ``fdir_window_s``,
``fdir_wheel_threshold_Nm``, ``fdir_persist``, ``fdir_lost_s``, ``fdir_gyro_stuck_samples``,
``max_wheel_speed_rad_s``.
"""

from __future__ import annotations

import math

import numpy as np

from sim.rotations import dcm

from . import fdir as fdir_mod
from . import guidance as gd
from .control import LAWS, WheelDistribution, control_torque, dumping_dipole, pd_gains
from .determination import MEKF
from .modes import DETUMBLE, FINE_POINTING, MODES, SUN_ACQUISITION, ModeConfig, ModeManager
from .quat import add, conj, cross, finite3, mat3, mv, norm, normalised, positive, qmul, scale, sub

__all__ = ["PointingController", "default_wheel_axes_B"]

MODE_CODES = {m: float(i) for i, m in enumerate(MODES)}
OMEGA_EARTH_RAD_S = 7.292115e-5
GUIDANCE = ("inertial", "nadir", "sun", "target")
#: The options the constructor takes.
OPTIONS = frozenset({"inertia_kg_m2", "star_tracker", "star_tracker_q_TB", "tracker_sigma_rad", "gyro", "gyro_q_SB",
    "gyro_arw_rad_s05", "gyro_rrw_rad_s15", "wheels", "wheel_axes_B", "wheel_inertia_kg_m2",
    "max_wheel_torque_Nm", "wheel_speed_target_rad_s", "null_gain_per_s", "magnetorquer",
    "magnetorquer_q_SB", "dump_gain_per_s", "max_dipole_A_m2", "h_target_B", "sun_sensor",
    "sun_sensor_q_SB", "sun_sensor_normals_B", "sun_axis_B", "guidance", "q_RN", "orbit_r_N_m",
    "orbit_v_N_m_s", "epoch", "secondary_N", "target_itrs_m", "law", "natural_frequency_rad_s",
    "damping_ratio", "detumble_gain_N_m_s", "initial_mode", "modes", "gate_sigma", "initial_bias_rad_s",
    "sigma_bias_rad_s", "wheel_coulomb_Nm", "wheel_viscous_Nm_s", *fdir_mod.OPTIONS})
#: Control periods of on-board orbit solved in one vectorised call.
ORBIT_BATCH = 1000


def default_wheel_axes_B(n: int) -> np.ndarray:
    """Spin axes (3 x n): body x, y, z for three wheels; a pyramid about +z at 54.74 deg for four."""
    if n == 3:
        return np.eye(3)
    if n == 4:
        tilt = math.acos(1.0 / math.sqrt(3.0))
        az = np.radians([0.0, 90.0, 180.0, 270.0])
        return np.stack((math.sin(tilt) * np.cos(az), math.sin(tilt) * np.sin(az), np.full(4, math.cos(tilt))))
    raise ValueError(f"wheels: {n} names given and no wheel_axes_B; defaults exist for 3 (orthogonal) or 4 "
                     "(pyramid) wheels only; give wheel_axes_B.")


def _option_vec(options, name, n, default=None):
    v = options.get(name, default)
    a = np.asarray(v, dtype=float)
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ValueError(f"options.{name} = {v!r}; it must be {n} finite numbers.")
    return a


def _mount(options, name) -> np.ndarray:
    q = _option_vec(options, name, 4, (1.0, 0.0, 0.0, 0.0))
    if abs(np.linalg.norm(q) - 1.0) > 1e-6:
        raise ValueError(f"options.{name} = {options.get(name)!r}; a unit quaternion [w, x, y, z] is required.")
    return q


def _positive(options, name, default):
    v = options.get(name, default)
    if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
        raise ValueError(f"options.{name} = {v!r}; it must be a finite positive number.")
    return float(v)


def _count(options, name, lo: int, what: str) -> int:
    v = options.get(name, fdir_mod.OPTIONS[name])
    if not (isinstance(v, int) and not isinstance(v, bool) and lo <= v <= 1000):
        raise ValueError(f"options.{name} = {v!r}; a whole number of {what} from {lo} to 1000.")
    return v


def _non_negative(options, name):
    v = options.get(name, 0.0)
    if not (isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and v >= 0):
        raise ValueError(f"options.{name} = {v!r}; it must be a finite number >= 0.")
    return float(v)


def _finite3_or_none(v) -> tuple | None:
    """``v`` as 3 floats, or None unless it is 3 finite numbers (a sensor's sample, refused without an error)."""
    try:
        return finite3(v, "sample", ValueError)
    except ValueError:
        return None


def _unit_quat_or_none(q) -> tuple | None:
    """``q`` normalised, or None unless it is 4 finite numbers of norm within 1e-3 of 1."""
    try:
        if isinstance(q, np.ndarray) and q.shape != (4,):
            return None
        a, b, c, d = q
        w, x, y, z = float(a), float(b), float(c), float(d)
    except (TypeError, ValueError):
        return None
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return normalised((w, x, y, z)) if math.isfinite(n) and abs(n - 1.0) <= 1e-3 else None


def _speed_of(sample):
    if sample is None:
        return None
    if isinstance(sample, (int, float)):  # noqa: UP038 - a tuple: isinstance with a union is slower
        return float(sample)
    if not getattr(sample, "valid", True):
        return None
    return float(sample.speed_rad_s)



def _inertia_option(options: dict) -> np.ndarray:
    """``options.inertia_kg_m2`` as a 3 x 3 matrix (3 principal moments or the matrix itself)."""
    if "inertia_kg_m2" not in options:
        raise ValueError("options.inertia_kg_m2 is required (3 principal moments or a 3 x 3 matrix, kg m^2).")
    I = np.asarray(options["inertia_kg_m2"], dtype=float)
    inertia = np.diag(I) if I.shape == (3,) else I
    if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)):
        raise ValueError(f"options.inertia_kg_m2 = {options['inertia_kg_m2']!r}; 3 moments or a 3 x 3 matrix.")
    return inertia


def _wheels_option(options: dict, devices: dict) -> list:
    """The host drivers of the wheels ``options.wheels`` names (at least three), in that order."""
    names = options.get("wheels")
    if not isinstance(names, list | tuple) or len(names) < 3:
        raise ValueError(f"options.wheels = {names!r}; name at least three reaction wheels.")
    for name in names:
        if name not in devices:
            raise ValueError(f"options.wheels names {name!r}, which is not a device; devices: {sorted(devices)}.")
    return [devices[name] for name in names]

class PointingController:
    """Detumble, sun acquisition and fine pointing over a star tracker, a gyro and reaction wheels."""

    def __init__(self, devices: dict, period_s: float, **options):
        known = OPTIONS
        unknown = sorted(set(options) - known)
        if unknown:
            raise ValueError(f"options {unknown} are not PointingController options; allowed: {sorted(known)}.")
        if not (isinstance(period_s, int | float) and math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"period_s = {period_s!r}; the control period must be a positive number of seconds.")
        self.period_s = float(period_s)
        self.inertia = _inertia_option(options)

        def device(key, required=False):
            name = options.get(key)
            if name is None:
                if required:
                    raise ValueError(f"options.{key} must name a device; devices: {sorted(devices)}.")
                return None
            if name not in devices:
                raise ValueError(f"options.{key} = {name!r} is not a device of this scenario; devices: "
                                 f"{sorted(devices)}.")
            return devices[name]

        self.tracker_name, self.gyro_name, self.mtq_name = (options.get(k) for k in ("star_tracker", "gyro",
                                                                                      "magnetorquer"))
        self.wheel_names = list(options.get("wheels") or ())
        self.tracker = device("star_tracker")
        self.gyro = device("gyro", required=True)
        self.mtq = device("magnetorquer")
        self.sun_sensor = device("sun_sensor")
        self.wheels = _wheels_option(options, devices)
        n = len(self.wheels)
        axes = options.get("wheel_axes_B")
        A = default_wheel_axes_B(n) if axes is None else np.asarray(axes, dtype=float).T
        if A.shape != (3, n):
            raise ValueError(f"options.wheel_axes_B = {axes!r}; give one 3-vector per wheel ({n}).")
        self.max_wheel_torque = _positive(options, "max_wheel_torque_Nm", 0.01)
        self.dist = WheelDistribution(A, self.max_wheel_torque)
        J = np.broadcast_to(np.asarray(options.get("wheel_inertia_kg_m2", 0.0), dtype=float), (n,)).copy()
        if not np.all(np.isfinite(J)) or np.any(J <= 0):
            raise ValueError(f"options.wheel_inertia_kg_m2 = {options.get('wheel_inertia_kg_m2')!r}; give the rotors' "
                             "spin inertia (kg m^2, one value or one per wheel).")
        self.wheel_inertia = J
        self.speed_target = float(options.get("wheel_speed_target_rad_s", 0.0))
        # The wheels' bearing friction from their datasheet, fed forward (0: none): without it a spin-biased cluster
        # leaves a steady pointing error of friction / stiffness, as the PD law has no integral term.
        self.wheel_coulomb = _non_negative(options, "wheel_coulomb_Nm")
        self.wheel_viscous = _non_negative(options, "wheel_viscous_Nm_s")
        self.null_gain = float(options.get("null_gain_per_s", 0.0))
        self.q_TB = _mount(options, "star_tracker_q_TB")
        self._q_BT = conj(tuple(self.q_TB.tolist()))
        self.dcm_BS_gyro = mat3(dcm(_mount(options, "gyro_q_SB")).T)
        self.dcm_BS_mtq = dcm(_mount(options, "magnetorquer_q_SB")).T
        self.dcm_BS_sun = dcm(_mount(options, "sun_sensor_q_SB")).T
        sig = _option_vec(options, "tracker_sigma_rad", 2, (math.radians(5.0 / 3600.0), math.radians(40.0 / 3600.0)))
        C_BT = dcm(self.q_TB).T
        self.R_tracker_B = C_BT @ np.diag([sig[0] ** 2, sig[0] ** 2, sig[1] ** 2]) @ C_BT.T
        self.arw = float(options.get("gyro_arw_rad_s05", 1e-5))
        self.rrw = float(options.get("gyro_rrw_rad_s15", 1e-7))
        self.initial_bias = tuple(_option_vec(options, "initial_bias_rad_s", 3, (0.0, 0.0, 0.0)).tolist())
        self.sigma_bias = _positive(options, "sigma_bias_rad_s", 1e-4)
        self.gate_sigma = options.get("gate_sigma")
        self.fdir = self._setup_fdir(options)
        self.law = options.get("law", "mrp")
        if self.law not in LAWS:
            raise ValueError(f"options.law = {self.law!r}; allowed: {', '.join(LAWS)}.")
        wn = self.natural_frequency = _positive(options, "natural_frequency_rad_s", 0.1)
        self.K, self.P = pd_gains(self.inertia, wn, _positive(options, "damping_ratio", 0.9), self.law)
        self._inertia_rows, self._P_rows = mat3(self.inertia), mat3(self.P)
        self.detumble_gain = _positive(options, "detumble_gain_N_m_s", float(np.max(np.diag(self.inertia))) * 0.1)
        self.dump_gain = float(options.get("dump_gain_per_s", 0.0))
        self.max_dipole = _positive(options, "max_dipole_A_m2", 0.2)
        self.h_target = _option_vec(options, "h_target_B", 3, (0.0, 0.0, 0.0))
        self.sun_axis_B = _option_vec(options, "sun_axis_B", 3, (0.0, 0.0, 1.0))
        self.sun_axis_B = self.sun_axis_B / np.linalg.norm(self.sun_axis_B)
        normals = options.get("sun_sensor_normals_B")
        self.sun_normals = None if normals is None else np.asarray(normals, dtype=float)
        self._setup_guidance(options)
        mode = options.get("initial_mode", DETUMBLE)
        if mode not in MODES:
            raise ValueError(f"options.initial_mode = {mode!r}; allowed: {', '.join(MODES)}.")
        self.modes = ModeManager(ModeConfig(**options.get("modes", {})), mode)
        self.filter: MEKF | None = None
        self._t_prev: float | None = None
        self._omega_meas_B: tuple | None = None  # the gyro's rate in body axes (rad/s)
        self._speeds = np.zeros(n)
        self._b_B: np.ndarray | None = None
        self.last_wheel_cmd = np.zeros(n)
        self.last_dipole = np.zeros(3)
        self.last_q_RN = (1.0, 0.0, 0.0, 0.0)
        self._w_RN_prev: tuple | None = None  # (t_s, omega_RN_R) of the last fine-pointing period
        self.counters = {"tracker_used": 0, "tracker_invalid": 0, "gyro_missing": 0, "gyro_rejected": 0}
        self._asked_tracker_s = -math.inf  # when the FDIR last asked a silent tracker for solutions again
        self._fresh_speeds = np.full(n, math.nan)  # this period's wheel speeds, NaN where none came (for the FDIR)
        self._keep: list[int] | None = None  # the wheels still used after an isolation (None: all)

    def _setup_fdir(self, options) -> fdir_mod.Fdir | None:
        """The FDIR (:mod:`.fdir`) unless ``options.fdir`` is false; its wheel threshold from the datasheet torque."""
        on = options.get("fdir", True)
        if not isinstance(on, bool):
            raise ValueError(f"options.fdir = {on!r}; true or false.")
        if not on:
            for key in fdir_mod.OPTIONS:
                if key != "fdir" and key in options:
                    raise ValueError(f"options.{key} = {options[key]!r} is unused with options.fdir = false; "
                                     "remove it.")
            return None
        if self.gate_sigma is None:
            self.gate_sigma = fdir_mod.GATE_SIGMA
        threshold = options.get("fdir_wheel_threshold_Nm")
        threshold = 0.25 * self.max_wheel_torque if threshold is None else _positive(options, "fdir_wheel_threshold_Nm",
                                                                                     None)
        persist = _count(options, "fdir_persist", 1, "control periods")
        stuck = _count(options, "fdir_gyro_stuck_samples", 0, "gyro samples (0: no frozen-output check)")
        window = _positive(options, "fdir_window_s", fdir_mod.OPTIONS["fdir_window_s"])
        max_speed = options.get("max_wheel_speed_rad_s")
        max_speed = math.inf if max_speed is None else _positive(options, "max_wheel_speed_rad_s", None)
        monitor = fdir_mod.WheelMonitor(self.wheel_inertia, max_speed, self.period_s, window, threshold, persist)
        # The sun sensor is read in sun acquisition only: its silence elsewhere is no fault.
        names = [options[k] for k in ("gyro", "star_tracker", "magnetorquer") if options.get(k)]
        return fdir_mod.Fdir(monitor, _positive(options, "fdir_lost_s", fdir_mod.OPTIONS["fdir_lost_s"]),
                             names + list(options["wheels"]), stuck)

    # -- guidance -----------------------------------------------------------------------------------
    def _setup_guidance(self, options) -> None:
        kind = options.get("guidance", "inertial")
        if kind not in GUIDANCE:
            raise ValueError(f"options.guidance = {kind!r}; allowed: {', '.join(GUIDANCE)}.")
        self.guidance = kind
        self.q_RN = None
        self._orbit_cache = None
        self._earth = None
        if kind == "inertial":
            self.q_RN, _ = gd.inertial(_option_vec(options, "q_RN", 4, (1.0, 0.0, 0.0, 0.0)))
        if kind in ("nadir", "target"):
            self.r0 = _option_vec(options, "orbit_r_N_m", 3)
            self.v0 = _option_vec(options, "orbit_v_N_m_s", 3)
        if kind in ("sun", "target"):
            from sim.time import Epoch

            if "epoch" not in options:
                raise ValueError(f"options.guidance = {kind!r} needs options.epoch (ISO 8601 UTC of t = 0).")
            self.epoch = Epoch.from_iso(options["epoch"])
        if kind == "sun":
            self.secondary_N = _option_vec(options, "secondary_N", 3, (0.0, 0.0, 1.0))
        if kind == "target":
            self.target_itrs = _option_vec(options, "target_itrs_m", 3)

    def reference(self, t_s: float):
        """``(q_RN, omega_RN_R)`` at ``t_s`` for the configured guidance."""
        if self.guidance == "inertial":
            return self.q_RN, (0.0, 0.0, 0.0)
        if self.guidance == "sun":
            from sim.environment import sun_position_gcrs

            return gd.sun_pointing(sun_position_gcrs(self.epoch + t_s), self.secondary_N, self.sun_axis_B)
        r, v = self._orbit(t_s)
        if self.guidance == "nadir":
            return gd.nadir(r, v)
        if self._earth is None:
            from sim.frames import EarthRotation

            self._earth = EarthRotation(self.epoch)  # precession-nutation on a coarse grid, cheap per call
        rt = self._earth.dcm_itrs_gcrs(t_s).T @ self.target_itrs  # the matrix maps GCRS to ITRS
        vt = cross([0.0, 0.0, OMEGA_EARTH_RAD_S], rt)
        return gd.target_pointing(r, v, rt, vt)

    def _orbit(self, t_s: float):
        """On-board two-body orbit from the state at t = 0: solved for the next ORBIT_BATCH control times at once
        (one vectorised call), looked up while the controller keeps its period."""
        k = round(t_s / self.period_s)
        cache = self._orbit_cache
        if cache is not None and cache[0] <= k < cache[0] + len(cache[1]) and abs(k * self.period_s - t_s) < 1e-9:
            i = k - cache[0]
            return cache[1][i], cache[2][i]
        from sim.orbit import propagate_kepler

        if abs(k * self.period_s - t_s) >= 1e-9:  # off the control grid: one state
            return propagate_kepler(self.r0, self.v0, t_s)
        r, v = propagate_kepler(self.r0, self.v0, (k + np.arange(ORBIT_BATCH)) * self.period_s)
        self._orbit_cache = (k, r, v)
        return r[0], v[0]

    # -- the plug-in API --------------------------------------------------------------------------------
    def telemetry_columns(self) -> list[tuple[str, int, str]]:
        cols = [("adcs_q_BN_est", 4, ""), ("adcs_bias_est_B", 3, "rad/s"), ("adcs_sigma3_B", 3, "rad"),
                ("adcs_mode", 1, ""), ("adcs_gyro_only", 1, ""),
                ("adcs_q_RN", 4, ""), ("adcs_wheel_torque_cmd", len(self.wheels), "N m")]
        if self.mtq is not None:
            cols.append(("adcs_dipole_cmd_B", 3, "A m^2"))
        cols.append(("adcs_fdir", 1, ""))  # bit flags, stand.adcs.fdir.FLAGS (0 with the FDIR off)
        return cols

    def telemetry(self) -> tuple:
        f = self.filter
        q = tuple(f.q) if f is not None else (math.nan,) * 4
        b = tuple(f.bias) if f is not None else (math.nan,) * 3
        s = tuple(f.sigma3_attitude_rad) if f is not None else (math.nan,) * 3
        row = (*q, *b, *s, MODE_CODES[self.modes.mode], float(self.modes.gyro_only), *self.last_q_RN,
               *self.last_wheel_cmd)
        if self.mtq is not None:
            row += tuple(self.last_dipole)
        row += (self.fdir.flags if self.fdir is not None else 0,)
        return tuple(map(float, row))

    def update(self, t_s: float) -> None:
        dt = 0.0 if self._t_prev is None else t_s - self._t_prev
        self._t_prev = t_s
        w_prev = self._omega_meas_B
        fd = self.fdir
        self._read_gyro(t_s)
        self._read_wheels(t_s)
        self._read_magnetometer(t_s)
        q_meas = self._read_tracker(t_s)
        if fd is not None:
            self._fdir_sense(t_s)
        w = self._omega_meas_B
        if self.filter is not None and w is not None:
            # The rate over the last period: the mean of its end samples (second order while slewing).
            self.filter.propagate(w if w_prev is None else scale(0.5, add(w, w_prev)), dt)
        fix = q_meas is not None
        if q_meas is not None:
            if self.filter is None:
                # The first solution is the estimate: its uncertainty is the tracker's.
                sigma0 = math.sqrt(float(np.max(np.linalg.eigvalsh(self.R_tracker_B))))
                self.filter = MEKF(q_meas, self.initial_bias, sigma_attitude_rad=sigma0,
                                   sigma_bias_rad_s=self.sigma_bias, arw_rad_s05=self.arw, rrw_rad_s15=self.rrw)
                accepted = True
            else:
                accepted = self.filter.update_attitude(q_meas, self.R_tracker_B, self.gate_sigma,
                                                       self._gate_slack_rad2() if fd is not None else 0.0)
            if fd is not None:
                # A rejected solution is no fix: the mode manager counts the outage, the rate fall-back skips it.
                fix = accepted
                fd.tracker_rejected = not accepted
                if accepted:
                    fd.tracker_solution(t_s, q_meas)
        rate = self._rate_B()
        sigma3 = max(self.filter.sigma3_attitude_rad) if self.filter is not None else math.inf
        mode = self.modes.update(t_s, norm(rate), fix, sigma3)
        h_w = tuple(self.dist.momentum_B(self._speeds, self.wheel_inertia).tolist())
        if mode == FINE_POINTING and self.filter is not None:
            q_RN, w_RN = self.reference(t_s)
            self.last_q_RN = tuple(map(float, q_RN))
            w_RN = tuple(map(float, w_RN))
            # The reference's angular acceleration (R-frame derivative) by a backward difference over one period:
            # the feed-forward that keeps a slewing target (a ground pass) from lagging by alpha / wn^2.
            prev = self._w_RN_prev
            dt_RN = 0.0 if prev is None else t_s - prev[0]
            dw_RN = tuple((a - b) / dt_RN for a, b in zip(w_RN, prev[1], strict=True)) if prev is not None and (
                0.0 < dt_RN <= 1.5 * self.period_s) else (0.0, 0.0, 0.0)
            self._w_RN_prev = (t_s, w_RN)
            u_B = control_torque(self.filter.q, rate, q_RN, w_RN, self.inertia, self.K, self.P, h_w, dw_RN,
                                 law=self.law)
        elif mode == SUN_ACQUISITION:
            u_B = self._sun_acquisition_torque(rate, h_w)
        else:
            u_B = add(scale(-self.detumble_gain, rate), cross(rate, add(mv(self._inertia_rows, rate), h_w)))
        m_B = self._dump(h_w) if self.mtq is not None else None
        if m_B is not None and self._b_B is not None:
            u_B = sub(u_B, cross(m_B, self._b_B))  # the magnetic torque is already on the body
        cmd = self._allocate(u_B)
        for wheel, u in zip(self.wheels, cmd, strict=True):
            wheel.command_torque(float(u))
        self.last_wheel_cmd = cmd
        if fd is not None:
            fd.wheels.commanded(cmd)

    def _gate_slack_rad2(self) -> float:
        """The innovation gate's allowance for a solution's age (rad^2): the attitude turned through in three control
        periods at the present rate. The filter takes a solution as of now, so while the body turns a late one is off
        by its age times the rate; that is no lie, and the gate must not reject it."""
        w = self._omega_meas_B
        if w is None:
            return 0.0
        bias = self.filter.bias if self.filter is not None else self.initial_bias
        d = sub(w, bias)
        return (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) * (3.0 * self.period_s) ** 2

    def _allocate(self, u_B) -> np.ndarray:
        """Motor torques for the body torque ``u_B``: over every wheel, or over those left after an isolation (the
        pseudo-inverse of their spin axes; an isolated wheel is commanded zero)."""
        keep = self._keep
        if keep is None:
            cmd = self.dist.motor_torques(u_B, self._speeds, self.wheel_inertia, self.speed_target, self.null_gain)
        else:
            cmd = np.zeros(len(self.wheels))
            cmd[keep] = self._dist_kept.motor_torques(u_B, self._speeds[keep], self.wheel_inertia[keep],
                                                      self.speed_target, self.null_gain)
        if self.wheel_coulomb or self.wheel_viscous:
            w = self._speeds
            ff = self.wheel_coulomb * np.sign(w) + self.wheel_viscous * w
            if keep is not None:
                ff[[i for i in range(len(w)) if i not in keep]] = 0.0
            cmd = np.clip(cmd + ff, -self.max_wheel_torque, self.max_wheel_torque)
        return cmd

    def _fdir_sense(self, t_s: float) -> None:
        """The FDIR's checks of this period (after the sensors are read, before the filter and the control)."""
        fd = self.fdir
        fd.check_silence(t_s)
        if self.tracker_name in fd.lost:
            self._ask_tracker_again(t_s)
        if self.gyro_name in fd.lost:
            fd.gyro.silent(fd.silent_s(self.gyro_name, t_s))
        if fd.gyro.failed:
            w_B = fd.tracker_rate_B()
            if w_B is not None:
                bias = self.filter.bias if self.filter is not None else self.initial_bias
                self._omega_meas_B = add(w_B, bias)  # the filter and the control subtract the bias again
        for i in fd.wheels.update(self._fresh_speeds):
            if i not in fd.isolated:
                self._isolate(t_s, i)

    def _ask_tracker_again(self, t_s: float) -> None:
        """A tracker that stopped sending may have rebooted, and a reboot ends its subscriptions (its ICD): ask for
        solutions again, without waiting for the answer, once every lost_s while it stays silent."""
        ask = getattr(self.tracker, "request_solutions", None)
        if ask is None or t_s - self._asked_tracker_s < self.fdir.lost_s:
            return
        self._asked_tracker_s = t_s
        self.counters["tracker_resubscribed"] = self.counters.get("tracker_resubscribed", 0) + 1
        ask()

    def _isolate(self, t_s: float, i: int) -> None:
        fd = self.fdir
        keep = [k for k in range(len(self.wheels)) if k != i and k not in fd.isolated]
        name = self.wheel_names[i]
        r = fd.wheels.residual_Nm[i]
        try:
            if len(keep) < 3:
                raise ValueError("fewer than three wheels would be left")
            dist = WheelDistribution(self.dist.A[:, keep], self.max_wheel_torque)
        except ValueError as exc:
            if not any(name in what and "cannot be isolated" in what for _, what in fd.events):
                fd.events.append((t_s, f"{name} does not follow its commands but cannot be isolated: {exc}"))
            return
        fd.isolated.append(i)
        self._keep, self._dist_kept = keep, dist
        fd.events.append((t_s, f"{name} isolated: over {fd.wheels.window_s:g} s its speed change showed {r:+.3g} N m "
                               "beside the torque commanded"))

    # -- pieces -------------------------------------------------------------------------------------
    def _rate_B(self) -> tuple:
        if self._omega_meas_B is None:
            return 0.0, 0.0, 0.0
        bias = self.filter.bias if self.filter is not None else self.initial_bias
        return sub(self._omega_meas_B, bias)

    def _read_gyro(self, t_s: float) -> None:
        s = self.gyro.take_rate()
        fd = self.fdir
        if s is not None and fd is not None:
            fd.heard(self.gyro_name, t_s)
        if s is None or not getattr(s, "valid", True):
            self.counters["gyro_missing"] += 1
            if s is not None and fd is not None:
                fd.gyro.sample(None, False)
            return
        w = _finite3_or_none(s.omega_rad_s)
        if w is None:
            self.counters["gyro_rejected"] += 1  # flagged valid but unusable: flight code drops it, keeps flying
            if fd is not None:
                fd.gyro.sample(None, False)
            return
        if fd is not None:
            fd.gyro.sample(w, True)
        self._omega_meas_B = mv(self.dcm_BS_gyro, w)

    def _read_wheels(self, t_s: float) -> None:
        fd = self.fdir
        for i, wheel in enumerate(self.wheels):
            got = wheel.take_speed()
            s = _speed_of(got)
            if fd is not None:
                if got is not None:
                    fd.heard(self.wheel_names[i], t_s)
                self._fresh_speeds[i] = s if s is not None and math.isfinite(s) else math.nan
            if s is not None and math.isfinite(s):
                self._speeds[i] = s

    def _read_tracker(self, t_s: float):
        if self.tracker is None:
            return None
        sol = self.tracker.take_solution()
        if sol is None:
            return None
        if self.fdir is not None:
            self.fdir.heard(self.tracker_name, t_s)
        if not getattr(sol, "valid", True):
            self.counters["tracker_invalid"] += 1
            return None
        q_TN = _unit_quat_or_none(sol.q_TN if hasattr(sol, "q_TN") else sol.q)
        if q_TN is None:
            self.counters["tracker_invalid"] += 1
            return None
        self.counters["tracker_used"] += 1
        # q_BN = compose(conjugate(q_TB), q_TN) = q_TN (x) conjugate(q_TB) in Hamilton order
        return positive(qmul(q_TN, self._q_BT))

    def _read_magnetometer(self, t_s: float) -> None:
        if self.mtq is None:
            return
        s = self.mtq.take_sample()
        if s is not None and self.fdir is not None:
            self.fdir.heard(self.mtq_name, t_s)
        if s is not None and s.valid and not s.coil_active:
            self._b_B = self.dcm_BS_mtq @ np.asarray(s.b_T, dtype=float)

    def _sun_B(self):
        if self.sun_sensor is None:
            return None
        s = self.sun_sensor.take_sun()
        if s is None or not getattr(s, "valid", False):
            return None
        if getattr(s, "angles_rad", None) is not None:  # a coarse sample has no angles (or None)
            a, b = s.angles_rad
            v = np.array([math.tan(a), math.tan(b), 1.0])
        elif self.sun_normals is not None:
            v, *_ = np.linalg.lstsq(self.sun_normals, np.asarray(s.currents_A, dtype=float), rcond=None)
        else:
            return None
        n = float(np.linalg.norm(v))
        return None if not (math.isfinite(n) and n > 0) else self.dcm_BS_sun @ (v / n)

    def _sun_acquisition_torque(self, rate, h_w) -> tuple:
        gyro = cross(rate, add(mv(self._inertia_rows, rate), h_w))
        s = self._sun_B()
        if s is None:
            return add(scale(-self.detumble_gain, rate), gyro)
        # Turning the body about a x s brings the Sun (s, body axes) onto the axis a.
        # |a x s| ~ the angle off the Sun: the same stiffness per radian as fine pointing.
        k = self.natural_frequency ** 2 * float(np.max(np.linalg.eigvalsh(self.inertia)))
        return add(sub(scale(k, cross(self.sun_axis_B, s)), mv(self._P_rows, rate)), gyro)

    def _dump(self, h_w) -> np.ndarray:
        if self._b_B is None or self.dump_gain <= 0.0:
            self.last_dipole = np.zeros(3)
            return self.last_dipole
        m_B = dumping_dipole(self._b_B, sub(h_w, self.h_target), self.dump_gain, self.max_dipole)
        self.mtq.command_dipole(tuple(float(x) for x in self.dcm_BS_mtq.T @ m_B), self.period_s)
        self.last_dipole = m_B
        return m_B
