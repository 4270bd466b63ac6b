"""The Helmholtz cage itself, pure: three single-quadrant current supplies behind polarity relays,
three coil pairs, the interlocks and a magnetometer at the test position, stepped in time. No port,
no clock, no thread: :class:`~drivers.cage.emulator.CageEmulator` puts it behind a Modbus server and
decides what time it is; tests step it directly.

Physics per axis, every regulator period ``h`` (the supply's control period):

- Coil: ``L di/dt = V - R i`` with ``V`` held over the period, stepped exactly (zero-order hold):
  ``i+ = V/R + (i - V/R) exp(-h R / L)`` -- the update of ``sim.actuators.CoilLR`` (drivers may
  not import sim; a test compares the two).
- Supply: a current regulator. Its reference moves towards ``min(set point, current limit)`` by at
  most ``slew limit x h``; the voltage is the one that brings the coil exactly onto the reference at
  the end of the period, clipped to ``[0, compliance]`` (single quadrant: it cannot drive a current
  down, the coil decays through its free-wheel path at ``V = 0``).
- Relay: sets the sign of the coil current. A change of the requested polarity is held while the
  current is above ``zero_current_A``; below it the axis' output goes off for the dead time, and the
  relay has switched at its end.
- Coil temperature: first order, ``T+ = T_ss + (T - T_ss) exp(-h / tau)``, ``T_ss = ambient + R_th R i^2``.
- Field at the test position: ``b_T = K i_signed + b_lab(t)`` (``K`` 3x3, T/A: coil constants with
  the cross-coupling of real coils); the magnetometer samples it every ``mag_period_s`` with white
  noise and saturates at ``mag_range_T``.

Coil failure (fault injection): :attr:`CageModel.failed_coil_axes` (axis indices, none by default) are open
circuits: no current flows in those pairs whatever the supply does (its regulator then runs to the compliance
voltage), so they add no field and their current reads 0.

Interlocks hold whatever is written: set points above the limit are held at the limit, every change
is slew-limited, a heartbeat older than the timeout or a coil above the trip temperature switches
the outputs off (latched), and relays never switch under current. The ``interlocks`` register and
the event counters say why (see ``docs/cage_register_map.md``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.cage.registers import RegisterMap, load_map
from drivers.device_faults import axis_indices

__all__ = ["EXC_ILLEGAL_ADDRESS", "EXC_ILLEGAL_FUNCTION", "EXC_ILLEGAL_VALUE", "CageConfig", "CageModel"]

#: Modbus exception codes the model answers with (the emulator hands them to pymodbus).
EXC_ILLEGAL_FUNCTION = 1
EXC_ILLEGAL_ADDRESS = 2
EXC_ILLEGAL_VALUE = 3

_TICK_EPS = 1e-9  # s: a requested time this close above a period boundary counts as on it

LabField = Callable[[float], Sequence[float]]


def _triple(name: str, value: Any, unit: str, positive: bool = True) -> tuple[float, float, float]:
    try:
        x = tuple(float(v) for v in value)
    except TypeError:
        x = (float(value),) * 3
    if len(x) != 3 or not all(math.isfinite(v) and (v > 0 or not positive) for v in x):
        what = "positive" if positive else "finite"
        raise ValueError(f"CageConfig.{name} = {value!r} is not allowed; give three {what} numbers in {unit}.")
    return x  # type: ignore[return-value]


@dataclass(frozen=True)
class CageConfig:
    """The cage on one bench. Defaults: a 1 m class cage with ~50 uT/A per axis on 30 V supplies.

    Attributes (per axis where a triple):
        inductance_H, resistance_ohm: coil pair (tau = L/R = 10 ms by default).
        coil_T_per_A: 3x3 matrix K, field at the test position per ampere, rows = field axes,
            columns = coils (off-diagonal = cross-coupling and mounting misalignment).
        lab_field_T: the residual field in the lab at the test position, cage axes.
        compliance_V: largest supply voltage.
        current_limit_A, slew_limit_A_s: the supplies' current and slew limits.
        regulator_period_s: control period of the supplies (the model's step).
        polarity_dead_time_s, zero_current_A: relay switching (output off for the dead time; only
            below the zero current).
        heartbeat_timeout_s: longest gap between two heartbeat changes with the outputs on.
        ambient_C, thermal_resistance_K_W, thermal_time_constant_s: coil temperature model.
        temperature_trip_C, temperature_reset_C: over-temperature trip, and below what it can clear.
        mag_period_s, mag_noise_T, mag_range_T: magnetometer sample period, 1-sigma white noise
            per axis, saturation.
        device_id: Modbus unit id.
    """

    inductance_H: tuple[float, float, float] = (0.048, 0.050, 0.052)
    resistance_ohm: tuple[float, float, float] = (4.9, 5.0, 5.1)
    coil_T_per_A: tuple[tuple[float, float, float], ...] = (
        (5.10e-5, 0.30e-6, -0.20e-6),
        (-0.25e-6, 4.90e-5, 0.40e-6),
        (0.15e-6, -0.35e-6, 5.30e-5),
    )
    lab_field_T: tuple[float, float, float] = (19.5e-6, -1.8e-6, 43.2e-6)
    compliance_V: float = 30.0
    current_limit_A: float = 4.0
    slew_limit_A_s: float = 10.0
    regulator_period_s: float = 1e-3
    polarity_dead_time_s: float = 0.02
    zero_current_A: float = 1e-3
    heartbeat_timeout_s: float = 0.5
    ambient_C: float = 22.0
    thermal_resistance_K_W: float = 0.5
    thermal_time_constant_s: float = 900.0
    temperature_trip_C: float = 60.0
    temperature_reset_C: float = 50.0
    mag_period_s: float = 0.01
    mag_noise_T: float = 5e-9
    mag_range_T: float = 1e-3
    device_id: int = 1

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "inductance_H", _triple("inductance_H", self.inductance_H, "H"))
        set_(self, "resistance_ohm", _triple("resistance_ohm", self.resistance_ohm, "ohm"))
        set_(self, "lab_field_T", _triple("lab_field_T", self.lab_field_T, "T", positive=False))
        k = np.asarray(self.coil_T_per_A, dtype=float)
        if k.shape != (3, 3) or not np.all(np.isfinite(k)) or abs(np.linalg.det(k)) < 1e-30:
            raise ValueError(f"CageConfig.coil_T_per_A = {self.coil_T_per_A!r} is not allowed; give an invertible "
                             "3x3 matrix of finite numbers in T/A.")
        set_(self, "coil_T_per_A", tuple(tuple(float(v) for v in row) for row in k))
        # (name, upper bound the register map can show); all must be positive and finite
        for name, hi in (("compliance_V", 65.535), ("current_limit_A", 6.5535), ("slew_limit_A_s", 65.535),
                         ("regulator_period_s", 0.1), ("polarity_dead_time_s", 65.535), ("zero_current_A", 6.5535),
                         ("heartbeat_timeout_s", 65.535), ("thermal_resistance_K_W", math.inf),
                         ("thermal_time_constant_s", math.inf), ("mag_period_s", 60.0), ("mag_range_T", 0.2)):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and 0 < v <= hi):
                raise ValueError(f"CageConfig.{name} = {v!r} is not allowed; give a positive number up to {hi:g}.")
        if not (math.isfinite(self.mag_noise_T) and self.mag_noise_T >= 0):
            raise ValueError(f"CageConfig.mag_noise_T = {self.mag_noise_T!r} is not allowed; give a number >= 0 T.")
        if not -50 <= self.temperature_reset_C < self.temperature_trip_C <= 300:
            raise ValueError(f"CageConfig.temperature_reset_C = {self.temperature_reset_C!r} and temperature_trip_C = "
                             f"{self.temperature_trip_C!r} are not allowed; give -50 <= reset < trip <= 300 degC.")
        if not -50 <= self.ambient_C < self.temperature_reset_C:
            raise ValueError(f"CageConfig.ambient_C = {self.ambient_C!r} is not allowed; it must lie below "
                             f"temperature_reset_C ({self.temperature_reset_C!r} degC).")
        if self.zero_current_A >= self.current_limit_A:
            raise ValueError(f"CageConfig.zero_current_A = {self.zero_current_A!r} is not allowed; it must lie below "
                             f"current_limit_A ({self.current_limit_A!r} A).")
        if not (isinstance(self.device_id, int) and 1 <= self.device_id <= 247):
            raise ValueError(f"CageConfig.device_id = {self.device_id!r} is not allowed; give 1..247.")


@dataclass
class _Axis:
    """State of one supply, relay and coil pair."""

    i_A: float = 0.0  # coil current magnitude (>= 0: single quadrant)
    ref_A: float = 0.0  # the regulator's slew-limited reference
    v_V: float = 0.0
    negative: bool = False  # relay position
    dead_until_s: float | None = None  # relay switching: output off until then
    temperature_C: float = 22.0
    slewing: bool = False
    decay: float = 0.0  # exp(-h R / L)
    resistance_ohm: float = 1.0


@dataclass
class _Events:
    current_limit_events: int = 0
    slew_limit_events: int = 0
    heartbeat_trips: int = 0
    polarity_holds: int = 0
    over_temperature_trips: int = 0
    refused_writes: int = 0
    last: str = "none"
    last_axis: str = "all"


class CageModel:
    """The cage, stepped by :meth:`advance`; read and written as Modbus registers.

    Args:
        config: the bench's :class:`CageConfig`.
        rng: seed or ``numpy.random.Generator`` of the magnetometer noise.
        lab_field: optional ``lab_field(t_s) -> 3 floats`` (T, cage axes) replacing the constant
            ``config.lab_field_T`` (a moving lab disturbance).
        regmap: the register map (default: the ICD).

    Time starts at 0 (power-up) and only moves forward, in steps of ``config.regulator_period_s``.
    """

    def __init__(self, config: CageConfig | None = None, *, rng: int | np.random.Generator | None = 0,
                 lab_field: LabField | None = None, regmap: RegisterMap | None = None) -> None:
        self.config = cfg = config if config is not None else CageConfig()
        self.map = regmap if regmap is not None else load_map()
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self._lab_field = lab_field
        self._K = np.asarray(cfg.coil_T_per_A, dtype=float)
        h = cfg.regulator_period_s
        self.axes = [
            _Axis(temperature_C=cfg.ambient_C, decay=math.exp(-h * r / ind), resistance_ohm=r)
            for ind, r in zip(cfg.inductance_H, cfg.resistance_ohm, strict=True)
        ]
        self._thermal_decay = math.exp(-h / cfg.thermal_time_constant_s)
        self.k = 0  # regulator periods since power-up
        # holding registers (raw)
        self.output_on = False
        self.polarity_request = 0
        self.setpoint_raw = [0, 0, 0]
        self.heartbeat = 0
        self._t_heartbeat = -math.inf
        # latches and events
        self.heartbeat_lost = False
        self.over_temperature = False
        self.events = _Events()
        # magnetometer
        self.field_T = (0.0, 0.0, 0.0)
        self.field_time_s = 0.0
        self.field_valid = False
        self._k_next_sample = 0
        self._noise = np.zeros((0, 3))
        self._noise_i = 0
        self._k_per_sample = max(1, round(cfg.mag_period_s / h))
        self._holding = self.map.holding
        self._input_regs = list(self.map.input.values())
        self._setpoint_scale = self._holding["current_setpoint_x_A"].scale
        self._failed_axes: tuple[int, ...] = ()  # open coil pairs (fault injection)

    @property
    def failed_coil_axes(self) -> tuple[int, ...]:
        """The coil pairs (0 x, 1 y, 2 z) that are open circuits: no current, no field (module docstring)."""
        return self._failed_axes

    @failed_coil_axes.setter
    def failed_coil_axes(self, axes) -> None:
        self._failed_axes = axis_indices("failed_coil_axes", axes)

    # -- time ------------------------------------------------------------------------------------

    @property
    def t_s(self) -> float:
        """Model time, s since power-up (a whole number of regulator periods)."""
        return self.k * self.config.regulator_period_s

    def advance(self, t_s: float) -> int:
        """Step to the last regulator period boundary at or before ``t_s``; returns the periods run.

        Raises ValueError for a time before the model's (time only moves forward) or not finite.
        """
        if not math.isfinite(t_s):
            raise ValueError(f"t_s = {t_s!r} is not allowed; give a finite time in s.")
        h = self.config.regulator_period_s
        target = math.floor(t_s / h + _TICK_EPS)
        if target < self.k:
            if t_s < self.t_s - h:
                raise ValueError(f"t_s = {t_s!r} s lies before the cage's time {self.t_s!r} s; time only moves "
                                 "forward.")
            return 0
        n = target - self.k
        for _ in range(n):
            self._period()
        return n

    def _period(self) -> None:
        cfg = self.config
        h = cfg.regulator_period_s
        t = self.k * h
        if self.output_on and t - self._t_heartbeat > cfg.heartbeat_timeout_s:
            self._trip("heartbeat_lost")
        if not self.over_temperature and any(ax.temperature_C > cfg.temperature_trip_C for ax in self.axes):
            self._trip("over_temperature")
        limit = cfg.current_limit_A
        step_max = cfg.slew_limit_A_s * h
        failed = self._failed_axes
        for a, ax in enumerate(self.axes):
            want_negative = bool(self.polarity_request >> a & 1)
            target = min(self.setpoint_raw[a] * self._setpoint_scale, limit)
            if ax.dead_until_s is not None:
                if t >= ax.dead_until_s - _TICK_EPS:
                    ax.negative = want_negative
                    ax.dead_until_s = None
            elif want_negative != ax.negative:
                target = 0.0
                if ax.i_A < cfg.zero_current_A:
                    ax.dead_until_s = t + cfg.polarity_dead_time_s
            on = self.output_on and ax.dead_until_s is None
            r, d = ax.resistance_ohm, ax.decay
            if on:
                diff = target - ax.ref_A
                slewing = abs(diff) > step_max
                ax.ref_A = ax.ref_A + math.copysign(step_max, diff) if slewing else target
                if slewing and not ax.slewing:
                    self.events.slew_limit_events += 1
                    self._note("slew_limit", a)
                ax.slewing = slewing
                # the voltage that lands the coil on the reference at the end of the period
                v = r * (ax.ref_A - ax.i_A * d) / (1.0 - d)
                v = 0.0 if v < 0.0 else (cfg.compliance_V if v > cfg.compliance_V else v)
            else:
                v = 0.0
                ax.slewing = False
            i_ss = v / r
            ax.i_A = max(i_ss + (ax.i_A - i_ss) * d, 0.0)
            if failed and a in failed:
                ax.i_A = 0.0  # an open coil pair: nothing flows
            if not on:
                ax.ref_A = ax.i_A  # bumpless: a later ramp starts from the current that flows
            ax.v_V = v
            t_ss = cfg.ambient_C + cfg.thermal_resistance_K_W * r * ax.i_A * ax.i_A
            ax.temperature_C = t_ss + (ax.temperature_C - t_ss) * self._thermal_decay
        self.k += 1
        if self.k >= self._k_next_sample:
            self._sample()
            self._k_next_sample = self.k + self._k_per_sample

    def _trip(self, why: str) -> None:
        if why == "heartbeat_lost":
            self.heartbeat_lost = True
            self.events.heartbeat_trips += 1
        else:
            self.over_temperature = True
            self.events.over_temperature_trips += 1
        self.output_on = False
        self._note(why, None)

    def _note(self, why: str, axis: int | None) -> None:
        self.events.last = why
        self.events.last_axis = "all" if axis is None else self.map.axes[axis]

    # -- what the cage produces ------------------------------------------------------------------

    def currents_A(self) -> tuple[float, float, float]:
        """Coil currents, signed by the relays (A)."""
        return tuple(-ax.i_A if ax.negative else ax.i_A for ax in self.axes)  # type: ignore[return-value]

    def lab_field_T(self, t_s: float | None = None) -> np.ndarray:
        t = self.t_s if t_s is None else t_s
        b = self._lab_field(t) if self._lab_field is not None else self.config.lab_field_T
        out = np.asarray(b, dtype=float).reshape(3)
        if not np.all(np.isfinite(out)):
            raise ValueError(f"lab_field({t!r}) must return 3 finite floats (T, cage axes); got {b!r}.")
        return out

    def cage_field_T(self) -> np.ndarray:
        """The noiseless field at the test position now (T, cage axes): coils plus lab."""
        return self._K @ np.asarray(self.currents_A()) + self.lab_field_T()

    def _sample(self) -> None:
        cfg = self.config
        if self._noise_i >= len(self._noise):
            self._noise = self.rng.standard_normal((256, 3)) * cfg.mag_noise_T
            self._noise_i = 0
        b = self.cage_field_T() + self._noise[self._noise_i]
        self._noise_i += 1
        r = cfg.mag_range_T
        self.field_valid = bool(np.all(np.abs(b) <= r))
        self.field_T = tuple(float(min(max(x, -r), r)) for x in b)  # type: ignore[assignment]
        self.field_time_s = self.t_s

    # -- registers -------------------------------------------------------------------------------

    def holding_words(self) -> list[int]:
        """Holding registers 0.. as words."""
        return [1 if self.output_on else 0, self.polarity_request, *self.setpoint_raw, self.heartbeat]

    def interlock_flags(self) -> frozenset[str]:
        cfg = self.config
        flags = set()
        if self.heartbeat_lost:
            flags.add("heartbeat_lost")
        if self.over_temperature:
            flags.add("over_temperature")
        for a, name in enumerate(self.map.axes):
            ax = self.axes[a]
            if self.setpoint_raw[a] * self._setpoint_scale > cfg.current_limit_A:
                flags.add(f"current_limit_{name}")
            if ax.slewing:
                flags.add(f"slew_limit_{name}")
            if bool(self.polarity_request >> a & 1) != ax.negative:
                flags.add(f"polarity_held_{name}")
        return frozenset(flags)

    def status_flags(self) -> frozenset[str]:
        flags = set()
        if self.output_on:
            flags.add("output_on")
        if self.field_valid:
            flags.add("field_valid")
        for a, name in enumerate(self.map.axes):
            if self.axes[a].negative:
                flags.add(f"relay_negative_{name}")
            if self.axes[a].dead_until_s is not None:
                flags.add(f"dead_time_{name}")
        return frozenset(flags)

    def input_values(self) -> dict[str, Any]:
        """Every input register's value (SI, bit names, enum names), by name."""
        cfg, ev, t = self.config, self.events, self.t_s
        cur = self.currents_A()
        wrap = 0xFFFF
        v: dict[str, Any] = {
            "field_time_s": (round(self.field_time_s * 1e3) & 0xFFFFFFFF) * 1e-3,
            "status": self.status_flags(),
            "interlocks": self.interlock_flags(),
            "last_interlock": ev.last,
            "last_interlock_axis": ev.last_axis,
            "current_limit_events": ev.current_limit_events & wrap,
            "slew_limit_events": ev.slew_limit_events & wrap,
            "heartbeat_trips": ev.heartbeat_trips & wrap,
            "polarity_holds": ev.polarity_holds & wrap,
            "over_temperature_trips": ev.over_temperature_trips & wrap,
            "refused_writes": ev.refused_writes & wrap,
            "current_limit_A": cfg.current_limit_A,
            "slew_limit_A_s": cfg.slew_limit_A_s,
            "heartbeat_timeout_s": cfg.heartbeat_timeout_s,
            "temperature_trip_C": cfg.temperature_trip_C,
            "temperature_reset_C": cfg.temperature_reset_C,
            "polarity_dead_time_s": cfg.polarity_dead_time_s,
            "zero_current_A": cfg.zero_current_A,
            "uptime_s": (round(t * 1e3) & 0xFFFFFFFF) * 1e-3,
            "heartbeat_age_s": min(t - self._t_heartbeat, 65.535),
            "map_version": self.map.version_word,
        }
        for a, name in enumerate(self.map.axes):
            v[f"current_{name}_A"] = cur[a]
            v[f"field_{name}_T"] = self.field_T[a]
            v[f"coil_temperature_{name}_C"] = self.axes[a].temperature_C
            v[f"supply_voltage_{name}_V"] = self.axes[a].v_V
        return v

    def input_words(self) -> list[int]:
        """Input registers 0.. as words."""
        values = self.input_values()
        words: list[int] = []
        for r in self._input_regs:
            v = values[r.name]
            if isinstance(v, float):  # a measurement beyond what its register carries reads as the end of the range
                lo, hi = r.si_range
                v = min(max(v, lo), hi)
            words += r.encode(v)
        return words

    def _span_ok(self, table: str, address: int, count: int) -> bool:
        """A request must cover whole registers: start at one and end at the end of one."""
        if count < 1 or address < 0:
            return False
        first = self.map.at(table, address)
        last = self.map.covering(table, address + count - 1)
        return first is not None and last is not None and address + count == last.address + last.words and all(
            self.map.covering(table, a) is not None for a in range(address, address + count))

    def read(self, table: str, address: int, count: int) -> list[int] | int:
        """Words ``address .. address + count - 1`` of ``table`` (``"holding"``/``"input"``), or a
        Modbus exception code (2: outside the map, or a request that splits a 32-bit value)."""
        if not self._span_ok(table, address, count):
            return EXC_ILLEGAL_ADDRESS
        words = self.holding_words() if table == "holding" else self.input_words()
        return words[address : address + count]

    def write(self, address: int, words: Sequence[int]) -> int:
        """Write holding registers from ``address``; 0 when applied, else a Modbus exception code
        (2 outside the map, 3 a value a register does not accept) and nothing is applied."""
        words = [int(w) & 0xFFFF for w in words]
        if not self._span_ok("holding", address, len(words)):
            self.events.refused_writes += 1
            return EXC_ILLEGAL_ADDRESS
        regs = {}
        for i, w in enumerate(words):
            r = self.map.at("holding", address + i)
            if r is None or not r.accepts(w):
                self.events.refused_writes += 1
                return EXC_ILLEGAL_VALUE
            regs[r.name] = w
        self._apply(regs)
        return 0

    def _apply(self, regs: dict[str, int]) -> None:
        cfg = self.config
        t = self.t_s
        if "heartbeat" in regs:  # first, so one request may carry a heartbeat and the enable
            if regs["heartbeat"] != self.heartbeat:
                self._t_heartbeat = t
            self.heartbeat = regs["heartbeat"]
        if "polarity_request" in regs:
            new = regs["polarity_request"]
            for a in range(3):
                bit = bool(new >> a & 1)
                ax = self.axes[a]
                if bit != bool(self.polarity_request >> a & 1) and bit != ax.negative and ax.i_A >= cfg.zero_current_A:
                    self.events.polarity_holds += 1
                    self._note("polarity_held", a)
            self.polarity_request = new
        for a, name in enumerate(self.map.axes):
            key = f"current_setpoint_{name}_A"
            if key in regs:
                was_over = self.setpoint_raw[a] * self._setpoint_scale > cfg.current_limit_A
                self.setpoint_raw[a] = regs[key]
                if self.setpoint_raw[a] * self._setpoint_scale > cfg.current_limit_A and not was_over:
                    self.events.current_limit_events += 1
                    self._note("current_limit", a)
        if "output_enable" in regs:
            if regs["output_enable"] == 0:
                self.output_on = False
            else:
                if self.heartbeat_lost and t - self._t_heartbeat <= cfg.heartbeat_timeout_s:
                    self.heartbeat_lost = False
                if self.over_temperature and all(ax.temperature_C < cfg.temperature_reset_C for ax in self.axes):
                    self.over_temperature = False
                if not self.output_on and t - self._t_heartbeat > cfg.heartbeat_timeout_s:
                    # going on without a fresh heartbeat would trip at once: latch now and say why, but it is a
                    # refused enable, not a trip (heartbeat_trips counts outputs switched off)
                    self.heartbeat_lost = True
                    self._note("heartbeat_lost", None)
                self.output_on = not (self.heartbeat_lost or self.over_temperature)
