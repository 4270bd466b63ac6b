"""Emulator: the stand *being* one reaction wheel, on any python-can bus.

The emulator speaks the ICD (``fixtures/devices/reaction_wheel.dbc``) for wheel ``n`` through the
same codec as the host driver. It knows no physics: it holds what was commanded, which the stand
reads with :meth:`ReactionWheelEmulator.command_at` and turns into motor torque and speed with
its wheel model (:class:`sim.actuators.WheelMotor`), and it reports the speed the stand hands it
through ``speed_source(t_s)``.

Behaviour (times are sim seconds passed in by the caller; the emulator never reads a clock):

- RW_TORQUE_CMD puts the wheel in mode TORQUE holding the torque, clipped to ``max_torque_Nm``
  keeping its sign (``torque_limited`` and one ``saturations`` count); RW_SPEED_CMD puts it in mode
  SPEED holding the speed, clipped to ``max_speed_rad_s``. RW_MODE_CMD sets the mode with a zero
  command (IDLE: motor off). A command with a timeout is dropped that long after it: the wheel
  goes IDLE (motor off, it coasts), with one ``watchdog_expiries`` count. The wheel boots in
  ``initial_mode`` with a zero command.
- RW_SPEED_TLM every ``telemetry_period_s``: the speed from ``speed_source(t)`` (a float, rad/s,
  or a ``(speed_rad_s, motor_torque_Nm)`` pair; with a float the held torque command is reported as
  the motor torque in TORQUE mode, 0 otherwise), quantised by the wire; ``speed_limited`` at or
  beyond ``max_speed_rad_s``; a speed the field cannot carry is clipped with ``valid`` = 0. With the fault
  attribute ``speed_sensor_failed`` set (a dead tachometer) the speed is 0 with ``valid`` = 0.
- RW_STATUS every ``status_period_s``, RW_HEARTBEAT every ``heartbeat_period_s``, on the grid
  ``t0 + k * period`` (``t0`` = the first service time); a late call sends one message and counts the
  missed telemetry slots in ``samples_skipped``.
- Frames are sorted by :class:`drivers.can_node.CanNode`: frames of other nodes on a shared bus
  (the other wheels, a magnetorquer) are counted in ``foreign`` and ignored; this wheel's commands
  of a wrong length or with an undecodable value are counted, never raised.

``counters``: the node's (``sent``, ``received``, ``rejected_unknown_id``, ``rejected_length``,
``rejected_other``, ``foreign``, ``echoes``), then ``commands_accepted``, ``saturations``,
``watchdog_expiries``, ``samples_skipped``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import can

from drivers.can_node import CanDevice, check_positive
from drivers.reaction_wheel.codec import (
    MODES,
    Heartbeat,
    ModeCommand,
    ReactionWheelCodec,
    SpeedCommand,
    Status,
    TorqueCommand,
    WheelSpeed,
)

__all__ = ["ReactionWheelEmulator", "SpeedSource", "WheelCommand", "WheelEmulatorConfig"]

SpeedSource = Callable[[float], Any]
#: math.isfinite by a module name: on Python 3.11 a builtin call on a float costs less than chained comparisons with
#: ``-math.inf``, which make a new float each time (docs/fast_paths.md, eighth pass).
_isfinite = math.isfinite



class WheelCommand(NamedTuple):
    """What the wheel holds: ``mode`` (IDLE, TORQUE, SPEED), ``torque_Nm`` (TORQUE mode, clipped),
    ``speed_rad_s`` (SPEED mode, clipped); the other value is 0."""

    mode: str
    torque_Nm: float
    speed_rad_s: float


#: A :class:`WheelCommand` of (mode, torque, speed) without the Python-level ``__new__`` namedtuple generates (the
#: stand reads the command once a tick per wheel).
_command = functools.partial(tuple.__new__, WheelCommand)
#: What a wheel holds after a command's timeout: motor off.
_IDLE = WheelCommand("IDLE", 0.0, 0.0)


@dataclass(frozen=True)
class WheelEmulatorConfig:
    """Knobs of the emulated wheel; defaults are a small CubeSat wheel.

    Attributes:
        max_torque_Nm: rated motor torque (4 mN m, the class of the RW-0.003 wheel).
        max_speed_rad_s: rated speed (628 rad/s = 6000 rpm).
        telemetry_period_s, status_period_s, heartbeat_period_s: publication periods (the DBC's
            GenMsgCycleTime: 100 ms, 1000 ms, 1000 ms).
        temperature_C: reported in RW_STATUS.
        initial_mode: mode at boot ("TORQUE", with a zero command).
    """

    max_torque_Nm: float = 4e-3
    max_speed_rad_s: float = 6000.0 * math.pi / 30.0
    telemetry_period_s: float = 0.1
    status_period_s: float = 1.0
    heartbeat_period_s: float = 1.0
    temperature_C: float = 20.0
    initial_mode: str = "TORQUE"

    def __post_init__(self) -> None:
        check_positive(self, ("max_torque_Nm", "max_speed_rad_s", "telemetry_period_s", "status_period_s",
                              "heartbeat_period_s"))
        if self.initial_mode not in MODES:
            raise ValueError(f"WheelEmulatorConfig.initial_mode must be one of {', '.join(MODES)}; "
                             f"got {self.initial_mode!r}.")


class ReactionWheelEmulator(CanDevice):
    """Wheel ``wheel`` (0..15), emulated on ``bus`` (see the module docstring for the behaviour).

    Args:
        bus: an open :class:`can.BusABC` (shut down by :meth:`close` only if ``owns_bus``).
        speed_source: ``speed_source(t_s) -> speed_rad_s`` or ``(speed_rad_s, motor_torque_Nm)``.
        config: :class:`WheelEmulatorConfig`.
        codec: a :class:`ReactionWheelCodec` (default: the ICD in ``fixtures/`` for ``wheel``).
        wheel: the wheel number (node 0x20 + wheel); must match the codec's when both are given.
    """

    def __init__(
        self,
        bus: can.BusABC,
        speed_source: SpeedSource,
        config: WheelEmulatorConfig | None = None,
        codec: ReactionWheelCodec | None = None,
        *,
        wheel: int = 0,
        owns_bus: bool = False,
        name: str | None = None,
    ) -> None:
        self.config = cfg = config if config is not None else WheelEmulatorConfig()
        self.codec = codec = codec if codec is not None else ReactionWheelCodec(wheel)
        if codec.wheel != wheel:
            raise ValueError(f"reaction wheel emulator: wheel = {wheel} but the codec is for wheel {codec.wheel}.")
        if cfg.max_torque_Nm > codec.torque_range_Nm[1] or cfg.max_speed_rad_s > codec.speed_range_rad_s[1]:
            raise ValueError(
                f"WheelEmulatorConfig max_torque_Nm = {cfg.max_torque_Nm!r} / max_speed_rad_s = "
                f"{cfg.max_speed_rad_s!r} exceed what the commands carry ({codec.torque_range_Nm[1]!r} N m, "
                f"{codec.speed_range_rad_s[1]!r} rad/s)."
            )
        self.source = speed_source
        self.name = name or f"rw{wheel} emulator"
        self._init_node(bus, codec, accept=codec.wheel_rx_ids, own=codec.wheel_tx_ids,
                        extra_counters=("commands_accepted", "saturations", "watchdog_expiries", "samples_skipped"),
                        owns_bus=owns_bus)
        self._board = {"rejected_frames": 0, "commands_accepted": 0, "watchdog_expiries": 0, "saturations": 0}
        self.mode = cfg.initial_mode
        self._torque = 0.0
        self._speed = 0.0
        self._torque_limited = False
        self._expires_s = math.inf
        self._seq_ack = 0
        self._t0: float | None = None
        self._k_sample = self._k_status = self._k_heartbeat = 0
        self._sample, self._sample_period_s = self.telemetry, cfg.telemetry_period_s  # for CanDevice.publish
        #: The newest RW_SPEED_TLM sent.
        self.last_sample: WheelSpeed | None = None
        self._tlm_seq = 0
        self._heartbeat_counter = 0
        t_lo, t_hi = codec.dbc.signal_range("RW_STATUS", "temperature")
        self._temperature = min(max(cfg.temperature_C, t_lo), t_hi)
        # Each bound with its negative, worked out once (a -x in the telemetry would make a new float every sample).
        self._tlm_speed_max = codec.tlm_speed_range_rad_s[1]
        self._tlm_speed_min = -self._tlm_speed_max
        self._tlm_torque_max = codec.tlm_torque_range_Nm[1]
        self._tlm_torque_min = -self._tlm_torque_max
        #: At or beyond this speed (either sign) RW_SPEED_TLM says ``speed_limited`` (the configuration is frozen).
        self._speed_limit = cfg.max_speed_rad_s - 1e-9
        self._speed_limit_neg = -self._speed_limit
        self._torque_cmd_min = -cfg.max_torque_Nm
        #: Fault (issue 24): the tachometer is dead: RW_SPEED_TLM carries speed 0 with ``valid`` = 0 (the motor
        #: torque it reports still comes from the drive).
        self.speed_sensor_failed = False

    _heartbeat_type = Heartbeat

    def __repr__(self) -> str:
        return f"ReactionWheelEmulator(wheel={self.codec.wheel}, mode={self.mode!r}, counters={self.counters})"

    # -- what the stand reads ---------------------------------------------------------------------

    def command_at(self, t_s: float) -> WheelCommand:
        """The command the wheel holds at ``t_s`` (after a command's timeout: IDLE, motor off)."""
        if t_s >= self._expires_s:
            return _IDLE
        return _command((self.mode, self._torque, self._speed))

    def torque_command_Nm(self, t_s: float) -> float:
        """The held motor torque at ``t_s`` in mode TORQUE, else 0."""
        return self.command_at(t_s).torque_Nm

    # -- service ----------------------------------------------------------------------------------

    def receive(self, t_s: float) -> int:
        """Drain the bus and apply every command at ``t_s``; returns the number of frames read."""
        if t_s >= self._expires_s:  # a command's timeout ran out (most ticks: none is running, or not yet)
            self._watchdog(t_s)
        return self._drain(t_s)

    def _watchdog(self, t_s: float) -> None:
        if t_s >= self._expires_s:
            self.mode, self._torque, self._speed = "IDLE", 0.0, 0.0
            self._expires_s = math.inf
            self.counters["watchdog_expiries"] += 1
            self._board["watchdog_expiries"] += 1

    def _take(self, cmd: Any, t_s: float) -> None:
        cfg = self.config
        if isinstance(cmd, TorqueCommand):
            u = cmd.torque_Nm
            top = cfg.max_torque_Nm
            self._torque_limited = u > top or u < self._torque_cmd_min  # abs(u) > top, without the call or a -top
            if self._torque_limited:
                u = math.copysign(cfg.max_torque_Nm, u)
                self._saturated()
            self.mode, self._torque, self._speed = "TORQUE", u, 0.0
            self._expires_s = t_s + cmd.timeout_s if cmd.timeout_s > 0 else math.inf
        elif isinstance(cmd, SpeedCommand):
            w = cmd.speed_rad_s
            if abs(w) > cfg.max_speed_rad_s:
                w = math.copysign(cfg.max_speed_rad_s, w)
                self._saturated()
            self._torque_limited = False
            self.mode, self._torque, self._speed = "SPEED", 0.0, w
            self._expires_s = t_s + cmd.timeout_s if cmd.timeout_s > 0 else math.inf
        elif isinstance(cmd, ModeCommand):
            self.mode, self._torque, self._speed = cmd.mode, 0.0, 0.0
            self._torque_limited = False
            self._expires_s = math.inf
            if cmd.reset_counters:
                for k in self._board:
                    self._board[k] = 0
        else:  # pragma: no cover - wheel_rx_ids only holds the three commands
            return
        self._seq_ack = cmd.seq
        self.counters["commands_accepted"] += 1
        self._board["commands_accepted"] += 1

    def _saturated(self) -> None:
        self.counters["saturations"] += 1
        self._board["saturations"] += 1

    def _reboot_device(self, t_up: float) -> None:
        # A cold power-up (drivers.device_faults): the configured mode, no command held, counters from 0.
        self.mode, self._torque, self._speed = self.config.initial_mode, 0.0, 0.0
        self._torque_limited = False
        self._expires_s = math.inf
        self._seq_ack = self._tlm_seq = 0
        for k in self._board:
            self._board[k] = 0

    def _status_messages(self, t_s: float) -> tuple[Status]:
        return (self.status(),)

    # -- messages ---------------------------------------------------------------------------------

    def telemetry(self, t_s: float) -> WheelSpeed:
        """The RW_SPEED_TLM the wheel reports at ``t_s`` (advances the sample counter)."""
        got = self.source(t_s)
        try:
            # A number or a 0-d array is a speed; anything else a pair (the stand's source: a tuple, asked first).
            if not isinstance(got, tuple) and (isinstance(got, (int, float)) or getattr(got, "shape", None) == ()):
                speed, torque = float(got), self.command_at(t_s).torque_Nm
            else:
                s, tq = got
                speed, torque = float(s), float(tq)
            if not (_isfinite(speed) and _isfinite(torque)):
                raise ValueError
        except (TypeError, ValueError):
            raise ValueError(f"speed_source({t_s!r}) must return a finite speed (rad/s) or a pair (speed rad/s, "
                             f"motor torque N m); got {got!r}.") from None
        # The clips below are comparisons on finite floats: the same results as abs(), min() and max() (a -0.0
        # stays -0.0), without a builtin call each (the wheels send every tick).
        top = self._tlm_speed_max
        valid = self._tlm_speed_min <= speed <= top
        if not valid:
            speed = math.copysign(top, speed)
        if self.speed_sensor_failed:
            speed, valid = 0.0, False
        if torque > self._tlm_torque_max:
            torque = self._tlm_torque_max
        elif torque < self._tlm_torque_min:
            torque = self._tlm_torque_min
        seq = self._tlm_seq
        self._tlm_seq = (seq + 1) & 0xFF
        return WheelSpeed(speed, torque, valid, speed >= self._speed_limit or speed <= self._speed_limit_neg,
                          self._torque_limited, seq)

    def status(self) -> Status:
        """The RW_STATUS the wheel reports (counters wrapped at their DBC width)."""
        b = self._board
        return Status(self.mode, b["rejected_frames"] & 0xFFFF, b["commands_accepted"] & 0xFF, self._seq_ack,
                      b["watchdog_expiries"] & 0xFF, b["saturations"] & 0xFF, self._temperature)
