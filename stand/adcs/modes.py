"""The ADCS mode manager: detumble -> sun acquisition -> fine pointing, with fall-backs and hysteresis.

Modes and transitions (every threshold is a :class:`ModeConfig` field; rates are |omega| in rad/s):

* ``detumble``: rate damping. Left for ``sun_acquisition`` once the rate has stayed below
  ``detumble_exit_rate_rad_s`` for ``hold_s``. Entered from any mode when the rate exceeds
  ``detumble_entry_rate_rad_s`` (above the exit rate: the gap is the hysteresis).
* ``sun_acquisition``: a body axis to the Sun by the sun sensor (or rate hold without one). Left for
  ``fine_pointing`` after ``fine_entry_solutions`` consecutive valid tracker solutions with the rate below
  ``fine_entry_rate_rad_s`` and the filter's 3-sigma below ``max_sigma3_rad``.
* ``fine_pointing``: the estimator's attitude and guidance. Through a tracker outage the filter
  propagates on the gyro (``gyro_only`` is set) for at most ``outage_s`` or until its 3-sigma exceeds
  ``max_sigma3_rad``; then back to ``sun_acquisition``, and re-entry needs the consecutive solutions again.

The manager is pure logic on its inputs; :meth:`ModeManager.update` returns the mode, and ``transitions``
records ``(t_s, from, to, reason)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

DETUMBLE, SUN_ACQUISITION, FINE_POINTING = "detumble", "sun_acquisition", "fine_pointing"
MODES = (DETUMBLE, SUN_ACQUISITION, FINE_POINTING)


@dataclass(frozen=True)
class ModeConfig:
    detumble_entry_rate_rad_s: float = math.radians(2.0)
    detumble_exit_rate_rad_s: float = math.radians(0.5)
    hold_s: float = 10.0
    fine_entry_rate_rad_s: float = math.radians(0.3)
    fine_entry_solutions: int = 5
    outage_s: float = 120.0
    max_sigma3_rad: float = math.radians(0.5)

    def __post_init__(self):
        for name in ("detumble_entry_rate_rad_s", "detumble_exit_rate_rad_s", "hold_s", "fine_entry_rate_rad_s",
                     "outage_s", "max_sigma3_rad"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0.0):
                raise ValueError(f"modes.{name} = {v!r}; it must be a finite number >= 0.")
        if self.detumble_exit_rate_rad_s >= self.detumble_entry_rate_rad_s:
            raise ValueError(f"modes.detumble_exit_rate_rad_s = {self.detumble_exit_rate_rad_s!r} must be below "
                             f"modes.detumble_entry_rate_rad_s = {self.detumble_entry_rate_rad_s!r} (hysteresis).")
        if not (isinstance(self.fine_entry_solutions, int) and self.fine_entry_solutions >= 1):
            raise ValueError(f"modes.fine_entry_solutions = {self.fine_entry_solutions!r}; it must be an integer >= 1.")


class ModeManager:
    def __init__(self, config: ModeConfig | None = None, initial: str = DETUMBLE):
        if initial not in MODES:
            raise ValueError(f"initial mode = {initial!r}; allowed: {', '.join(MODES)}.")
        self.config = config or ModeConfig()
        self.mode = initial
        self.gyro_only = False
        self.transitions: list[tuple[float, str, str, str]] = []
        self._slow_since: float | None = None
        self._good_solutions = 0
        self._last_fix: float | None = None

    def _go(self, t_s: float, mode: str, reason: str) -> None:
        self.transitions.append((t_s, self.mode, mode, reason))
        self.mode = mode
        self._slow_since = None
        self._good_solutions = 0
        self.gyro_only = False

    def update(self, t_s: float, rate_rad_s: float, tracker_valid: bool, sigma3_rad: float = math.inf) -> str:
        """Advance the logic with this control period's inputs; returns the mode to fly."""
        c = self.config
        if not math.isfinite(rate_rad_s):
            raise ValueError(f"rate_rad_s = {rate_rad_s!r}; the mode manager needs a finite body rate.")
        if tracker_valid:
            self._last_fix = t_s
        if self.mode != DETUMBLE and rate_rad_s > c.detumble_entry_rate_rad_s:
            self._go(t_s, DETUMBLE, f"rate {math.degrees(rate_rad_s):.3g} deg/s above "
                                    f"{math.degrees(c.detumble_entry_rate_rad_s):.3g} deg/s")
            return self.mode
        if self.mode == DETUMBLE:
            if rate_rad_s < c.detumble_exit_rate_rad_s:
                if self._slow_since is None:
                    self._slow_since = t_s
                if t_s - self._slow_since >= c.hold_s:
                    self._go(t_s, SUN_ACQUISITION, f"rate below {math.degrees(c.detumble_exit_rate_rad_s):.3g} deg/s "
                                                   f"for {c.hold_s:g} s")
            else:
                self._slow_since = None
        elif self.mode == SUN_ACQUISITION:
            good = tracker_valid and rate_rad_s < c.fine_entry_rate_rad_s and sigma3_rad <= c.max_sigma3_rad
            self._good_solutions = self._good_solutions + 1 if good else 0
            if self._good_solutions >= c.fine_entry_solutions:
                self._go(t_s, FINE_POINTING, f"{c.fine_entry_solutions} consecutive tracker solutions")
        elif self.mode == FINE_POINTING:
            self.gyro_only = not tracker_valid
            lost = self._last_fix is None or t_s - self._last_fix > c.outage_s
            if lost or sigma3_rad > c.max_sigma3_rad:
                why = (f"tracker outage longer than {c.outage_s:g} s" if lost else
                       f"attitude 3-sigma {math.degrees(sigma3_rad):.3g} deg above "
                       f"{math.degrees(c.max_sigma3_rad):.3g} deg")
                self._go(t_s, SUN_ACQUISITION, why)
        return self.mode
