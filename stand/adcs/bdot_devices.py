"""The reference B-dot as a plug-in over the devices (``[controller] kind = "plugin"``,
``module = "stand.adcs.bdot_devices:DeviceBDot"``): it commands the magnetorquer board ``magnetorquer`` and reads
the field from ``magnetometer``, a standalone magnetometer, or from the board's own magnetometer when that option
is left out. Both answer ``take_sample()`` with the same sample type (``b_T``, ``valid``, ``coil_active``), so the
law is :class:`stand.adcs.BDot`'s, unchanged.
"""

from __future__ import annotations

from stand.adcs import BDot


class DeviceBDot(BDot):
    """``DeviceBDot(devices, period_s, magnetorquer=NAME, gain_A_m2_s_per_T=..., max_dipole_A_m2=...,
    magnetometer=NAME or None, q_SB=[w, x, y, z] of the magnetometer read, skip_coil_active, duty_cycle)``."""

    def __init__(self, devices: dict, period_s: float, magnetorquer: str, gain_A_m2_s_per_T: float,
                 max_dipole_A_m2: float, magnetometer: str | None = None, q_SB=(1.0, 0.0, 0.0, 0.0),
                 skip_coil_active: bool = True, duty_cycle: float = 1.0):
        for key, name in (("magnetorquer", magnetorquer), ("magnetometer", magnetometer)):
            if name is not None and name not in devices:
                raise ValueError(f"options.{key} = {name!r} is not a device of the scenario; give one of "
                                 f"{', '.join(sorted(devices))}")
        super().__init__(devices[magnetorquer], period_s, gain_A_m2_s_per_T, max_dipole_A_m2, q_SB=q_SB,
                         skip_coil_active=skip_coil_active, duty_cycle=duty_cycle)
        #: Where the field is read: the standalone magnetometer, or the board itself.
        self.sensor = devices[magnetometer] if magnetometer is not None else self.board

    def update(self, t_s: float) -> None:
        sample = self.sensor.take_sample()  # polls its bus
        if sample is not None:
            self.command_for(sample, t_s)
