"""Emulator: the stand *being* the magnetorquer board, on any python-can bus.

The emulator speaks the ICD (``fixtures/devices/magnetorquer.dbc``) through the same codec as the
host driver. It knows no physics: the stand hands it ``field_source(t_s)``, the TRUE flux density
at the magnetometer in sensor axes (T), and reads back :meth:`MagnetorquerEmulator.dipole_at`, the
dipole the coils actually produce, to compute the torque.

Behaviour (times are sim seconds passed in by the caller; the emulator never reads a clock):

- Modes: OFF (coils off, dipole commands refused), DIPOLE (dipole commands accepted), SELFTEST
  (modelled as coils off and dipole commands refused; no self-test pattern). Any mode change
  switches the coils off. The board boots in ``EmulatorConfig.initial_mode``.
- MTQ_DIPOLE_CMD received at ``t``: each axis is clipped to ``max_dipole_A_m2`` keeping its sign
  (one ``saturations`` count per clipped command), quantised to ``dipole_lsb_A_m2`` (the PWM
  step), driven from ``t`` until ``t + duration``; then the watchdog switches the coils off and
  counts a ``watchdog_expiries``. A new command replaces the previous one; duration 0 = off now.
- Coil faults (attributes, neutral by default; set at any time, they act at once): ``coil_gain`` per axis
  scales the dipole a coil produces from what the board drives (1 nominal, 0 an open coil, -1 a coil wired
  with its polarity reversed); ``stuck_on_axes`` (axis indices 0..2): those coils hold the rated dipole with the
  sign of the last command that drove them (+ if none did), whatever is commanded, in every mode and past the
  watchdog. The board reports in MTQ_STATUS the current its drivers measure: nothing through an open coil, the
  commanded current through a reversed one (the board cannot tell), the full current through a stuck one.
- Reboot and clock faults: :class:`drivers.can_node.CanDevice` (heartbeat BOOT first; mode, coils off, sample
  counter and on-board counters back to power-up; coil faults are hardware and stay).
- MAG_SAMPLE every ``sample_period_s``, measured by :class:`drivers.magnetometer.sensor.MagnetometerModel`
  (the one magnetometer model of the stand): ``truth + bias + noise`` (+ ``coupling @ dipole`` and the
  ``coil_active`` flag while the coils are driven), quantised to ``mag_lsb_T``, saturated at the
  DBC's range (then ``valid`` = 0). Noise is drawn from the emulator's own Generator in blocks.
- MTQ_STATUS and MTQ_COUNTERS every ``status_period_s``, MTQ_HEARTBEAT every ``heartbeat_period_s``.
  Periodic messages are due at ``t0 + k * period`` (``t0`` = the first time seen); when a call
  comes late, one message is sent and the missed slots are counted in ``samples_skipped``.
- Frames are sorted by :class:`drivers.can_node.CanNode`: the board's range is its command block
  0x090..0x09F; frames of other nodes (a wheel on the same bus) are ignored, frames addressed to
  the board with an unknown id, a wrong length or an undecodable value are counted, never raised.

``counters`` (cumulative, for the stand's recorder): the node's (``sent``, ``received``,
``rejected_unknown_id``, ``rejected_length``, ``rejected_other``, ``foreign``, ``echoes``), then
``rejected_mode``, ``commands_accepted``, ``saturations``, ``watchdog_expiries``, ``mag_saturations``,
``samples_skipped``. The board counters carried by MTQ_COUNTERS are separate (they reset on
``reset_counters`` and wrap at their DBC width).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import can
import numpy as np

from drivers.can_node import EPS_S, CanDevice, check_positive
from drivers.device_faults import axis_indices
from drivers.magnetometer.sensor import FieldSource, MagnetometerModel
from drivers.magnetorquer.codec import (
    MODES,
    Counters,
    DipoleCommand,
    Heartbeat,
    MagnetorquerCodec,
    MagSample,
    ModeCommand,
    Status,
)

__all__ = ["EmulatorConfig", "MagnetorquerEmulator"]

@dataclass(frozen=True)
class EmulatorConfig:
    """Realism knobs of the emulated board; defaults are a plausible 3U CubeSat torquer board.

    Attributes:
        max_dipole_A_m2: rated dipole per axis; commands beyond it are clipped keeping the sign.
            0.2 A m^2 is the class of common CubeSat torquer rods.
        dipole_lsb_A_m2: step of the driven dipole: a 10-bit PWM magnitude plus a sign bit gives
            1023 steps up to the rating, 0.2 / 1023 = 196 uA m^2 (coarser than the DBC's 10 uA m^2).
        coil_area_turns_m2: effective N*A per axis (with the core gain of a rod), to report the coil
            current i = m / (N A): 2 m^2 gives 0.1 A at 0.2 A m^2.
        mag_noise_T: 1-sigma white noise per axis (50 nT: a MEMS/AMR magnetometer on the board).
        mag_bias_T: residual bias per axis after calibration (hard iron), sensor axes.
        mag_lsb_T: quantisation of the magnetometer; a multiple of the DBC's 5 nT.
        coil_coupling_T_per_A_m2: 3x3 matrix, rows = sensor axes, columns = coil axes: the field
            the driven coils add at the magnetometer. The defaults (~1e-4 T per A m^2 on the
            diagonal) are a dipole seen from ~12 cm: 24 uT at full dipole, which corrupts the
            sample without saturating the sensor.
        sample_period_s, status_period_s, heartbeat_period_s: publication periods (the DBC's
            GenMsgCycleTime: 100 ms, 1000 ms, 1000 ms). Status and counters share a period.
        temperature_C: board temperature reported in MTQ_STATUS.
        initial_mode: mode at boot: "DIPOLE" (coils off, ready for dipole commands).
        noise_block: how many 3-axis noise vectors to draw from the Generator at once.
    """

    max_dipole_A_m2: float = 0.2
    dipole_lsb_A_m2: float = 0.2 / 1023
    coil_area_turns_m2: tuple[float, float, float] = (2.0, 2.0, 2.0)
    mag_noise_T: float = 50e-9
    mag_bias_T: tuple[float, float, float] = (200e-9, -150e-9, 100e-9)
    mag_lsb_T: float = 5e-9
    coil_coupling_T_per_A_m2: tuple[tuple[float, float, float], ...] = (
        (1.2e-4, 1.0e-5, -5.0e-6),
        (8.0e-6, 0.9e-4, 1.2e-5),
        (-4.0e-6, 6.0e-6, 1.5e-4),
    )
    sample_period_s: float = 0.1
    status_period_s: float = 1.0
    heartbeat_period_s: float = 1.0
    temperature_C: float = 20.0
    initial_mode: str = "DIPOLE"
    noise_block: int = 4096

    def __post_init__(self) -> None:
        check_positive(self, ("max_dipole_A_m2", "dipole_lsb_A_m2", "mag_lsb_T", "sample_period_s", "status_period_s",
                              "heartbeat_period_s"))
        if not (math.isfinite(self.mag_noise_T) and self.mag_noise_T >= 0):
            raise ValueError(
                f"EmulatorConfig.mag_noise_T must be a finite number >= 0; got {self.mag_noise_T!r}."
            )
        if self.dipole_lsb_A_m2 > self.max_dipole_A_m2:
            raise ValueError(
                f"EmulatorConfig.dipole_lsb_A_m2 = {self.dipole_lsb_A_m2!r} must not exceed "
                f"max_dipole_A_m2 = {self.max_dipole_A_m2!r}."
            )
        shapes = {"coil_area_turns_m2": (3,), "mag_bias_T": (3,), "coil_coupling_T_per_A_m2": (3, 3)}
        for name, shape in shapes.items():
            value = getattr(self, name)
            arr = np.asarray(value, dtype=float)
            if arr.shape != shape or not np.all(np.isfinite(arr)):
                raise ValueError(
                    f"EmulatorConfig.{name} must be finite numbers of shape {shape}; got {value!r}."
                )
        if np.any(np.asarray(self.coil_area_turns_m2) <= 0):
            raise ValueError(
                "EmulatorConfig.coil_area_turns_m2 must be > 0 on every axis; "
                f"got {self.coil_area_turns_m2!r}."
            )
        if self.initial_mode not in MODES:
            raise ValueError(
                f"EmulatorConfig.initial_mode must be one of {', '.join(MODES)}; got {self.initial_mode!r}."
            )
        if not (isinstance(self.noise_block, int) and self.noise_block >= 1):
            raise ValueError(f"EmulatorConfig.noise_block must be an int >= 1; got {self.noise_block!r}.")


_ZERO3 = np.zeros(3)
_ZERO3.flags.writeable = False
_OFF = (0.0, 0.0, 0.0)

#: The board's command block: its two commands and the ids the ICD leaves free in it are addressed to the board.
COMMAND_BLOCK = frozenset(range(0x090, 0x0A0))



class MagnetorquerEmulator(CanDevice):
    """The magnetorquer board, emulated on ``bus`` (see the module docstring for the behaviour).

    Args:
        bus: an open :class:`can.BusABC` (closed by :meth:`close` only if ``owns_bus``).
        field_source: ``field_source(t_s) -> (3,)`` true field at the magnetometer, sensor axes, T.
        config: :class:`EmulatorConfig`.
        rng: a ``numpy.random.Generator`` or a seed.
        codec: a :class:`MagnetorquerCodec` (default: the ICD in ``fixtures/``).
    """

    def __init__(
        self,
        bus: can.BusABC,
        field_source: FieldSource,
        config: EmulatorConfig | None = None,
        rng: np.random.Generator | int = 0,
        codec: MagnetorquerCodec | None = None,
        *,
        owns_bus: bool = False,
    ) -> None:
        self.name = "mtq emulator"
        self.config = config = config if config is not None else EmulatorConfig()
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.codec = codec = codec if codec is not None else MagnetorquerCodec()

        if config.max_dipole_A_m2 > codec.dipole_range_A_m2[1]:
            raise ValueError(
                f"EmulatorConfig.max_dipole_A_m2 = {config.max_dipole_A_m2!r} exceeds what MTQ_DIPOLE_CMD "
                f"can carry ({codec.dipole_range_A_m2[1]!r} A m^2)."
            )

        # The board's magnetometer: the one sensor model every magnetometer of the stand measures through.
        self.magnetometer = MagnetometerModel(
            field_source, noise_T=config.mag_noise_T, bias_T=config.mag_bias_T, lsb_T=config.mag_lsb_T,
            wire_lsb_T=codec.mag_lsb_T, range_T=codec.mag_range_T, rng=self.rng, noise_block=config.noise_block,
            what="EmulatorConfig.mag_lsb_T")
        self._coupling = np.asarray(config.coil_coupling_T_per_A_m2, dtype=float)
        self._na_xyz = tuple(float(x) for x in config.coil_area_turns_m2)
        self._dipole_levels = math.floor(config.max_dipole_A_m2 / config.dipole_lsb_A_m2 + 1e-9)
        i_lo, i_hi = codec.dbc.signal_range("MTQ_STATUS", "current_x")
        self._i_max = min(-i_lo, i_hi) * 1e-3
        t_lo, t_hi = codec.dbc.signal_range("MTQ_STATUS", "temperature")
        self._temperature = min(max(config.temperature_C, t_lo), t_hi)

        self._init_node(bus, codec, accept=codec.board_rx_ids, own=codec.board_tx_ids, addressed=COMMAND_BLOCK,
                        extra_counters=("rejected_mode", "commands_accepted", "saturations", "watchdog_expiries",
                                        "mag_saturations", "samples_skipped"), owns_bus=owns_bus)
        # On-board counters (MTQ_COUNTERS): zeroed by reset_counters.
        self._board = {"rejected_frames": 0, "watchdog_expiries": 0, "saturations": 0, "commands_accepted": 0}
        self._mode_seq_ack = 0

        self.mode: str = config.initial_mode
        # The driven dipole (saturated, quantised) is kept as floats: the stand reads it every tick
        # (dipole_xyz_at). Its read-only array (dipole_at) and the field the coils add at the
        # magnetometer (coupling @ dipole) are computed when first asked for, as most commands are
        # never sampled while driven (the watchdog switches the coils off before the next sample).
        self._dipole_xyz = _OFF
        self._dipole_array: np.ndarray | None = _ZERO3
        self._coil_field: tuple[float, float, float] | None = _OFF
        self._driven = False  # a command with a duration is running
        self._on_until_s = -math.inf
        self._any_nonzero = False
        # Coil faults (module docstring). Without one the produced dipole is the driven one and nothing below is
        # looked at per tick: _idle_xyz is what the coils produce with no command (stuck coils only).
        self._coil_gain = (1.0, 1.0, 1.0)
        self._stuck_on_axes: tuple[int, ...] = ()
        self._stuck_sign = (1.0, 1.0, 1.0)
        self._coil_faulted = False
        self._commanded_xyz = _OFF  # what the board drives for the current command, before coil faults
        self._idle_xyz = _OFF
        self._idle_active = False

        self._t0: float | None = None
        self._k_sample = self._k_status = self._k_heartbeat = 0
        self._sample_seq = 0
        self._heartbeat_counter = 0

        self.last_sample: MagSample | None = None
        self._sample, self._sample_period_s = self.measure, config.sample_period_s  # for CanDevice.publish

    _heartbeat_type = Heartbeat

    # -- lifecycle ------------------------------------------------------------------------------

    def __repr__(self) -> str:
        return f"MagnetorquerEmulator(mode={self.mode!r}, counters={self.counters})"

    @property
    def field_source(self) -> FieldSource:
        """The true field at the magnetometer (sensor axes, T) as a function of time; settable."""
        return self.magnetometer.field_source

    @field_source.setter
    def field_source(self, source: FieldSource) -> None:
        self.magnetometer.field_source = source

    # -- actuator state (pure queries) ------------------------------------------------------------

    def dipole_at(self, t_s: float) -> np.ndarray:
        """The dipole the coils actually produce at ``t_s`` (A m^2, board axes), read-only (3,) array.

        Saturated per axis, quantised, zero in modes other than DIPOLE and once the command's
        duration has expired. Answers from the current command (no history is kept).
        """
        if self._driven and t_s < self._on_until_s:
            return self._driven_array()
        if self._idle_xyz is _OFF:
            return _ZERO3
        idle = np.array(self._idle_xyz)  # stuck coils with no command
        idle.flags.writeable = False
        return idle

    def dipole_xyz_at(self, t_s: float) -> tuple[float, float, float]:
        """:meth:`dipole_at` as a tuple of floats (no array: the stand's loop reads it every tick)."""
        if self._driven and t_s < self._on_until_s:
            return self._dipole_xyz
        return self._idle_xyz

    def coil_active(self, t_s: float) -> bool:
        """True when at least one coil produces a dipole at ``t_s``."""
        if self._driven and t_s < self._on_until_s:
            return self._any_nonzero
        return self._idle_active

    # -- coil faults (module docstring) -----------------------------------------------------------

    @property
    def coil_gain(self) -> tuple[float, float, float]:
        """Per axis, the dipole produced per dipole driven: 1 nominal, 0 coil open, -1 polarity reversed."""
        return self._coil_gain

    @coil_gain.setter
    def coil_gain(self, gain) -> None:
        try:
            g = tuple(float(x) for x in gain)
        except (TypeError, ValueError):
            g = ()
        if len(g) != 3 or not all(math.isfinite(x) and abs(x) <= 10.0 for x in g):
            raise ValueError(f"{self.name}: coil_gain = {gain!r} is not allowed; give 3 numbers from -10 to 10 "
                             "(1 nominal, 0 open, -1 reversed).")
        self._coil_gain = g  # type: ignore[assignment]
        self._refresh_coils()

    @property
    def stuck_on_axes(self) -> tuple[int, ...]:
        """The axes (0 x, 1 y, 2 z) whose coil holds the rated dipole with its last sign whatever is commanded."""
        return self._stuck_on_axes

    @stuck_on_axes.setter
    def stuck_on_axes(self, axes) -> None:
        stuck = axis_indices(f"{self.name}: stuck_on_axes", axes)
        # A coil sticks with the sign it was last driven with (kept for a coil already stuck).
        sign = list(self._stuck_sign)
        for a in stuck:
            if a not in self._stuck_on_axes:
                sign[a] = -1.0 if self._commanded_xyz[a] < 0.0 else 1.0
        self._stuck_sign = tuple(sign)  # type: ignore[assignment]
        self._stuck_on_axes = stuck
        self._refresh_coils()

    def _faulty(self, driven: tuple[float, float, float]) -> tuple[float, float, float]:
        """The dipole the coils produce when the board drives ``driven`` (coil faults applied)."""
        full = self._dipole_levels * self.config.dipole_lsb_A_m2
        g, stuck, sign = self._coil_gain, self._stuck_on_axes, self._stuck_sign
        return tuple(sign[a] * full if a in stuck else driven[a] * g[a] for a in range(3))  # type: ignore[return-value]

    def _refresh_coils(self) -> None:
        """Recompute what the coils produce after a coil fault changed (the current command and idle)."""
        self._coil_faulted = self._coil_gain != (1.0, 1.0, 1.0) or bool(self._stuck_on_axes)
        if self._coil_faulted:
            self._idle_xyz = self._faulty(_OFF)
            self._idle_active = any(self._idle_xyz)
        else:
            self._idle_xyz, self._idle_active = _OFF, False
        if self._driven:
            self._produce(self._commanded_xyz)

    def _produce(self, driven: tuple[float, float, float]) -> None:
        """The coils driven with ``driven`` (what the board's drivers put out) from now on."""
        self._commanded_xyz = driven
        if self._coil_faulted:
            driven = self._faulty(driven)
        self._dipole_xyz = driven
        self._dipole_array = self._coil_field = None  # built from driven when first asked for
        self._any_nonzero = any(driven)

    def _driver_dipole_xyz_at(self, t_s: float) -> tuple[float, float, float]:
        """The dipole the board's drivers put out at ``t_s``, as its current sensors see it: the produced dipole
        without coil faults; with one, nothing on an open coil, the driven current on a reversed one and the full
        current on a stuck one."""
        if not self._coil_faulted:
            return self.dipole_xyz_at(t_s)
        driven = self._commanded_xyz if self._driven and t_s < self._on_until_s else _OFF
        full = self._dipole_levels * self.config.dipole_lsb_A_m2
        g, stuck, sign = self._coil_gain, self._stuck_on_axes, self._stuck_sign
        return tuple(sign[a] * full if a in stuck else (0.0 if g[a] == 0.0 else driven[a])  # type: ignore[return-value]
                     for a in range(3))

    # -- service ----------------------------------------------------------------------------------

    def _coils_off(self) -> None:
        self._driven = False
        self._dipole_xyz = _OFF
        self._dipole_array = _ZERO3
        self._coil_field = _OFF
        self._any_nonzero = False

    def _driven_array(self) -> np.ndarray:
        """The current command's dipole as a read-only array, built once per command when first needed."""
        if self._dipole_array is None:
            dipole = np.array(self._dipole_xyz)
            dipole.flags.writeable = False
            self._dipole_array = dipole
        return self._dipole_array

    def _coil_field_now(self) -> tuple[float, float, float]:
        """``coupling @ dipole`` (T, sensor axes), computed once per command when first needed."""
        if self._coil_field is None:
            self._coil_field = tuple((self._coupling @ self._driven_array()).tolist())
        return self._coil_field

    def _coil_field_at(self, t_s: float) -> tuple[float, float, float]:
        """The field the producing coils add at the magnetometer at ``t_s`` (called only when they produce)."""
        if self._driven and t_s < self._on_until_s:
            return self._coil_field_now()
        return tuple((self._coupling @ np.array(self._idle_xyz)).tolist())  # stuck coils with no command

    def _watchdog(self, t_s: float) -> None:
        if self._driven and t_s >= self._on_until_s:
            self._coils_off()
            self.counters["watchdog_expiries"] += 1
            self._board["watchdog_expiries"] += 1

    def receive(self, t_s: float) -> int:
        """Drain the bus and apply every command at ``t_s``; returns the number of frames read."""
        if self._driven:
            self._watchdog(t_s)
        return self._drain(t_s)

    def _take(self, cmd: Any, t_s: float) -> None:
        if type(cmd) is DipoleCommand:
            self._apply_dipole(cmd, t_s)
        elif type(cmd) is ModeCommand:
            self._apply_mode(cmd)
        else:  # pragma: no cover - board_rx_ids only holds the two commands
            self._reject("rejected_other")

    def _accepted(self) -> None:
        self.counters["commands_accepted"] += 1
        self._board["commands_accepted"] += 1

    def _apply_dipole(self, cmd: DipoleCommand, t_s: float) -> None:
        if self.mode != "DIPOLE":
            self._reject("rejected_mode")
            return
        self._accepted()
        if cmd.duration_s <= 0.0:
            self._coils_off()
            return
        cfg = self.config
        lsb = cfg.dipole_lsb_A_m2
        levels = self._dipole_levels
        mx, my, mz = cmd.dipole_A_m2
        rating = cfg.max_dipole_A_m2
        if abs(mx) > rating or abs(my) > rating or abs(mz) > rating:
            self.counters["saturations"] += 1
            self._board["saturations"] += 1
        # PWM steps clipped to the rating's step count, written out per axis: a generator over
        # three components costs more than the arithmetic, and this runs once per command.
        self._produce((min(max(round(mx / lsb), -levels), levels) * lsb,
                       min(max(round(my / lsb), -levels), levels) * lsb,
                       min(max(round(mz / lsb), -levels), levels) * lsb))
        self._driven = True
        # The watchdog deadline gets the same tolerance as the publication schedule, so coils
        # commanded for exactly one period are off when the next period's sample is taken.
        self._on_until_s = t_s + cmd.duration_s - EPS_S

    def _reboot_device(self, t_up: float) -> None:
        # A cold power-up (drivers.device_faults): the configured mode, coils off, counters from 0. Coil faults
        # are the hardware's and stay.
        self.mode = self.config.initial_mode
        self._coils_off()
        self._on_until_s = -math.inf
        self._mode_seq_ack = 0
        self._sample_seq = 0
        for key in self._board:
            self._board[key] = 0

    def _apply_mode(self, cmd: ModeCommand) -> None:
        if cmd.mode != self.mode:
            self.mode = cmd.mode
            self._coils_off()
        self._mode_seq_ack = cmd.seq
        if cmd.reset_counters:
            for key in self._board:
                self._board[key] = 0
        else:
            self._accepted()

    # -- publish ----------------------------------------------------------------------------------

    def _status_messages(self, t_s: float) -> tuple[Status, Counters]:
        return self.status(t_s), self.board_counters()

    def measure(self, t_s: float) -> MagSample:
        """The MAG_SAMPLE the board measures at ``t_s`` (consumes noise; advances the sample counter)."""
        active = self.coil_active(t_s)
        b_T, valid = self.magnetometer.measure(t_s, self._coil_field_at(t_s) if active else None)
        if not valid:
            self.counters["mag_saturations"] += 1
        seq = self._sample_seq
        self._sample_seq = (seq + 1) & 0xFF
        return MagSample(b_T, active, valid, seq)

    def status(self, t_s: float) -> Status:
        """The MTQ_STATUS the board reports at ``t_s``."""
        # On the command's floats, not the (3,) array: this runs once a second in every emulated board.
        mx, my, mz = self._driver_dipole_xyz_at(t_s)
        nx, ny, nz = self._na_xyz
        i_max = self._i_max
        return Status(
            self.mode,
            (mx != 0.0, my != 0.0, mz != 0.0),
            (min(max(mx / nx, -i_max), i_max), min(max(my / ny, -i_max), i_max), min(max(mz / nz, -i_max), i_max)),
            self._temperature,
        )

    def board_counters(self) -> Counters:
        """The MTQ_COUNTERS the board reports (each wrapped at its DBC width)."""
        b = self._board
        return Counters(
            b["rejected_frames"] & 0xFFFF,
            b["watchdog_expiries"] & 0xFFFF,
            b["saturations"] & 0xFFFF,
            b["commands_accepted"] & 0xFF,
            self._mode_seq_ack,
        )
