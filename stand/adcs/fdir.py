"""Fault detection, isolation and recovery of the reference ADCS (issue 24), as a real one has it.

Each control period :class:`Fdir` is told what the controller read and commanded, and keeps:

* **wheels** (:class:`WheelMonitor`): a wheel that does not follow its commands is isolated. Over a window of
  ``window_s`` the measured speed change, times the rotor's inertia and divided by the window, is the torque the
  rotor actually got; the mean of the torques commanded over the same periods is what it should have got. When they
  differ by more than ``threshold_Nm`` (default a quarter of the datasheet torque, ``max_wheel_torque_Nm``: far above
  the bearing friction and the one-period offset between a command and the speed it shows up in) for ``persist``
  consecutive periods, the wheel is isolated: commanded to zero and left out of the torque allocation, which becomes
  the pseudo-inverse of the remaining spin axes (never below three wheels that span the three axes). A wheel near
  its rated speed (back-EMF roll-off) or with no fresh speed is not judged.
* **gyro** (:class:`GyroMonitor`): failed when its samples are flagged invalid for ``invalid_periods`` periods in a
  row, when it is silent for ``lost_s``, or stuck (``stuck_samples`` successive samples exactly equal: a live gyro's
  noise never repeats to the bit; a noiseless one, the stand's ``ideal`` gyro, does whenever the body's rate is
  steady to the wire's resolution, so ``fdir_gyro_stuck_samples = 0`` turns this check off for it). The rate then
  comes from the star tracker's attitude differenced over ``TRACKER_RATE_SPAN`` solutions; it goes back to the gyro
  after ``recover_samples`` good samples in a row.
* **tracker**: a solution whose MEKF innovation fails the chi-square gate (``gate_sigma``, see
  :meth:`stand.adcs.determination.MEKF.update_attitude`) is rejected (a misidentified star field, still flagged valid).
* **lost devices**: a device that has given no sample for ``lost_s`` is reported (flag 8), not silently held.

The report is the telemetry column ``adcs_fdir``, bit flags (:data:`FLAGS`): 1 a wheel is isolated, 2 the gyro has
failed (rate from the tracker), 4 the last tracker solution was rejected by the innovation gate, 8 a device is lost;
``isolated`` names the wheels and ``events`` records ``(t_s, what)`` of every change.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from .quat import Vec3, conj, positive, qmul

__all__ = ["FLAGS", "Fdir", "GyroMonitor", "WheelMonitor", "rate_from_attitudes"]

WHEEL_ISOLATED, GYRO_FAILED, TRACKER_REJECTED, DEVICE_LOST = 1, 2, 4, 8
#: Bit -> meaning, for the docs and the report.
FLAGS = {WHEEL_ISOLATED: "a wheel is isolated (the others carry the pointing)",
         GYRO_FAILED: "the gyro has failed (rate from the star tracker's differenced attitude)",
         TRACKER_REJECTED: "the last star tracker solution was rejected by the filter's innovation gate",
         DEVICE_LOST: "a device has given no sample for lost_s"}
#: Tracker solutions the fall-back rate is differenced over (the oldest to the newest): over five periods the
#: tracker's noise on the rate falls five-fold for a lag of two and a half periods.
TRACKER_RATE_SPAN = 6
#: Options of the FDIR (``PointingController`` options, SI units) and their defaults; None: derived (see the module).
OPTIONS = {"fdir": True, "fdir_window_s": 2.0, "fdir_wheel_threshold_Nm": None, "fdir_persist": 3,
           "fdir_lost_s": 5.0, "fdir_gyro_stuck_samples": 10, "max_wheel_speed_rad_s": None}
#: The innovation gate (``gate_sigma``) when the FDIR is on and the option is not given: 5 sigma on each of the three
#: axes, a chi-square of 75 on 3 degrees of freedom (a false rejection about once in 10^15 solutions).
GATE_SIGMA = 5.0


def rate_from_attitudes(q1_BN, q2_BN, dt_s: float) -> Vec3:
    """The mean body rate (rad/s, body axes) taking ``q1_BN`` to ``q2_BN`` in ``dt_s``: q2 = q1 (x) exp(omega dt/2)."""
    w, x, y, z = positive(qmul(conj(q1_BN), q2_BN))
    vn = math.sqrt(x * x + y * y + z * z)
    if vn == 0.0:
        return 0.0, 0.0, 0.0
    k = 2.0 * math.atan2(vn, w) / vn / dt_s
    return x * k, y * k, z * k


class WheelMonitor:
    """Commanded against measured speed change of ``n`` wheels over a window (see the module docstring)."""

    def __init__(self, inertia_kg_m2, max_speed_rad_s: float, period_s: float, window_s: float, threshold_Nm: float,
                 persist: int):
        self.J = [float(j) for j in inertia_kg_m2]
        self.n = len(self.J)
        self.periods = max(1, round(window_s / period_s))
        self.window_s = self.periods * period_s
        self.threshold_Nm = threshold_Nm
        self.persist = persist
        self.judged_below = 0.9 * max_speed_rad_s  # above it the back-EMF may rightly withhold torque
        self._speeds: deque = deque(maxlen=self.periods + 1)  # per period: n speeds, NaN when no fresh sample
        # The last `periods` commands in a ring (row k % periods), so their mean is one sum per period.
        self._cmds = np.zeros((self.periods, self.n))
        self._n_cmds = 0
        self._strikes = [0] * self.n
        #: The newest residual torque per wheel (N m; NaN: not judged).
        self.residual_Nm = [math.nan] * self.n

    def update(self, fresh_speeds) -> list[int]:
        """This period's fresh speeds (n, NaN for none); returns the wheels that failed the check ``persist`` times in a
        row (the caller records the period's commands afterwards with :meth:`commanded`)."""
        self._speeds.append(list(map(float, fresh_speeds)))  # a copy: the caller refills its array
        if len(self._speeds) <= self.periods or self._n_cmds < self.periods:
            return []
        w0, w1 = self._speeds[0], self._speeds[-1]
        want_sum = self._cmds.sum(axis=0).tolist()
        limit = self.judged_below
        for i in range(self.n):
            r = self.J[i] * (w1[i] - w0[i]) / self.window_s - want_sum[i] / self.periods  # got - commanded
            if math.isfinite(r) and abs(w0[i]) < limit and abs(w1[i]) < limit:
                self.residual_Nm[i] = r
                self._strikes[i] = self._strikes[i] + 1 if abs(r) > self.threshold_Nm else 0
            else:
                self.residual_Nm[i] = math.nan  # not judged: the strikes stay as they were
        return [i for i in range(self.n) if self._strikes[i] >= self.persist]

    def commanded(self, torques_Nm) -> None:
        self._cmds[self._n_cmds % self.periods] = torques_Nm
        self._n_cmds += 1


class GyroMonitor:
    """A gyro's health from its samples (see the module docstring)."""

    def __init__(self, invalid_periods: int = 3, stuck_samples: int = 10, recover_samples: int = 10):
        self.invalid_periods = invalid_periods
        self.stuck_samples = stuck_samples
        self.recover_samples = recover_samples
        self.failed = False
        self.why = ""
        self._invalid = 0
        self._same = 0
        self._good = 0
        self._last: tuple | None = None

    def sample(self, omega, valid: bool) -> None:
        """One sample: its rate (sensor axes) and whether it was flagged valid and usable."""
        if not valid:
            self._invalid += 1
            self._good = 0
            if self._invalid >= self.invalid_periods:
                self._fail(f"{self._invalid} invalid samples in a row")
            return
        self._invalid = 0
        w = tuple(map(float, omega))
        self._same = self._same + 1 if w == self._last else 0
        self._last = w
        if self.stuck_samples and self._same + 1 >= self.stuck_samples:
            self._good = 0
            self._fail(f"stuck: {self._same + 1} identical samples")
            return
        self._good += 1
        if self.failed and self._good >= self.recover_samples:
            self.failed, self.why = False, ""

    def silent(self, seconds: float) -> None:
        self._good = 0
        self._fail(f"no sample for {seconds:.3g} s")

    def _fail(self, why: str) -> None:
        if not self.failed:
            self.failed, self.why = True, why


class Fdir:
    """The FDIR state of one :class:`~stand.adcs.pointing.PointingController` (see the module docstring)."""

    def __init__(self, wheel_monitor: WheelMonitor, lost_s: float, device_names, gyro_stuck_samples: int = 10):
        self.wheels = wheel_monitor
        self.gyro = GyroMonitor(stuck_samples=gyro_stuck_samples)
        self.lost_s = lost_s
        self.isolated: list[int] = []
        self.tracker_rejected = False
        self.lost: set[str] = set()
        self._last_sample = {name: None for name in device_names}
        self._t0: float | None = None
        self._solutions: deque = deque(maxlen=TRACKER_RATE_SPAN)  # (t_s, q_BN) of accepted or rejected solutions
        self.events: list[tuple[float, str]] = []

    @property
    def flags(self) -> int:
        return ((WHEEL_ISOLATED if self.isolated else 0) | (GYRO_FAILED if self.gyro.failed else 0)
                | (TRACKER_REJECTED if self.tracker_rejected else 0) | (DEVICE_LOST if self.lost else 0))

    def heard(self, name: str, t_s: float) -> None:
        """A sample (any, valid or not) came from device ``name`` this period."""
        self._last_sample[name] = t_s

    def silent_s(self, name: str, t_s: float) -> float:
        """Seconds since device ``name`` gave its last sample (or since the first period, if it never gave one)."""
        last = self._last_sample[name]
        return t_s - (self._t0 if last is None else last)

    def check_silence(self, t_s: float) -> None:
        """Devices silent for more than ``lost_s`` (since their last sample, or since the first period)."""
        if self._t0 is None:
            self._t0 = t_s
        for name in self._last_sample:
            silent = self.silent_s(name, t_s)
            if silent > self.lost_s:
                if name not in self.lost:
                    self.lost.add(name)
                    self.events.append((t_s, f"{name} lost: no sample for {silent:.3g} s"))
            elif name in self.lost:
                self.lost.discard(name)
                self.events.append((t_s, f"{name} heard again"))

    def tracker_solution(self, t_s: float, q_BN) -> None:
        self._solutions.append((t_s, tuple(q_BN)))

    def tracker_rate_B(self) -> Vec3 | None:
        """The body rate from the oldest and newest tracker solutions kept (rad/s), or None with fewer than two."""
        if len(self._solutions) < 2:
            return None
        (t1, q1), (t2, q2) = self._solutions[0], self._solutions[-1]
        return rate_from_attitudes(q1, q2, t2 - t1) if t2 > t1 else None
