"""Stiff actuator sub-models as exact discrete updates: magnetorquer coil, wheel friction and motor,
flexible mode; and the spin-axis layouts of wheel clusters.

Each is linear (or piecewise linear) with inputs held over a step (zero-order hold), so its exact
solution over a step costs as much as one explicit stage and has no stability limit. Integrating
them inside the attitude ODE with explicit RK4 would need h < 2.78 tau (coil), h < 2.78 / stiffness
(regularised friction) or h < 2.83 / omega_n (flexible mode) just to stay stable, and at the
dynamics step of 10-100 ms they are stiff (docs/numerical_methods.md: RK4 blew up a tau = 1 ms coil in
0.04 s and wiped out a 40 Hz mode). ``max_explicit_step_s`` on each model states that limit, for
the step guard of a scene that would put the model into an explicit integrator.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np
from scipy.linalg import expm

import compiled_paths

#: The wheel's float arithmetic (compiled where the install built it; the plain module otherwise, the same bits).
_wheel_step = compiled_paths.load("sim.wheel_step")

_INF = math.inf
_isfinite = math.isfinite

#: RK4's stability interval on the negative real axis (|lambda h| <= 2.785).
RK4_REAL_LIMIT = 2.785
#: RK4's stability interval on the imaginary axis (|lambda h| <= 2 sqrt 2).
RK4_IMAG_LIMIT = 2.0 * math.sqrt(2.0)


def _positive(name: str, value, unit: str) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f"{name} = {value!r} {unit}; it must be a finite positive number.")
    return v


def _non_negative(name: str, value, unit: str) -> float:
    v = float(value)
    if not (math.isfinite(v) and v >= 0.0):
        raise ValueError(f"{name} = {value!r} {unit}; it must be a finite number >= 0.")
    return v


class CoilLR:
    """Magnetorquer coil: L di/dt = V - R i, with V held over each step (exact ZOH update).

    ``inductance_h`` (H), ``resistance_ohm`` (ohm), ``turns_area_m2`` (N A, m^2: dipole per ampere).
    ``step(i_A, v_V, h_s)`` broadcasts over coils; the update is
    i+ = V/R + (i - V/R) exp(-h R / L), exact for any h.
    """

    def __init__(self, inductance_h: float, resistance_ohm: float, turns_area_m2: float = 1.0):
        self.inductance_h = _positive("inductance_h", inductance_h, "H")
        self.resistance_ohm = _positive("resistance_ohm", resistance_ohm, "ohm")
        self.turns_area_m2 = _positive("turns_area_m2", turns_area_m2, "m^2")
        self._decay: dict[float, float] = {}

    @property
    def tau_s(self) -> float:
        """Time constant L / R (s)."""
        return self.inductance_h / self.resistance_ohm

    @property
    def max_explicit_step_s(self) -> float:
        """Largest step (s) at which explicit RK4 on this coil would still be stable."""
        return RK4_REAL_LIMIT * self.tau_s

    def step(self, i_A, v_V, h_s: float):
        """Current (A) after ``h_s`` seconds at held voltage ``v_V`` (V), from current ``i_A``."""
        h = _positive("h_s", h_s, "s")
        d = self._decay.get(h)
        if d is None:
            # exp(-h/tau) is cached per step length: the loop uses one or two step lengths.
            d = self._decay[h] = math.exp(-h / self.tau_s)
        i_ss = np.asarray(v_V, dtype=float) / self.resistance_ohm
        return i_ss + (np.asarray(i_A, dtype=float) - i_ss) * d

    def dipole(self, i_A):
        """Magnetic dipole (A m^2) of current ``i_A``."""
        return self.turns_area_m2 * np.asarray(i_A, dtype=float)


class ReactionWheel:
    """Wheel speed with Coulomb + viscous friction and stiction, stepped exactly (Karnopp stick/slip).

    J dOmega/dt = u - tau_c sign(Omega) - c Omega while slipping; the wheel sticks at Omega = 0 while
    |u| <= tau_static. ``inertia_kg_m2`` J, ``coulomb_nm`` tau_c, ``viscous_nms`` c (N m s/rad),
    ``static_nm`` tau_static (>= tau_c; default tau_c). Between sign changes the motion is solved in
    closed form, zero crossings are located exactly inside the step and the stick test is applied
    there, so the speed never chatters round zero and friction never adds energy.
    """

    def __init__(self, inertia_kg_m2: float, coulomb_nm: float, viscous_nms: float = 0.0,
                 static_nm: float | None = None):
        self.inertia = _positive("inertia_kg_m2", inertia_kg_m2, "kg m^2")
        self.coulomb = _non_negative("coulomb_nm", coulomb_nm, "N m")
        self.viscous = _non_negative("viscous_nms", viscous_nms, "N m s/rad")
        self.static = self.coulomb if static_nm is None else _non_negative("static_nm", static_nm, "N m")
        if self.static < self.coulomb:
            raise ValueError(
                f"static_nm = {static_nm!r} N m is below coulomb_nm = {coulomb_nm!r} N m; breakaway "
                "friction must be at least the sliding friction."
            )

    @property
    def max_explicit_step_s(self) -> float:
        """Explicit RK4 stability limit (s) of the viscous part alone (inf without viscosity).

        A bare sign() Coulomb term has no stable explicit step at all (it chatters at ~h tau_c / J);
        that is why this model is stepped exactly.
        """
        return math.inf if self.viscous == 0.0 else RK4_REAL_LIMIT * self.inertia / self.viscous

    def step(self, omega_rad_s: float, u_nm: float, h_s: float):
        """Advance the wheel ``h_s`` seconds with motor torque ``u_nm`` held.

        Returns ``(omega, body_torque_nm, friction_energy_J)``: the new wheel speed (rad/s), the mean
        torque the wheel puts on the body over the step (-J dOmega/h, so momentum is exchanged
        exactly) and the energy friction dissipated (>= 0).
        """
        h = _positive("h_s", h_s, "s")
        w = float(omega_rad_s)
        u = float(u_nm)
        if not (math.isfinite(w) and math.isfinite(u)):
            raise ValueError(f"omega_rad_s = {omega_rad_s!r}, u_nm = {u_nm!r}; both must be finite.")
        return self._advance(w, u, h)

    def _advance(self, w: float, u: float, h: float) -> tuple[float, float, float]:
        """:meth:`step` on values already checked: finite floats, ``h`` > 0 (a motor steps its rotor this way).
        Between sign changes the motion is solved in closed form, a zero crossing is located exactly inside the step
        and the stick test applied there (:func:`sim.wheel_step.rotor_advance`)."""
        return _wheel_step.rotor_advance(self.inertia, self.coulomb, self.viscous, self.static, w, u, h)


class WheelState(NamedTuple):
    """A wheel motor's state: rotor speed about its spin axis (rad/s) and the motor torque now (N m)."""

    omega_rad_s: float
    motor_torque_Nm: float


#: ``WheelState`` of a (speed, torque) pair without the Python-level ``__new__`` namedtuple generates (once a tick
#: per wheel).
_wheel_state = functools.partial(tuple.__new__, WheelState)


class WheelMotor:
    """A reaction wheel with its motor: torque limit, back-EMF roll-off, motor lag, friction.

    The rotor is a :class:`ReactionWheel` (Karnopp friction, stepped exactly). The motor adds:

    - ``max_torque_Nm``: the command is clipped to +-tau_max;
    - ``max_speed_rad_s`` w_max with ``rolloff_rad_s`` (default 10 % of w_max): driving the speed up
      (torque and speed of one sign) the available torque falls linearly from tau_max to 0 over the
      last ``rolloff_rad_s`` before w_max, as the back-EMF eats the driver's voltage; braking keeps
      tau_max. The roll-off is evaluated at the start of each step and the motor never drives the
      speed past ``max(w_max, |w|)`` within a step, so the limit holds at any step;
    - ``time_constant_s`` T: the motor torque follows the (limited) command as a first-order lag,
      exactly: tau(t) = u + (tau0 - u) e^(-t/T). The rotor is driven by the mean torque of that
      exponential over the step, so the momentum the motor delivers is exact at any step length.

    :meth:`step` returns the new state, the mean torque on the body over the step (-J dOmega / h:
    the motor's and the bearing friction's reactions together, so momentum is exchanged exactly)
    and the friction energy. In speed mode (:meth:`speed_loop_torque`) the wheel's own controller
    asks for the torque that closes the speed error over ``speed_loop_s`` (never faster than one
    step, so it cannot overshoot by gain at a long step) plus its friction at the present speed.
    Scalars: one wheel per object.
    """

    def __init__(self, wheel: ReactionWheel, max_torque_Nm: float, max_speed_rad_s: float,
                 time_constant_s: float = 0.0, rolloff_rad_s: float | None = None, speed_loop_s: float = 0.2):
        if not isinstance(wheel, ReactionWheel):
            raise TypeError(f"WheelMotor needs a ReactionWheel rotor; got {type(wheel).__name__}.")
        self.wheel = wheel
        self.max_torque_Nm = _positive("max_torque_Nm", max_torque_Nm, "N m")
        self.max_speed_rad_s = _positive("max_speed_rad_s", max_speed_rad_s, "rad/s")
        self.time_constant_s = _non_negative("time_constant_s", time_constant_s, "s")
        roll = 0.1 * self.max_speed_rad_s if rolloff_rad_s is None else rolloff_rad_s
        self.rolloff_rad_s = _positive("rolloff_rad_s", roll, "rad/s")
        if self.rolloff_rad_s > self.max_speed_rad_s:
            raise ValueError(f"rolloff_rad_s = {rolloff_rad_s!r} rad/s exceeds max_speed_rad_s = "
                             f"{max_speed_rad_s!r} rad/s; the roll-off band lies below the rated speed.")
        self.speed_loop_s = _positive("speed_loop_s", speed_loop_s, "s")
        if wheel.static > self.max_torque_Nm:
            raise ValueError(f"the wheel's breakaway friction {wheel.static!r} N m exceeds max_torque_Nm = "
                             f"{max_torque_Nm!r} N m: the motor could never start it.")
        self._lag: dict[float, tuple[float, float]] = {}
        # Faults (issue 24): plain attributes with neutral values; :meth:`step` checks one flag, ``_faulty``, kept
        # true while any of them is off its neutral value, so a healthy wheel steps exactly as before.
        self._faulty = False
        self._friction_scale = 1.0
        self._seized = False
        self._torque_scale = 1.0
        self._motor_on = True
        self._scaled_rotor: ReactionWheel | None = None

    # -- faults ------------------------------------------------------------------------------------------
    @property
    def friction_scale(self) -> float:
        """Bearing friction (Coulomb, viscous and breakaway) times this (>= 0; 1 = healthy; a friction rise > 1)."""
        return self._friction_scale

    @friction_scale.setter
    def friction_scale(self, value: float) -> None:
        self._friction_scale = _non_negative("friction_scale", value, "")
        w = self.wheel
        self._scaled_rotor = None if self._friction_scale == 1.0 else ReactionWheel(
            w.inertia, w.coulomb * self._friction_scale, w.viscous * self._friction_scale,
            w.static * self._friction_scale)
        self._update_faulty()

    @property
    def seized(self) -> bool:
        """The rotor seizes: a bearing torque of :data:`SEIZURE_TORQUE_RATIO` times ``max_torque_Nm`` stops it
        relative to the body within a few steps and holds it there; the motor's torque goes nowhere (stator and
        rotor are locked to the body) and the rotor's momentum goes to the body through the step's body torque."""
        return self._seized

    @seized.setter
    def seized(self, value: bool) -> None:
        self._seized = bool(value)
        self._update_faulty()

    @property
    def torque_scale(self) -> float:
        """Torque loss: the motor gives this fraction of its torque (0..1; 1 = healthy)."""
        return self._torque_scale

    @torque_scale.setter
    def torque_scale(self, value: float) -> None:
        v = float(value)
        if not (math.isfinite(v) and 0.0 <= v <= 1.0):
            raise ValueError(f"torque_scale = {value!r}; it must be a fraction from 0 to 1.")
        self._torque_scale = v
        self._update_faulty()

    @property
    def motor_on(self) -> bool:
        """False: the motor is off (no torque whatever the command, its lag state dropped); friction still acts."""
        return self._motor_on

    @motor_on.setter
    def motor_on(self, value: bool) -> None:
        self._motor_on = bool(value)
        self._update_faulty()

    def _update_faulty(self) -> None:
        self._faulty = (self._friction_scale != 1.0 or self._seized or self._torque_scale != 1.0
                        or not self._motor_on)

    @property
    def inertia(self) -> float:
        return self.wheel.inertia

    def available_torque(self, omega_rad_s: float, u_nm: float) -> float:
        """The torque the motor can give for command ``u_nm`` at speed ``omega_rad_s`` (clipped, rolled off)."""
        u = float(u_nm)
        return _wheel_step.available_torque(u, float(omega_rad_s), self.max_torque_Nm, self.max_speed_rad_s,
                                            self.rolloff_rad_s)

    def speed_loop_torque(self, state: tuple[float, float], omega_cmd_rad_s: float, h_s: float) -> float:
        """The torque command of the wheel's speed loop for the next ``h_s`` (before the motor's limits).

        It asks for the mean torque that closes the speed error over ``max(speed_loop_s, h_s)`` plus
        the friction at the present speed, and inverts the motor lag so that the step's MEAN torque
        is that value (the torque still decaying from the last command counts towards it).
        Friction fed forward at the present speed, not the commanded one, keeps the approach from
        overshooting; at the command it is exact, so there is no steady error.
        """
        h = _positive("h_s", h_s, "s")
        w_cmd = min(max(float(omega_cmd_rad_s), -self.max_speed_rad_s), self.max_speed_rad_s)
        w_now, tau0 = float(state[0]), float(state[1])
        r = self.wheel
        s = w_now if w_now != 0.0 else w_cmd
        feed = r.coulomb * (1.0 if s > 0 else -1.0 if s < 0 else 0.0) + r.viscous * w_now
        want = r.inertia * (w_cmd - w_now) / max(self.speed_loop_s, h) + feed
        _, mean = self._lag_factors(h)
        return (want - tau0 * mean) / (1.0 - mean)

    def _lag_factors(self, h: float) -> tuple[float, float]:
        """``(e^(-h/T), mean of e^(-t/T) over the step)``, cached per step length."""
        f = self._lag.get(h)
        if f is None:
            T = self.time_constant_s
            if T == 0.0:
                f = (0.0, 0.0)
            else:
                x = h / T
                f = (math.exp(-x), -math.expm1(-x) / x)
            self._lag[h] = f
        return f

    def step(self, state: tuple[float, float], u_cmd_Nm: float, h_s: float) -> tuple[WheelState, float, float]:
        """Advance ``h_s`` seconds with torque command ``u_cmd_Nm`` held: ``(state, body_torque_Nm, friction_J)``.
        ``state``: a :class:`WheelState` or any (speed, motor torque) pair."""
        # A float step inside (0, inf) is what _positive would return: taken as it is, without the call.
        h = h_s if type(h_s) is float and 0.0 < h_s < _INF else _positive("h_s", h_s, "s")
        w0, tau0, u = float(state[0]), float(state[1]), float(u_cmd_Nm)
        if not (_isfinite(w0) and _isfinite(tau0) and _isfinite(u)):
            raise ValueError(f"state = {tuple(state)!r}, u_cmd_Nm = {u_cmd_Nm!r}; all must be finite.")
        if self._faulty:
            return self._step_faulty(w0, tau0, u_cmd_Nm, h)
        decay, mean = self._lag.get(h) or self._lag_factors(h)  # cached per step length: one look-up a step
        # The command clipped and rolled off, the lag, the rotor with its friction, the speed cap: one call.
        r = self.wheel
        w1, tau_end, body, friction = _wheel_step.motor_step(
            r.inertia, r.coulomb, r.viscous, r.static, self.max_torque_Nm, self.max_speed_rad_s, self.rolloff_rad_s,
            decay, mean, w0, tau0, u, h)
        return _wheel_state((w1, tau_end)), body, friction

    def step_speed(self, state: tuple[float, float], omega_cmd_rad_s: float,
                   h_s: float) -> tuple[WheelState, float, float]:
        """:meth:`step` in speed mode: the speed loop computes the torque command."""
        return self.step(state, self.speed_loop_torque(state, omega_cmd_rad_s, h_s), h_s)

    def _step_faulty(self, w0: float, tau0: float, u_cmd_Nm: float, h: float) -> tuple[WheelState, float, float]:
        """:meth:`step` with a fault active (see the fault attributes); same outputs."""
        J = self.wheel.inertia
        if self._seized:
            # The seized bearing's torque opposes the motion until the rotor stands still relative to the body;
            # the motor's torque acts between two parts locked to the body and moves nothing.
            dw = SEIZURE_TORQUE_RATIO * self.max_torque_Nm * h / J
            w1 = 0.0 if abs(w0) <= dw else w0 - math.copysign(dw, w0)
            friction = 0.5 * J * (w0 * w0 - w1 * w1)
            tau_end = tau0 * self._lag_factors(h)[0] if self._motor_on else 0.0
            return WheelState(w1, tau_end), -J * (w1 - w0) / h, friction
        if self._motor_on:
            u = self.available_torque(w0, u_cmd_Nm) * self._torque_scale
        else:
            u = tau0 = 0.0
        decay, mean = self._lag_factors(h)
        tau_end = u + (tau0 - u) * decay
        tau_mean = u + (tau0 - u) * mean
        rotor = self._scaled_rotor if self._scaled_rotor is not None else self.wheel
        w1, _, friction = rotor._advance(w0, tau_mean, h)
        cap = max(self.max_speed_rad_s, abs(w0))
        if abs(w1) > cap and tau_mean * w1 > 0.0:
            w1 = math.copysign(cap, w1)
        return WheelState(w1, tau_end), -J * (w1 - w0) / h, friction


#: A seized rotor's bearing torque, as a multiple of the motor's rated torque: it stops a wheel at its rated speed
#: and inertia J within ``J w_max / (20 tau_max)`` seconds (a few steps for a small wheel), much faster than the motor
#: could brake it.
SEIZURE_TORQUE_RATIO = 20.0

#: Tilt of the spin axes from the pyramid's axis that gives equal torque capability about all three
#: body axes: arccos(1 / sqrt(3)) = 54.7356 deg.
PYRAMID_EQUAL_TILT_DEG = math.degrees(math.acos(1.0 / math.sqrt(3.0)))


def wheel_spin_axes_B(layout: str, tilt_deg: float = PYRAMID_EQUAL_TILT_DEG) -> np.ndarray:
    """Unit spin axes of a wheel cluster in the body frame, one row per wheel.

    ``"orthogonal"``: three wheels along body x, y, z. ``"pyramid"``: four wheels whose axes lean
    ``tilt_deg`` from body +z, at azimuths 0, 90, 180, 270 deg from body +x.
    """
    if layout == "orthogonal":
        return np.eye(3)
    if layout == "pyramid":
        if not 0.0 < tilt_deg < 90.0:
            raise ValueError(f"pyramid tilt_deg = {tilt_deg!r}; it must lie strictly between 0 and 90 deg.")
        t = math.radians(tilt_deg)
        az = np.radians([0.0, 90.0, 180.0, 270.0])
        return np.column_stack((math.sin(t) * np.cos(az), math.sin(t) * np.sin(az), np.full(4, math.cos(t))))
    raise ValueError(f"wheel layout = {layout!r}; allowed: 'orthogonal' (3 wheels) or 'pyramid' (4 wheels).")


def wheel_torque_distribution(spin_axes_B) -> np.ndarray:
    """The minimum-norm map from a wanted motor torque on the body axes to per-wheel motor torques.

    With ``A`` the spin axes as columns (3 x n), the wheels' motor torques ``u`` give the body the
    torque ``-A u``; this returns ``pinv(A)`` (n x 3), so ``u = pinv(A) @ tau_B`` puts ``A u = tau_B``
    on the rotors (and ``-tau_B`` on the body). Refuses axes that do not span three dimensions.
    """
    A = np.asarray(spin_axes_B, dtype=float).T
    if A.ndim != 2 or A.shape[0] != 3 or np.linalg.matrix_rank(A, tol=1e-9) < 3:
        raise ValueError(f"spin axes of shape {np.shape(spin_axes_B)} must be n >= 3 vectors spanning 3-D.")
    return np.linalg.pinv(A)


class FlexibleMode:
    """One flexible mode eta'' + 2 zeta wn eta' + wn^2 eta = f, stepped with its exact transition.

    ``frequency_hz`` (natural), ``damping_ratio`` zeta (0 <= zeta < 1). ``step(x, f, h_s)`` takes the
    state ``x = (eta, eta_dot)`` and a modal force ``f`` (per unit modal mass, m/s^2 equivalent)
    held over the step and returns the exact state after ``h_s``:
    x+ = Phi x + Gamma f with Phi = expm(A h), Gamma = int_0^h expm(A s) ds B (cached per h).
    """

    def __init__(self, frequency_hz: float, damping_ratio: float):
        self.omega_n = 2.0 * math.pi * _positive("frequency_hz", frequency_hz, "Hz")
        self.zeta = _non_negative("damping_ratio", damping_ratio, "")
        if self.zeta >= 1.0:
            raise ValueError(f"damping_ratio = {damping_ratio!r}; a flexible mode needs 0 <= zeta < 1.")
        self.A = np.array([[0.0, 1.0], [-self.omega_n ** 2, -2.0 * self.zeta * self.omega_n]])
        self._cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    @property
    def max_explicit_step_s(self) -> float:
        """Largest step (s) at which explicit RK4 on this mode would still be stable (undamped bound)."""
        return RK4_IMAG_LIMIT / self.omega_n

    def transition(self, h_s: float):
        """``(Phi, Gamma)`` for step ``h_s`` (s): the exact ZOH discretisation."""
        h = _positive("h_s", h_s, "s")
        if h not in self._cache:
            # Van Loan: expm([[A, B], [0, 0]] h) holds Phi and Gamma together.
            M = np.zeros((3, 3))
            M[:2, :2] = self.A
            M[1, 2] = 1.0
            E = expm(M * h)
            self._cache[h] = (E[:2, :2].copy(), E[:2, 2].copy())
        return self._cache[h]

    def step(self, x, f, h_s: float):
        Phi, Gamma = self.transition(h_s)
        return Phi @ np.asarray(x, dtype=float) + Gamma * float(f)

    def energy(self, x):
        """Modal energy per unit modal mass: 0.5 (eta_dot^2 + wn^2 eta^2)."""
        x = np.asarray(x, dtype=float)
        return 0.5 * (x[..., 1] ** 2 + self.omega_n ** 2 * x[..., 0] ** 2)
