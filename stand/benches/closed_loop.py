"""Closed-loop work-precision for ``stand bench accuracy``: pointing and wheel-speed error against run time.

Two closed loops, each run by the stand's truth model (:class:`sim.truth.TruthModel` with its wheel cluster) at
the dynamics steps of :data:`STEPS_S` with every integrator a scenario may choose (:data:`INTEGRATORS`), the
controller at its own fixed rate with its wheel-torque command held between its ticks (zero-order hold):

* ``pointing``: ``fixtures/scenarios/pointing_star_tracker.toml`` loaded through the scenario loader with
  ``dynamics.step_s`` and ``dynamics.integrator`` overridden (the way a user picks them). Its truth (J2 orbit,
  gravity-gradient torque, four wheels in a pyramid at +-500 rpm) is built as ``stand.compose.build`` builds it;
  its controller is the reference ADCS itself (:class:`stand.adcs.pointing.PointingController`, MEKF, mode
  manager, MRP law, the scenario's options and datasheets) at the scenario's 10 Hz. A 0.2 s step cannot hold a
  10 Hz controller: the loader refuses it and the row says so.
* ``wheel_pointing``: three wheels on the body axes and MRP feedback on perfect navigation, modelled on Basilisk's
  scenarioAttitudeFeedbackRW (body diag(900, 800, 600) kg m^2, sigma_BN = (0.1, 0.2, -0.3), omega_BN_B = (0.001,
  -0.01, 0.03) rad/s, HR16 wheels of 50 N m s at 6000 rpm starting at 100, 200 and 300 rpm, 0.2 N m, K = 3.5 N m,
  P = 30 N m s, inertial target, 600 s, no environment torque), built here from the stand's pieces
  (:func:`stand.adcs.control.control_torque`, :class:`stand.adcs.control.WheelDistribution`). Its controller
  runs at 5 Hz so that every step of the grid, 0.2 s included, divides its period.

Without devices. The sensors are ideal (the truth's attitude, rate and wheel speeds, no noise, no delay) and the
wheel motors deliver the commanded torque exactly (no friction, no lag): the loop is then deterministic, so the
reference can run the same loop, and the only thing that changes between rows is the integration. The device
chain would add its own discretisation at the dynamics step (a motor lag and friction updated once per step and
held over it, sensor samples on the step grid): first-order effects of the step that would hide the integrator's
error and that no reference integrates the same way.

Reference. The same closed loop integrated by scipy's DOP853 (:data:`REF_RTOL`, :data:`REF_ATOL`) from one
control tick to the next, the command held constant over each piece, so the zero-order hold is exact and the
integrator never steps across a jump of the command. Its equations are written here again, on numpy, apart from
the truth model's float code (:func:`gyrostat_rhs`): the gyrostat of Schaub & Junkins sec. 4.5 with
gravity-gradient torque on the orbit the truth uses (the same J2 RK4 nodes, interpolated by scipy's cubic Hermite
spline). Errors are the largest over the control ticks of the run: the attitude angle between run and reference
(arcsec) and the wheel speed (rpm).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sim.constants import J2_EARTH, MU_EARTH, R_EARTH
from sim.orbit import propagate_j2
from sim.rotations import angle_between, dcm
from sim.time import NS_PER_S, seconds_to_ns
from sim.truth import TruthModel, compose_floats, rotate_to_body
from sim.wheels import WheelCluster

#: Dynamics steps of the grid (s).
STEPS_S = (0.2, 0.1, 0.05, 0.02, 0.01)
#: The fixed-step integrators a scenario's ``[dynamics] integrator`` may choose (stand.scenario.loader).
INTEGRATORS = ("rk4", "rkmk4", "implicit_midpoint")
#: DOP853 tolerances of the reference. Both ten times tighter move its result by 1.9e-11 arcsec (pointing scenario)
#: and 8.9e-10 arcsec (wheel case), below every error of the grid (the ``reference_self_check`` rows).
REF_RTOL = 1e-12
REF_ATOL = 1e-14
ARCSEC_PER_RAD = 180.0 * 3600.0 / math.pi
RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)
POINTING_SCENARIO = "pointing_star_tracker"


@dataclass
class Plant:
    """One closed loop's plant and controller, as both the fixed-step runs and the reference take them."""

    name: str
    inertia_kg_m2: np.ndarray  # whole spacecraft, wheels included as if locked (body axes)
    q_BN: tuple
    omega_BN_B: tuple
    wheels: WheelCluster
    speeds_rad_s: tuple  # relative to the body
    r_N_m: np.ndarray
    v_N_m_s: np.ndarray
    gravity: str  # the orbit's gravity ("point" or "j2")
    orbit_step_s: float
    torques: tuple  # environment torques: () or ("gravity_gradient",)
    control_period_s: float
    duration_s: float
    #: A fresh controller: ``(t_s, q_BN, omega_BN_B, speeds_rad_s) -> net torque on each rotor (N m)``.
    controller: Callable[[], Callable]

    def truth(self, step_s: float, integrator: str) -> TruthModel:
        return TruthModel(inertia=self.inertia_kg_m2, q_BN=self.q_BN, omega_BN_B=self.omega_BN_B, r_N=self.r_N_m,
                          v_N=self.v_N_m_s, step_ns=seconds_to_ns(step_s), gravity=self.gravity,
                          orbit_step_s=self.orbit_step_s, torques=self.torques, integrator=integrator,
                          wheels=self.wheels, wheel_speeds_rad_s=self.speeds_rad_s)

    @property
    def control_ticks(self) -> int:
        return seconds_to_ns(self.duration_s) // seconds_to_ns(self.control_period_s)


@dataclass
class Trajectory:
    """The state at every control tick (the instants the controller sees), and what the run cost."""

    t_s: np.ndarray
    q_BN: np.ndarray  # (n, 4)
    omega_BN_B: np.ndarray  # (n, 3) rad/s
    speeds_rad_s: np.ndarray  # (n, wheels) relative to the body
    wall_s: float = 0.0
    truth_s: float = 0.0
    cpu_s: float = 0.0  # the process's CPU time over the run: what the shared machine's load does not inflate
    #: The reference ADCS's mode changes ``(t_s, mode)`` (none for a controller without modes).
    modes: list = field(default_factory=list)


def _modes(command) -> list:
    adcs = getattr(command, "adcs", None)
    return [] if adcs is None else [(t, to) for t, _, to, _ in adcs.modes.transitions]


# -- the pointing scenario's loop ---------------------------------------------------------------------------------
class _Reading:
    """What an ideal sensor hands the reference ADCS: the fields its host drivers' samples have."""

    __slots__ = ("omega_rad_s", "q_TN", "valid")

    def __init__(self, q_TN=None, omega_rad_s=None):
        self.q_TN, self.omega_rad_s, self.valid = q_TN, omega_rad_s, True


class _IdealHosts:
    """Host drivers that read the truth exactly: tracker (q_TN), gyro (sensor axes), wheel speeds; the wheels'
    ``command_torque`` is kept as the net rotor torque."""

    def __init__(self, q_TB, q_SB_gyro, n_wheels: int):
        self.q_TB, self.q_SB = tuple(q_TB), tuple(q_SB_gyro)
        self.state = ((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0,) * n_wheels)
        self.commands = [0.0] * n_wheels

    def take_solution(self):
        return _Reading(q_TN=np.array(compose_floats(self.q_TB, self.state[0])))

    def take_rate(self):
        return _Reading(omega_rad_s=np.array(rotate_to_body(self.q_SB, self.state[1])))

    def wheel(self, i: int):
        hosts = self

        class Wheel:
            def take_speed(self):
                return hosts.state[2][i]

            def command_torque(self, torque_Nm):
                hosts.commands[i] = float(torque_Nm)

        return Wheel()


def pointing_plant(step_s: float = 0.1, integrator: str = "rk4", duration_s: float | None = None):
    """The pointing scenario with ``step_s`` and ``integrator`` as a user sets them, as a :class:`Plant`; raises the
    loader's ``ScenarioError`` when the scenario refuses them."""
    from stand.compose import initial_state, wheel_cluster
    from stand.controllers.pointing import pointing_options
    from stand.scenario import load

    sc = load(POINTING_SCENARIO, [f"dynamics.step_s={step_s!r}", f'dynamics.integrator="{integrator}"'])
    wheels, speeds, index = wheel_cluster(sc)
    options = pointing_options(sc)
    period_s = 1.0 / sc.controller.rate_hz

    def controller():
        from stand.adcs.pointing import PointingController

        hosts = _IdealHosts(options.get("star_tracker_q_TB", (1.0, 0.0, 0.0, 0.0)), options["gyro_q_SB"],
                            wheels.n)
        devices = {options["star_tracker"]: hosts, options["gyro"]: hosts}
        devices.update({name: hosts.wheel(index[name]) for name in options["wheels"]})
        adcs = PointingController(devices, period_s, **options)

        def command(t_s, q, w, speeds_rad_s):
            hosts.state = (tuple(q), tuple(w), tuple(speeds_rad_s))
            adcs.update(t_s)
            return tuple(hosts.commands)  # each wheel's host wrote its own column

        command.adcs = adcs  # the mode transitions, for the rows
        return command

    r0, v0 = initial_state(sc)
    return Plant(POINTING_SCENARIO, np.asarray(sc.spacecraft.inertia_kg_m2, float), tuple(sc.spacecraft.q_BN),
                 tuple(sc.spacecraft.omega_BN_B), wheels, tuple(speeds), r0, v0, sc.orbit.gravity, sc.orbit.step_s,
                 tuple(sc.torques), period_s, sc.duration_s if duration_s is None else duration_s, controller)


# -- the wheel-pointing case ----------------------------------------------------------------------------------------
#: Basilisk's HR16 wheel at its 50 N m s option: spin inertia = momentum / top speed.
HR16_MAX_SPEED_RAD_S = 6000.0 / RPM_PER_RAD_S
HR16_INERTIA_KG_M2 = 50.0 / HR16_MAX_SPEED_RAD_S
HR16_MAX_TORQUE_NM = 0.2


def mrp_to_quat(sigma) -> tuple:
    """The quaternion (scalar first) of MRP ``sigma``: q0 = (1 - s^2) / (1 + s^2), q = 2 sigma / (1 + s^2)."""
    s = np.asarray(sigma, dtype=float)
    s2 = float(s @ s)
    return (float((1.0 - s2) / (1.0 + s2)), *(float(x) for x in 2.0 * s / (1.0 + s2)))


def wheel_pointing_plant(duration_s: float = 600.0, control_period_s: float = 0.2, gains=(3.5, 30.0)) -> Plant:
    """Three wheels on the body axes, MRP feedback on perfect navigation (module docstring), as a :class:`Plant`."""
    from stand.adcs.control import WheelDistribution, control_torque

    wheels = WheelCluster(np.eye(3), [HR16_INERTIA_KG_M2] * 3)
    # Basilisk's hub inertia plus the rotors' spin inertia about their axes: the whole body, as the truth takes it.
    inertia = np.diag([900.0, 800.0, 600.0]) + HR16_INERTIA_KG_M2 * np.eye(3)
    dist = WheelDistribution(wheels.spin_axes_B, HR16_MAX_TORQUE_NM)
    K, P = gains
    q_RN, w_RN = (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0)

    def controller():
        def command(t_s, q, w, speeds_rad_s):
            h_B = dist.momentum_B(speeds_rad_s, wheels.inertia)
            u_B = control_torque(q, w, q_RN, w_RN, inertia, K, P, h_B)
            return tuple(float(x) for x in dist.motor_torques(u_B))

        return command

    r0 = np.array([7.0e6, 0.0, 0.0])  # unused: no environment torque; the truth wants an orbit all the same
    v0 = np.array([0.0, math.sqrt(MU_EARTH / 7.0e6), 0.0])
    return Plant("wheel_pointing", inertia, mrp_to_quat((0.1, 0.2, -0.3)), (0.001, -0.01, 0.03), wheels,
                 (100.0 / RPM_PER_RAD_S, 200.0 / RPM_PER_RAD_S, 300.0 / RPM_PER_RAD_S), r0, v0, "point", 10.0, (),
                 control_period_s, duration_s, controller)


# -- the fixed-step run and the reference ---------------------------------------------------------------------------
def run_fixed(plant: Plant, step_s: float, integrator: str) -> Trajectory:
    """The closed loop on the stand's truth at ``step_s`` with ``integrator``; the command held between ticks."""
    period_ns, step_ns = seconds_to_ns(plant.control_period_s), seconds_to_ns(step_s)
    if period_ns % step_ns:
        raise ValueError(f"step_s = {step_s:g} s does not divide the control period of {plant.control_period_s:g} s; "
                         "the controller's rate must be a whole number of steps.")
    every = period_ns // step_ns
    clock = time.perf_counter
    wall0, cpu0 = clock(), time.process_time()
    truth, command = plant.truth(step_s, integrator), plant.controller()
    zero, truth_s = (0.0, 0.0, 0.0), 0.0
    ts, qs, ws, ss = [], [], [], []
    for j in range(plant.control_ticks + 1):
        speeds = truth.wheel_speeds_rad_s
        ts.append(truth.t_ns / NS_PER_S)
        qs.append(truth.q)
        ws.append(truth.w)
        ss.append(speeds)
        if j == plant.control_ticks:
            break
        u = command(truth.t_ns / NS_PER_S, truth.q, truth.w, speeds)
        t0 = clock()
        for _ in range(every):
            truth.step(zero, u)
        truth_s += clock() - t0
    return Trajectory(np.array(ts), np.array(qs), np.array(ws), np.array(ss), wall_s=clock() - wall0,
                      truth_s=truth_s, cpu_s=time.process_time() - cpu0, modes=_modes(command))


def orbit_spline(plant: Plant):
    """Position (m, inertial) at any time of the run: the truth's own orbit nodes (J2 RK4 at ``orbit_step_s``)
    interpolated by scipy's cubic Hermite spline, an implementation apart from the truth's."""
    from scipy.interpolate import CubicHermiteSpline

    span = math.ceil(plant.duration_s / plant.orbit_step_s + 1.0) * plant.orbit_step_s
    t, r, v = propagate_j2(plant.r_N_m, plant.v_N_m_s, span, plant.orbit_step_s, mu=MU_EARTH,
                           j2=J2_EARTH if plant.gravity == "j2" else 0.0, r_eq=R_EARTH)
    return CubicHermiteSpline(t, r, v, axis=0)


def gyrostat_rhs(plant: Plant):
    """``f(t, y, tau)`` of the reference, y = (q_BN, omega_BN_B, h_abs): ``I_s domega/dt = T - omega x (I_s omega +
    A h) - A tau``, ``dh/dt = tau``, ``dq/dt = q (x) (0, omega) / 2``, T the gravity-gradient torque
    ``3 mu / r^5 r_B x (I r_B)`` when the plant has it."""
    A = plant.wheels.spin_axes_B
    I = plant.inertia_kg_m2
    Is = I - (A * plant.wheels.inertia) @ A.T
    Is_inv = np.linalg.inv(Is)
    position = orbit_spline(plant) if "gravity_gradient" in plant.torques else None

    def f(t, y, tau):
        q, w, h = y[:4], y[4:7], y[7:]
        T = -(A @ tau)
        if position is not None:
            r_B = dcm(q / math.sqrt(q @ q)) @ position(t)  # the attitude q stands for, unit
            r = math.sqrt(r_B @ r_B)
            T = T + 3.0 * MU_EARTH / r ** 5 * np.cross(r_B, I @ r_B)
        dw = Is_inv @ (T - np.cross(w, Is @ w + A @ h))
        dq = 0.5 * np.array([-q[1] * w[0] - q[2] * w[1] - q[3] * w[2], q[0] * w[0] + q[2] * w[2] - q[3] * w[1],
                             q[0] * w[1] - q[1] * w[2] + q[3] * w[0], q[0] * w[2] + q[1] * w[1] - q[2] * w[0]])
        return np.concatenate((dq, dw, tau))

    return f


def reference(plant: Plant, rtol: float = REF_RTOL, atol: float = REF_ATOL) -> Trajectory:
    """The same closed loop by DOP853, piecewise between control ticks (the command constant on each piece)."""
    from scipy.integrate import solve_ivp

    f = gyrostat_rhs(plant)
    A, J = plant.wheels.spin_axes_B, plant.wheels.inertia
    w0 = np.asarray(plant.omega_BN_B, float)
    y = np.concatenate((plant.q_BN, w0, J * (np.asarray(plant.speeds_rad_s, float) + w0 @ A)))
    command, period_ns = plant.controller(), seconds_to_ns(plant.control_period_s)
    clock = time.perf_counter
    wall0 = clock()
    ts, qs, ws, ss = [], [], [], []
    for j in range(plant.control_ticks + 1):
        t = j * period_ns / NS_PER_S
        q = y[:4] / np.linalg.norm(y[:4])
        q = -q if q[0] < 0.0 else q
        speeds = y[7:] / J - y[4:7] @ A
        ts.append(t)
        qs.append(q)
        ws.append(y[4:7].copy())
        ss.append(speeds)
        if j == plant.control_ticks:
            break
        tau = np.asarray(command(t, tuple(q), tuple(y[4:7]), tuple(speeds)), dtype=float)
        sol = solve_ivp(f, (t, (j + 1) * period_ns / NS_PER_S), y, method="DOP853", rtol=rtol, atol=atol,
                        args=(tau,))
        if not sol.success or not np.all(np.isfinite(sol.y[:, -1])):
            raise FloatingPointError(f"the DOP853 reference failed at t = {t:g} s: {sol.message}")
        y = sol.y[:, -1]
    return Trajectory(np.array(ts), np.array(qs), np.array(ws), np.array(ss), wall_s=clock() - wall0,
                      modes=_modes(command))


def errors(run: Trajectory, ref: Trajectory) -> tuple[float, float]:
    """(largest attitude error in arcsec, largest wheel-speed error in rpm) over the control ticks."""
    if run.t_s.shape != ref.t_s.shape or np.max(np.abs(run.t_s - ref.t_s)) > 1e-9:
        raise ValueError("run and reference are not on the same control ticks")
    att = float(np.max(angle_between(run.q_BN, ref.q_BN))) * ARCSEC_PER_RAD
    return att, float(np.max(np.abs(run.speeds_rad_s - ref.speeds_rad_s))) * RPM_PER_RAD_S


#: What a closed-loop error must stay under to be negligible on a bench: 1 % of the pointing scenario's tracker noise
#: (noise_cross_arcsec = 2.4, 1 sigma) and 1 % of the wheel speed telemetry's resolution (RW_SPEED_TLM.speed,
#: 0.001 rad/s: docs/reaction_wheel_icd.md).
TARGET_ARCSEC = 0.024
TARGET_RPM = 0.01 * 0.001 * RPM_PER_RAD_S


def _plant(case: str, step_s: float, integrator: str, duration_s: float) -> Plant:
    if case == POINTING_SCENARIO:
        return pointing_plant(step_s, integrator, duration_s)
    return wheel_pointing_plant(duration_s)


def _row(case: str, integrator: str, step_s: float, run: Trajectory | None, ref: Trajectory, refusal: str = ""):
    name = f"accuracy.closed_loop.{case}.{integrator}.h_{step_s:g}_s"
    base = {"name": name, "case": f"closed_loop.{case}", "method": integrator, "step_s": step_s}
    if run is None:
        return {**base, "value": "refused", "unit": "", "note": refusal[:240]}
    att, rpm = errors(run, ref)
    return {**base, "value": att, "unit": "arcsec", "error": att, "error_unit": "arcsec", "wheel_speed_error": rpm,
            "wheel_speed_error_unit": "rpm", "wall_s": run.wall_s, "truth_s": run.truth_s, "cpu_s": run.cpu_s,
            "note": f"h {step_s:g} s; wheel speed {rpm:.2e} rpm; wall {run.wall_s:.2f} s ({run.truth_s:.2f} s in the "
                    f"truth), CPU {run.cpu_s:.2f} s"}


def _order_row(case: str, rows: list[dict], floor_arcsec: float) -> dict | None:
    """RK4's observed order between the two largest steps it ran; noted when the smaller error is not ten times
    the floor: the reference's own error (``floor_arcsec``) or the smallest RK4 error of the grid (round-off)."""
    rk4 = sorted((r for r in rows if r["method"] == "rk4" and isinstance(r["value"], float)),
                 key=lambda r: -r["step_s"])
    if len(rk4) < 2:
        return None
    a, b = rk4[:2]
    order = math.log(a["error"] / b["error"]) / math.log(a["step_s"] / b["step_s"])
    note = f"h = {a['step_s']:g} and {b['step_s']:g} s"
    if b["error"] < 10.0 * max(floor_arcsec, min(r["error"] for r in rk4)):
        note += "; at the round-off floor already (no order to read)"
    return {"name": f"accuracy.closed_loop.{case}.rk4_order", "value": round(order, 2), "unit": "", "note": note}


def _recommended_row(case: str, rows: list[dict]) -> dict:
    """The largest step (the cheapest: fewest truth steps; wall times on a shared machine are too noisy to rank
    runs whose cost the controller dominates) whose errors are both under the targets; there the default RK4 when
    it meets them (the others' extra accuracy is orders of magnitude below what a bench can see, at up to twice the
    truth's cost), else the most accurate run."""
    ok = [r for r in rows if isinstance(r["value"], float) and r["error"] <= TARGET_ARCSEC
          and r["wheel_speed_error"] <= TARGET_RPM]
    best = min(ok, key=lambda r: (-r["step_s"], r["method"] != "rk4", r["error"])) if ok else None
    limit = f"attitude <= {TARGET_ARCSEC:g} arcsec and wheel speed <= {TARGET_RPM:.2g} rpm"
    if best is None:
        return {"name": f"accuracy.closed_loop.{case}.recommended_step", "value": "none", "unit": "s",
                "note": f"no run of the grid met {limit}"}
    return {"name": f"accuracy.closed_loop.{case}.recommended_step", "value": best["step_s"], "unit": "s",
            "note": f"{best['method']}: the largest step with {limit} ({best['error']:.2g} arcsec, "
                    f"{best['wheel_speed_error']:.2g} rpm, {best['wall_s']:.2f} s)"}


def bench_rows(quick: bool = False) -> list[dict]:
    """The closed-loop rows of ``stand bench accuracy`` (module docstring); ``quick``: 60 s and 120 s runs."""
    rows: list[dict] = []
    for case, duration_s in ((POINTING_SCENARIO, 60.0 if quick else None), ("wheel_pointing", 120.0 if quick else
                                                                             600.0)):
        plant = _plant(case, 0.1, "rk4", duration_s)
        ref = reference(plant)
        # The reference checked against itself at tolerances ten times tighter: how far it can be trusted.
        att, rpm = errors(reference(plant, REF_RTOL / 10.0, REF_ATOL / 10.0), ref)
        case_rows = []
        for integrator in INTEGRATORS:
            for step_s in STEPS_S[:3] if quick else STEPS_S:
                try:
                    run = run_fixed(_plant(case, step_s, integrator, duration_s), step_s, integrator)
                except ValueError as exc:  # the stand refuses the step (a ScenarioError too): the row says why
                    case_rows.append(_row(case, integrator, step_s, None, ref, str(exc)))
                    continue
                case_rows.append(_row(case, integrator, step_s, run, ref))
        rows += case_rows
        rows.append({"name": f"accuracy.closed_loop.{case}.reference_self_check", "value": att, "unit": "arcsec",
                     "case": f"closed_loop.{case}", "method": "reference", "error": att, "wheel_speed_error": rpm,
                     "note": f"DOP853 rtol {REF_RTOL:g} against rtol {REF_RTOL / 10:g}: wheel speed {rpm:.1e} rpm; "
                             f"{plant.duration_s:g} s, control every {plant.control_period_s:g} s; reference "
                             f"{ref.wall_s:.1f} s"})
        order = _order_row(case, case_rows, att)
        if order is not None:
            rows.append(order)
        rows.append(_recommended_row(case, case_rows))
    return rows


def plot(rows: list[dict], path) -> None:
    """Attitude and wheel-speed error against wall time: one row of panels per case, log-log, each point labelled
    with its step; the targets of the recommended step dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    cases = [c for c in dict.fromkeys(r.get("case") for r in rows) if c and c.startswith("closed_loop.")]
    fig, axes = plt.subplots(len(cases), 2, figsize=(11.0, 4.3 * len(cases)), squeeze=False)
    for ax_row, case in zip(axes, cases, strict=True):
        sel = [r for r in rows if r.get("case") == case and isinstance(r.get("value"), float) and "error" in r]
        for ax, key, unit, target in ((ax_row[0], "error", "arcsec", TARGET_ARCSEC),
                                      (ax_row[1], "wheel_speed_error", "rpm", TARGET_RPM)):
            _panel(ax, sel, key, unit, target, case.removeprefix("closed_loop."))
            # A short log axis: label 2 and 5 of each decade too, not every minor tick (they overlap).
            ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g}"))
            ax.xaxis.set_minor_formatter(FuncFormatter(lambda x, _: f"{x:g}" if f"{x:.0e}"[0] in "25" else ""))
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _panel(ax, sel: list[dict], key: str, unit: str, target: float, case: str) -> None:
    for method in INTEGRATORS:
        # In step order: the line follows the step, whatever order the (noisy) wall times come in.
        pts = sorted(((r["wall_s"], max(r[key], 1e-16), r["step_s"]) for r in sel if r["method"] == method),
                     key=lambda p: -p[2])
        if not pts:
            continue
        ax.loglog([p[0] for p in pts], [p[1] for p in pts], "o-", label=method)
        for x, y, h in pts:
            ax.annotate(f"{h:g} s", (x, y), textcoords="offset points", xytext=(4, 3), fontsize=7)
    ax.axhline(target, color="k", ls="--", lw=0.8, label=f"target {target:.2g} {unit}")
    for r in sel:
        if r["method"] == "reference":
            ax.axhline(max(r[key], 1e-16), color="grey", ls=":", lw=0.8, label="DOP853 rtol 1e-12 vs 1e-13")
    quantity = "attitude error" if key == "error" else "wheel-speed error"
    ax.set_title(f"{case}: {quantity}", fontsize=10)
    ax.set_xlabel("wall time of the closed-loop run (truth + controller) [s]")
    ax.set_ylabel(f"largest {quantity} against DOP853 [{unit}]")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, title="integrator (points: dynamics step)", title_fontsize=7, loc="best")


__all__ = ["INTEGRATORS", "STEPS_S", "TARGET_ARCSEC", "TARGET_RPM", "Plant", "Trajectory", "bench_rows", "errors",
           "gyrostat_rhs", "mrp_to_quat", "orbit_spline", "plot", "pointing_plant", "reference", "run_fixed",
           "wheel_pointing_plant"]
