"""The truth model of one spacecraft: orbit, Earth rotation, field along the track, attitude.

What it computes and where:

* The orbit does not depend on the attitude (drag and radiation pressure are cannonball models), so it
  runs ahead of the attitude in chunks: RK4 with the J2 force re-evaluated at every stage at a
  coarse ``orbit_step_s`` (10 s: 0.44 m per day), then cubic Hermite interpolation from positions
  and velocities (0.3 mm at 10 s in LEO) onto the half-step grid the attitude RK4 samples.
  A chunk is ``CHUNK_S`` of sim time but never more than ``CHUNK_POINTS`` grid points, so its memory does
  not grow as the dynamics step shrinks (at 1e-6 s a 200 s chunk would be 4e8 points, tens of GB); the
  orbit nodes of a propagation are kept until the chunks have used them, so short chunks do not
  propagate the same orbit step again.
* The geomagnetic field is evaluated vectorised for a whole chunk of that grid at once, so the
  attitude stages only rotate a precomputed inertial field into the body frame.
* The attitude is RK4 on plain floats (``sim.rigid_body.RigidBody``) with magnetic and gravity-
  gradient torques re-evaluated inside every stage.
* Reaction wheels, when the scene has them (``wheels``: a :class:`sim.wheels.WheelCluster`), put
  their momentum into the rigid-body equations (:class:`sim.wheels.WheeledBody`); their speeds join
  the state and the net torque on each rotor is an input held over the step, as the dipole is.
  Without wheels the step is the same code as before, bit for bit.
* Actuators reach the dynamics through one effector interface (:class:`Effect`, :meth:`TruthModel.effector`):
  a magnetic dipole, a torque on the body, or a momentum exchange with one rotor of the wheel cluster, each
  read once per step and held over it. Whoever runs the truth (the stand's loop) builds the step once from the
  effects its actuators declare and never names one.

Only what the scene needs exists: no field track without a field model, no torque the scenario
did not list. Time is integer nanoseconds; a run is bit-for-bit repeatable.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np

import compiled_paths

from . import orbit as orbit_mod
from .constants import J2_EARTH, MU_EARTH, R_EARTH
from .effects import EFFECT_TYPES, Effect  # noqa: F401 - Effect: the interface effector() takes
from .frames import EarthRotation
from .integrators import max_angle_rad, stepper, unit_start
from .rigid_body import RigidBody, check_step
from .rotations import hamilton_floats
from .time import NS_PER_S
from .wheels import WheelCluster, WheeledBody

#: Length of one precomputed chunk of orbit and field, s. Long enough to amortise the vectorised
#: calls, short enough that a stopped run wasted little.
CHUNK_S = 200.0
#: Most half-step grid points in one chunk (positions, velocities and field: about 1 KB a point with the
#: vectorised field model's temporaries). The shipped scenarios' chunks (4001 points at 0.1 s) are under it.
CHUNK_POINTS = 8192

#: The attitude step and the environment's torques: compiled where the install could (compiled_paths).
_step = compiled_paths.load("sim.body_step")


def _summed3(readers) -> Callable[[], tuple]:
    """One reader of the sum of 3-vectors from ``readers`` (each added to 0.0, the order they came in)."""
    if not readers:
        zero = (0.0, 0.0, 0.0)
        return lambda: zero
    if len(readers) == 1:
        read = readers[0]

        def one():
            m = read()
            return (0.0 + m[0], 0.0 + m[1], 0.0 + m[2])

        return one

    def many():
        x = y = z = 0.0
        for read in readers:
            m = read()
            x, y, z = x + m[0], y + m[1], z + m[2]
        return (x, y, z)

    return many


def chunk_points(half_step_s: float) -> int:
    """Grid points in one chunk of the orbit track for a half-step of ``half_step_s``."""
    return min(CHUNK_POINTS, max(2, int(round(CHUNK_S / half_step_s))))


#: ``dcm(q) @ v`` on float tuples (v_N -> v_B for q = q_BN), without building the matrix.
rotate_to_body = _step.rotate_to_body


def compose_floats(q_CB, q_BN):
    """``compose(q_CB, q_BN)`` (``dcm = dcm(q_CB) @ dcm(q_BN)``) on float tuples, ``w >= 0``."""
    w, x, y, z = hamilton_floats(q_BN, q_CB)
    return (w, x, y, z) if w >= 0.0 else (-w, -x, -y, -z)


class _ChunkBuild:
    """A chunk of the orbit track under construction: half-step indices ``start`` to ``start + n_points - 1``,
    sim times ``t_start`` to ``t_end`` (s), the orbit nodes it interpolates, and its first ``done`` points."""

    __slots__ = ("start", "n_points", "t_start", "t_end", "nodes", "done", "pos", "vel", "field")

    def __init__(self, start: int, n_points: int, t_start: float, t_end: float, nodes: tuple):
        self.start, self.n_points, self.t_start, self.t_end, self.nodes = start, n_points, t_start, t_end, nodes
        self.done = 0
        self.pos: list = []
        self.vel: list = []
        self.field: list = []


class OrbitTrack:
    """Orbit positions and (optionally) the inertial field on the dynamics half-step grid."""

    def __init__(self, r0_N, v0_N, *, gravity: str, orbit_step_s: float, half_step_ns: int,
                 field_N: Callable | None, mu: float = MU_EARTH, forces: Callable | None = None):
        if forces is None and gravity not in ("point", "j2"):
            raise ValueError(f"gravity {gravity!r} needs a force model (sim.forces.OrbitForces).")
        self.forces = forces  # None: the fast point-mass + J2 path
        self.j2 = J2_EARTH if gravity == "j2" else 0.0
        self.mu = mu
        self.orbit_step_s = float(orbit_step_s)
        self.half_step_ns = int(half_step_ns)
        self.field_N = field_N
        self._r = np.asarray(r0_N, dtype=float)
        self._v = np.asarray(v0_N, dtype=float)
        self._t0_s = 0.0  # start of the current chunk
        self._chunk_start_idx = 0
        self._chunk_len = 0
        # Flat lists of floats (x0, y0, z0, x1, ...): one list per chunk instead of thousands of 3-lists, which
        # the garbage collector would otherwise walk.
        self._pos: list = []
        self._vel: list = []
        self._field: list = []
        self._nodes: tuple | None = None  # (t, r, v) of the latest propagation, reused while they reach far enough
        self.evaluations = 0  # field points evaluated (tests prove left-out models stay at 0)
        self._ahead: _ChunkBuild | None = None  # the next chunk, built piece by piece in a paced run's slack
        self._ahead_failed = False  # building ahead raised: the chunks are computed when read, as without pacing

    def _fill(self, idx: int) -> None:
        """Compute the chunk that contains half-step index ``idx`` (finishing the one built ahead if it is that one)."""
        per_chunk = chunk_points(self.half_step_ns / NS_PER_S)
        start = (idx // per_chunk) * per_chunk
        build = self._ahead
        self._ahead = None
        if build is None or build.start != start:
            build = self._begin(start)
        self._extend(build, build.n_points)
        self._commit(build)

    def work_ahead(self, n_points: int) -> int:
        """Up to ``n_points`` more points of the next chunk, so a paced run computes it in the slack of the ticks
        before it is needed rather than all in the tick that first reads it (``stand.pacing.Pacer``, which sizes
        ``n_points`` to the slack). The points are bit-identical to a chunk computed whole. Returns the points done,
        0 when the next chunk is complete (or building ahead failed: the read that needs the chunk then computes it,
        and raises what it raises, as in a run that is not paced)."""
        if self._chunk_len == 0 or self._ahead_failed:
            return 0  # nothing read yet: the first chunk comes with the first read
        build = self._ahead
        if build is not None and build.done == build.n_points:
            return 0
        try:
            if build is None:
                build = self._ahead = self._begin(self._chunk_start_idx + self._chunk_len - 1)
            before = build.done
            self._extend(build, max(1, int(n_points)))
            return build.done - before
        except Exception:  # noqa: BLE001 - see the docstring: the same error comes from the read, where it belongs
            self._ahead, self._ahead_failed = None, True
            return 0

    def _begin(self, start: int) -> _ChunkBuild:
        """The chunk from half-step index ``start``: its orbit nodes, propagated on from the current chunk's last
        node when the ones kept do not reach its end."""
        h_half = self.half_step_ns / NS_PER_S
        per_chunk = chunk_points(h_half)
        t_start = start * h_half
        t_end = (start + per_chunk) * h_half
        if t_start < self._t0_s - 1e-9:
            raise RuntimeError("the orbit track only runs forward in time.")
        nodes = self._nodes
        if nodes is None or nodes[0][-1] < t_end - 1e-9:
            nodes = self._propagate(t_end)
        return _ChunkBuild(start, per_chunk + 1, t_start, t_end, nodes)

    def _extend(self, build: _ChunkBuild, n: int) -> None:
        """The chunk's next ``n`` points (or fewer, at its end): Hermite interpolation between the orbit nodes, the
        field where there is one. Every step is element by element, so the points do not depend on ``n``."""
        i0 = build.done
        i1 = min(build.n_points, i0 + n)
        if i1 <= i0:
            return
        t, r, v = build.nodes
        ts = np.arange(build.start + i0, build.start + i1) * (self.half_step_ns / NS_PER_S)
        k = np.clip(np.searchsorted(t, ts, side="right") - 1, 0, len(t) - 2)
        H = t[k + 1] - t[k]
        s = ((ts - t[k]) / H)[:, None]
        h00 = 2 * s**3 - 3 * s**2 + 1
        h10 = s**3 - 2 * s**2 + s
        h01 = -2 * s**3 + 3 * s**2
        h11 = s**3 - s**2
        Hc = H[:, None]
        pos = h00 * r[k] + h10 * Hc * v[k] + h01 * r[k + 1] + h11 * Hc * v[k + 1]
        d00 = (6 * s**2 - 6 * s) / Hc
        d10 = 3 * s**2 - 4 * s + 1
        d01 = (-6 * s**2 + 6 * s) / Hc
        d11 = 3 * s**2 - 2 * s
        vel = d00 * r[k] + d10 * v[k] + d01 * r[k + 1] + d11 * v[k + 1]
        build.pos += pos.ravel().tolist()
        build.vel += vel.ravel().tolist()
        if self.field_N is not None:
            build.field += self.field_N(ts, pos, build.t_start).ravel().tolist()
            self.evaluations += len(ts)
        build.done = i1

    def _commit(self, build: _ChunkBuild) -> None:
        """Make a complete chunk the current one."""
        t, r, v = self._nodes = build.nodes
        # Next chunk continues from the last orbit node at or before the chunk's end (not from the
        # interpolant), so interpolation error never feeds back into the orbit.
        last = int(np.searchsorted(t, build.t_end + 1e-9, side="right") - 1)
        self._r, self._v, self._t0_s = r[last], v[last], float(t[last])
        self._chunk_start_idx = build.start
        self._chunk_len = build.n_points
        self._pos, self._vel, self._field = build.pos, build.vel, build.field

    def _propagate(self, t_end: float) -> tuple:
        """Orbit nodes at the orbit step from the current node to at least ``t_end``."""
        span = t_end - self._t0_s
        n = max(1, int(math.ceil(span / self.orbit_step_s - 1e-9)))
        if self.forces is None:
            t, r, v = orbit_mod.propagate_j2(self._r, self._v, n * self.orbit_step_s, self.orbit_step_s,
                                             mu=self.mu, j2=self.j2, r_eq=R_EARTH)
            return t + self._t0_s, r, v
        return orbit_mod.propagate_cowell(self._r, self._v, n * self.orbit_step_s, self.orbit_step_s,
                                          self.forces, t0_s=self._t0_s)

    def _index(self, idx: int) -> int:
        j = idx - self._chunk_start_idx
        if not 0 <= j < self._chunk_len:
            self._fill(idx)
            j = idx - self._chunk_start_idx
        return j

    # The index is computed before the list is looked up: _index may replace the lists.
    def position(self, idx: int):
        j = 3 * self._index(idx)
        return self._pos[j:j + 3]

    def velocity(self, idx: int):
        j = 3 * self._index(idx)
        return self._vel[j:j + 3]

    def field(self, idx: int):
        j = 3 * self._index(idx)
        return self._field[j:j + 3]


class TruthModel:
    """Orbit + attitude truth of one spacecraft, advanced one dynamics step at a time."""

    def __init__(self, *, inertia, q_BN, omega_BN_B, r_N, v_N, step_ns: int, gravity: str = "j2",
                 orbit_step_s: float = 10.0, field_itrs: Callable | None = None,  # (t_s, r_itrs) -> B_itrs
                 earth_rotation: EarthRotation | None = None, torques=("magnetic", "gravity_gradient"),
                 forces: Callable | None = None, integrator: str = "rk4", wheels: WheelCluster | None = None,
                 wheel_speeds_rad_s=None):
        if step_ns <= 0 or step_ns % 2:
            raise ValueError(f"step_ns = {step_ns}; the dynamics step must be a positive even number of ns.")
        self.body = RigidBody(inertia)
        self.step_ns = int(step_ns)
        self.h = step_ns / NS_PER_S
        self.integrator = integrator
        self._step = stepper(self.body, integrator)
        self._max_angle = max_angle_rad(integrator)
        self.q = unit_start(tuple(float(x) for x in q_BN), integrator)
        self.w = tuple(float(x) for x in omega_BN_B)
        self.wheels = wheels
        if wheels is None:
            if wheel_speeds_rad_s is not None:
                raise ValueError("wheel_speeds_rad_s was given without wheels; give wheels (a WheelCluster) too.")
            check_step(self.body.inertia, omega_BN_B, self.h, "dynamics.step_s", self._max_angle, integrator)
        else:
            self._wheeled = WheeledBody(self.body.inertia, wheels, integrator)
            speeds = np.zeros(wheels.n) if wheel_speeds_rad_s is None else np.asarray(wheel_speeds_rad_s, float)
            if speeds.shape != (wheels.n,) or not np.all(np.isfinite(speeds)):
                raise ValueError(f"wheel_speeds_rad_s = {wheel_speeds_rad_s!r}; it must be {wheels.n} finite speeds "
                                 "in rad/s, one per wheel.")
            self.h_wheels = tuple(float(x) for x in wheels.absolute_momentum(speeds, self.w))
            self._wheeled.check_step(self.w, self.h_wheels, self.h, "dynamics.step_s")
            self.wheel_torque_Nm = (0.0,) * wheels.n
        self._limit_sq = (self._max_angle / self.h) ** 2
        self.t_ns = 0
        self.k = 0  # dynamics step index; half-step grid index is 2k
        self.magnetic = "magnetic" in torques
        self.gravity_gradient = "gravity_gradient" in torques
        if self.magnetic and field_itrs is None:
            raise ValueError("magnetic torque needs a field model (field_itrs).")
        field_N = None
        if field_itrs is not None:
            if earth_rotation is None:
                raise ValueError("a field model in Earth-fixed axes needs an earth_rotation model.")
            rot = earth_rotation

            def field_N(ts, pos, t_chunk_s):
                C = rot.dcm_itrs_gcrs(ts)
                r_itrs = np.einsum("nij,nj->ni", C, pos)
                # The field model's slow time dependence (secular variation, ~0.3 nT a day) is
                # taken at the chunk's start, whichever piece of the chunk this is.
                return np.einsum("nji,nj->ni", C, field_itrs(float(t_chunk_s), r_itrs))

        self.track = OrbitTrack(r_N, v_N, gravity=gravity, orbit_step_s=orbit_step_s,
                                half_step_ns=self.step_ns // 2, field_N=field_N, forces=forces)
        self.has_field = field_N is not None
        self.dipole_B = (0.0, 0.0, 0.0)
        self._I = self.body._I
        self._b_B = (-1, None)  # (k, b_B): a field sensor and the recorder both ask each step
        self._wheel_speeds: tuple = (None, None, ())  # (w, h_wheels, speeds): see wheel_speeds_rad_s
        #: The environment's torques at the RK4 stages (the compiled RK4 step calls it without a Python call).
        self._environment = _step.EnvironmentTorque(self.body.dynamics, self.h, MU_EARTH, self.magnetic,
                                                    self.gravity_gradient)
        #: The body torque of the "torque" effects (N m, body axes), held over the step (:meth:`effector`).
        self.torque_B = (0.0, 0.0, 0.0)
        self._stage_torque = self._environment if (self.magnetic or self.gravity_gradient) else None

    # --- truth at the current time ------------------------------------------------------------
    @property
    def t_s(self) -> float:
        return self.t_ns / NS_PER_S

    @property
    def r_N(self):
        return self.track.position(2 * self.k)

    @property
    def v_N(self):
        return self.track.velocity(2 * self.k)

    @property
    def b_N(self):
        return self.track.field(2 * self.k)

    def state_row(self, t_s: float) -> list:
        """``[t_s, *q_BN, *omega_BN_B, *r_N, *v_N]``: the truth's first columns of a telemetry row (stand.loop), the
        position and velocity taken from the track with one look-up."""
        track = self.track
        j = 3 * track._index(2 * self.k)
        return [t_s, *self.q, *self.w, *track._pos[j:j + 3], *track._vel[j:j + 3]]

    @property
    def wheel_speeds_rad_s(self) -> tuple:
        """Wheel speeds relative to the body (rad/s), one per wheel, as a tachometer reads them (() without wheels)."""
        # Every wheel device reads its speed several times a tick (its motor, its telemetry, its row) and the
        # controller may read them too: computed once per state. The key is the state tuples themselves, not the
        # step index, so a state put in from outside (a test setting ``w``) is never answered from the cache.
        # Without wheels the key never matches (``w`` is never None): ``h_wheels``, which does not exist, is not read.
        cache = self._wheel_speeds
        if cache[0] is self.w and cache[1] is self.h_wheels:
            return cache[2]
        if self.wheels is None:
            return ()
        w, h_wheels = self.w, self.h_wheels
        speeds = _step.relative_speeds(self._wheeled._A, self._wheeled._J, h_wheels, w)
        self._wheel_speeds = (w, h_wheels, speeds)
        return speeds

    def angular_momentum_B(self) -> tuple:
        """Total angular momentum of body and wheels (N m s, body components)."""
        I = self._I
        w0, w1, w2 = self.w
        H = (I[0] * w0 + I[1] * w1 + I[2] * w2, I[3] * w0 + I[4] * w1 + I[5] * w2,
             I[6] * w0 + I[7] * w1 + I[8] * w2)
        if self.wheels is None:
            return H
        # I omega + A J Omega = I_s omega + A h
        Is = self._wheeled.hub._I
        hx, hy, hz = self._wheeled.axes_sum(self.h_wheels)
        return (Is[0] * w0 + Is[1] * w1 + Is[2] * w2 + hx, Is[3] * w0 + Is[4] * w1 + Is[5] * w2 + hy,
                Is[6] * w0 + Is[7] * w1 + Is[8] * w2 + hz)

    def b_B(self, _t_s: float | None = None):
        """The field in body axes at the current step (T); ``_t_s`` is ignored, so a device can take this as
        its field source ``(t_s) -> b`` without a wrapper."""
        k, b = self._b_B
        if k != self.k:  # q only changes in step(), which advances k
            b = rotate_to_body(self.q, self.track.field(2 * self.k))
            self._b_B = (self.k, b)
        return b

    # --- dynamics --------------------------------------------------------------------------------
    def _torque_and_body(self, t, q, w):
        """The environment's torque at a stage plus the held body torque of the "torque" effects."""
        bx, by, bz = self.torque_B
        if not (self.magnetic or self.gravity_gradient):
            return bx, by, bz
        tx, ty, tz = self._environment(t, q, w)
        return tx + bx, ty + by, tz + bz

    def effector(self, effects) -> Callable[[], None]:
        """The dynamics step under ``effects`` (:class:`Effect`): a function of no argument that reads every effect
        once, then advances one step holding what they gave (dipoles summed in the order given, body torques summed,
        each rotor's torque to its column). Built once before t = 0, so a step pays only for the reads. A rotor
        column no effect targets keeps a zero torque. Raises ValueError for an unknown type or a bad target."""
        by_type: dict[str, list] = {t: [] for t in EFFECT_TYPES}
        for e in effects:
            if e.type not in by_type:
                raise ValueError(f"effect type {e.type!r} is not one of {', '.join(EFFECT_TYPES)}.")
            by_type[e.type].append(e)
        truth_step, dipoles = self.step, [e.read for e in by_type["dipole"]]
        rotors = self._rotor_reader(by_type["momentum_exchange"])
        if by_type["torque"]:
            body = _summed3([e.read for e in by_type["torque"]])
            dipole = _summed3(dipoles)
            self._stage_torque = self._torque_and_body

            model = self  # not ``self`` inside: a failing read is blamed on its device, not on the truth

            def step_with_body_torque():
                model.torque_B = body()
                truth_step(dipole(), None if rotors is None else rotors())

            return step_with_body_torque
        if rotors is not None:  # wheels: what step() calls for them, one call less a tick
            wheels_step = self._step_wheels
            if not dipoles:  # a wheel-only spacecraft: the zero dipole without a reader
                zero = (0.0, 0.0, 0.0)
                return lambda: wheels_step(zero, rotors())
            dipole = _summed3(dipoles)
            return lambda: wheels_step(dipole(), rotors())
        if not dipoles:  # no actuator: the truth's own step with a zero dipole, through one C-level call
            return functools.partial(truth_step, (0.0, 0.0, 0.0))
        if len(dipoles) == 1:  # the usual magnetic spacecraft: one call less per step
            read = dipoles[0]

            def step_one_dipole():
                m = read()
                truth_step((0.0 + m[0], 0.0 + m[1], 0.0 + m[2]))

            return step_one_dipole
        dipole = _summed3(dipoles)
        return lambda: truth_step(dipole())

    def _rotor_reader(self, effects):
        """None without momentum exchange, else a reader of the rotor torques in column order."""
        if not effects:
            return None
        columns = [e.target for e in effects]
        if self.wheels is None:
            raise ValueError(f"momentum_exchange targets {columns}, but the truth has no wheel cluster (no device's "
                             "kind declared a momentum wheel: DeviceKind.momentum_wheel).")
        n = self.wheels.n
        if len(set(columns)) != len(columns) or not all(isinstance(c, int) and 0 <= c < n for c in columns):
            raise ValueError(f"momentum_exchange targets {columns}: each must name a different rotor column of the "
                             f"truth's wheel cluster (0 to {n - 1}; it has {n} wheels).")
        readers = [float] * n  # float() is 0.0: a column no effect targets
        for e in effects:
            readers[e.target] = e.read
        readers = tuple(readers)

        def rotors():  # a loop, not a comprehension: no frame of its own on every step (Python 3.11)
            torques = []
            for read in readers:  # ``read``: the name stand.loop looks for to blame a failing read on its device
                torques.append(read())
            return tuple(torques)

        return rotors

    def step(self, dipole_B=(0.0, 0.0, 0.0), wheel_torque_Nm=None) -> None:
        """Advance one dynamics step holding the actuator dipole (A m^2, body axes) constant, and with wheels
        the net torque on each rotor (N m about its spin axis: motor minus friction; None keeps the last)."""
        if self.wheels is not None:
            self._step_wheels(dipole_B, wheel_torque_Nm)
            return
        if wheel_torque_Nm is not None:
            raise ValueError("wheel_torque_Nm was given to a truth model without wheels.")
        self._hold(dipole_B)
        # Stage times are passed relative to the step start so the stage lookup is exact.
        q, w = self._step(self.q, self.w, self.h, self._stage_torque, 0.0)
        if w[0] * w[0] + w[1] * w[1] + w[2] * w[2] > self._limit_sq:
            check_step(self.body.inertia, w, self.h, "dynamics.step_s", self._max_angle, self.integrator)
        self.q, self.w = q, w
        self.k += 1
        self.t_ns += self.step_ns

    def _hold(self, dipole_B) -> None:
        """Hold ``dipole_B`` over the next step and give the environment's torque the step's three half-step points:
        the field and the position at the step's start, middle and end, only what the listed torques use."""
        self.dipole_B = dipole_B
        if self._stage_torque is None:
            return
        mag, gg = self.magnetic, self.gravity_gradient
        track, base = self.track, 2 * self.k
        j = base - track._chunk_start_idx
        if 0 <= j and j + 2 < track._chunk_len:  # the usual case: one slice of each flat list
            j *= 3
            f = tuple(track._field[j:j + 9]) if mag else None
            p = tuple(track._pos[j:j + 9]) if gg else None
        else:  # the step crosses into a new chunk: point by point, field before position (the order fills go in)
            fs, ps = [], []
            for i in (base, base + 1, base + 2):
                if mag:
                    fs += track.field(i)
                if gg:
                    ps += track.position(i)
            f, p = (tuple(fs) if mag else None), (tuple(ps) if gg else None)
        self._environment.set_step(dipole_B if type(dipole_B) is tuple else tuple(dipole_B), f, p)

    def _step_wheels(self, dipole_B, wheel_torque_Nm) -> None:
        if wheel_torque_Nm is not None:
            tau = _step.finite_floats(wheel_torque_Nm, self.wheels.n)  # the usual tuple of floats: taken as it is
            if tau is None:
                tau = tuple(map(float, wheel_torque_Nm))
                if len(tau) != self.wheels.n or not all(map(math.isfinite, tau)):
                    raise ValueError(f"wheel_torque_Nm = {wheel_torque_Nm!r}; it must be {self.wheels.n} finite "
                                     "torques in N m, one per wheel.")
            self.wheel_torque_Nm = tau
        self._hold(dipole_B)
        torque = self._stage_torque
        body = self._wheeled
        q, w, hw = body.step(self.q, self.w, self.h_wheels, self.wheel_torque_Nm, self.h, torque, 0.0)
        if body.fastest_rate(w, hw) * self.h > self._max_angle:
            body.check_step(w, hw, self.h, "dynamics.step_s")
        self.q, self.w, self.h_wheels = q, w, hw
        self.k += 1
        self.t_ns += self.step_ns
