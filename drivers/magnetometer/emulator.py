"""Emulator: the stand *being* the standalone magnetometer, on any python-can bus.

It speaks the ICD ``fixtures/devices/magnetometer.dbc`` through the same codec as the host driver and measures
through :class:`drivers.magnetometer.sensor.MagnetometerModel`, the one magnetometer model of the stand (the
magnetorquer board's magnetometer measures through it too). It knows no physics: the stand hands it
``field_source(t_s)``, the true flux density at the sensor in sensor axes (T). It is far from any coil, so no
coil field reaches it.

Behaviour (times are sim seconds passed in by the caller; the emulator never reads a clock):

- MAG_FIELD every ``sample_period_s`` in mode MEASURE (the mode it boots in): ``truth + bias + noise``, quantised
  to ``lsb_T``, saturated at the DBC's range (then ``valid`` = 0). In mode OFF no sample is sent and no noise drawn.
- MAG_STATUS every ``status_period_s``, MAG_HEARTBEAT every ``heartbeat_period_s``.
- MAG_MODE_CMD sets the mode and echoes its ``seq``; ``reset_counters`` zeroes the on-board counters.
- Reboot and clock faults: :class:`drivers.can_node.CanDevice` (heartbeat BOOT first; mode, sample counter and
  on-board counters back to power-up).
- Frames are sorted by :class:`drivers.can_node.CanNode`: the unit's range is its command block 0x0E0..0x0E7;
  other nodes' frames are ignored, frames addressed to it that it cannot accept are counted, never raised.

``counters``: the node's, then ``commands_accepted``, ``mag_saturations``, ``samples_skipped``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import can
import numpy as np

from drivers.can_node import CanDevice, check_positive
from drivers.magnetometer.codec import MODES, Heartbeat, MagnetometerCodec, MagSample, ModeCommand, Status
from drivers.magnetometer.sensor import FieldSource, MagnetometerModel

__all__ = ["COMMAND_BLOCK", "MagnetometerConfig", "MagnetometerEmulator"]

#: The unit's command block: its command and the ids the ICD leaves free in it are addressed to it.
COMMAND_BLOCK = frozenset(range(0x0E0, 0x0E8))



@dataclass(frozen=True)
class MagnetometerConfig:
    """Realism knobs of the emulated unit; defaults are a plausible CubeSat fluxgate/AMR magnetometer.

    Attributes:
        noise_T: 1-sigma white noise per axis (10 nT).
        bias_T: residual bias per axis after calibration, sensor axes, T.
        lsb_T: quantisation step; a whole multiple of the DBC's 1 nT.
        sample_period_s, status_period_s, heartbeat_period_s: publication periods (the DBC's GenMsgCycleTime).
        initial_mode: mode at boot.
        noise_block: how many 3-axis noise vectors to draw from the Generator at once.
    """

    noise_T: float = 10e-9
    bias_T: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lsb_T: float = 1e-9
    sample_period_s: float = 0.1
    status_period_s: float = 1.0
    heartbeat_period_s: float = 1.0
    initial_mode: str = "MEASURE"
    noise_block: int = 4096

    def __post_init__(self) -> None:
        check_positive(self, ("lsb_T", "sample_period_s", "status_period_s", "heartbeat_period_s"))
        if not (isinstance(self.noise_T, (int, float)) and math.isfinite(self.noise_T) and self.noise_T >= 0):
            raise ValueError(f"MagnetometerConfig.noise_T must be a finite number >= 0; got {self.noise_T!r}.")
        bias = np.asarray(self.bias_T, dtype=float)
        if bias.shape != (3,) or not np.all(np.isfinite(bias)):
            raise ValueError(f"MagnetometerConfig.bias_T must be 3 finite numbers; got {self.bias_T!r}.")
        if self.initial_mode not in MODES:
            raise ValueError(f"MagnetometerConfig.initial_mode must be one of {', '.join(MODES)}; got "
                             f"{self.initial_mode!r}.")
        if not (isinstance(self.noise_block, int) and self.noise_block >= 1):
            raise ValueError(f"MagnetometerConfig.noise_block must be an int >= 1; got {self.noise_block!r}.")


class MagnetometerEmulator(CanDevice):
    """The standalone magnetometer, emulated on the open python-can ``bus`` (see the module docstring; ``bus`` is
    closed by :meth:`close` only if ``owns_bus``). It measures ``field_source(t_s) -> (3,)``, the true field at the
    sensor in sensor axes (T), as ``config`` (:class:`MagnetometerConfig`) says, with the noise of ``rng`` (a
    ``numpy.random.Generator`` or a seed), and speaks the ICD of ``codec`` (default: the one in ``fixtures/``)."""

    _heartbeat_type = Heartbeat
    _sampling_modes = frozenset({"MEASURE"})  # MAG_FIELD is sent in mode MEASURE only

    def __init__(self, bus: can.BusABC, field_source: FieldSource, config: MagnetometerConfig | None = None,
                 rng: np.random.Generator | int = 0, codec: MagnetometerCodec | None = None, *,
                 owns_bus: bool = False) -> None:
        self.name = "magnetometer emulator"
        self.config = config = config if config is not None else MagnetometerConfig()
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.codec = codec = codec if codec is not None else MagnetometerCodec()
        self.sensor = MagnetometerModel(field_source, noise_T=config.noise_T, bias_T=config.bias_T,
                                        lsb_T=config.lsb_T, wire_lsb_T=codec.mag_lsb_T, range_T=codec.mag_range_T,
                                        rng=self.rng, noise_block=config.noise_block,
                                        what="MagnetometerConfig.lsb_T")
        self._init_node(bus, codec, accept=codec.unit_rx_ids, own=codec.unit_tx_ids, addressed=COMMAND_BLOCK,
                        extra_counters=("commands_accepted", "mag_saturations", "samples_skipped"),
                        owns_bus=owns_bus)
        #: On-board counters (MAG_STATUS): zeroed by reset_counters.
        self._board = {"rejected_frames": 0, "saturations": 0, "commands_accepted": 0}
        self._mode_seq_ack = 0
        self.mode: str = config.initial_mode
        self._t0: float | None = None
        self._k_sample = self._k_status = self._k_heartbeat = 0
        self._sample_seq = 0
        self._heartbeat_counter = 0
        #: The newest sample sent, for a stand that serves this unit.
        self.last_sample: MagSample | None = None
        self._sample, self._sample_period_s = self.measure, config.sample_period_s  # for CanDevice.publish

    def __repr__(self) -> str:
        return f"MagnetometerEmulator(mode={self.mode!r}, counters={self.counters})"

    def receive(self, t_s: float) -> int:
        """Drain the bus and apply every command at ``t_s``; returns the number of frames read."""
        return self._drain(t_s)

    def _reboot_device(self, t_up: float) -> None:
        # A cold power-up (drivers.device_faults): the configured mode, sample counter and on-board counters from 0.
        self.mode = self.config.initial_mode
        self._mode_seq_ack = 0
        self._sample_seq = 0
        for key in self._board:
            self._board[key] = 0

    def _take(self, cmd: Any, t_s: float | None) -> None:
        if type(cmd) is not ModeCommand:  # pragma: no cover - unit_rx_ids only holds the mode command
            self._reject("rejected_other")
            return
        self.mode = cmd.mode
        self._mode_seq_ack = cmd.seq
        if cmd.reset_counters:
            for key in self._board:
                self._board[key] = 0
        else:
            self.counters["commands_accepted"] += 1
            self._board["commands_accepted"] += 1

    def measure(self, t_s: float) -> MagSample:
        """The MAG_FIELD sample the unit measures at ``t_s`` (consumes noise; advances the sample counter)."""
        b_T, valid = self.sensor.measure(t_s)
        if not valid:
            self.counters["mag_saturations"] += 1
            self._board["saturations"] += 1
        seq = self._sample_seq
        self._sample_seq = (seq + 1) & 0xFF
        return MagSample(b_T, False, valid, seq)

    def _status_messages(self, t_s: float) -> tuple[Status]:
        b = self._board
        return (Status(self.mode, b["rejected_frames"] & 0xFFFF, b["saturations"] & 0xFFFF,
                       b["commands_accepted"] & 0xFF, self._mode_seq_ack),)
