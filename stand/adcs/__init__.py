"""ADCS controllers in the loop, and the plug-in API for flight-software engineers.

A controller sees the spacecraft only through host drivers, exactly as flight software sees its
devices: every measurement it reads and every command it sends crosses the device protocol (the
CAN codec on a bus). It never touches the truth model.

Plug-in API: a class named in the scenario (``[controller] kind = "plugin"``,
``module = "package.module:ClassName"``, ``options = {...}``) is built as
``ClassName(devices, period_s, **options)`` where ``devices`` maps scenario device names to host
drivers, and is called once per control period as ``update(t_s)``. ``close()`` is called at the
end if it exists. The reference B-dot below is written against the same API.
"""

from __future__ import annotations

import importlib

import numpy as np

from sim.rotations import dcm


class BDot:
    """B-dot detumbling: m = -k dB/dt, by finite difference of successive magnetometer samples.

    The derivative is taken in body axes (the sensor mount ``q_SB`` is known to the flight
    software, as on a real spacecraft). Each command is clipped per axis to ``max_dipole_A_m2``
    and keeps the coils on for ``duty_cycle`` of the control period; the board's watchdog turns
    them off when that expires. Samples flagged ``coil_active`` are skipped when
    ``skip_coil_active`` is set (the coils corrupt the magnetometer while they are driven).
    """

    def __init__(self, board, period_s: float, gain_A_m2_s_per_T: float, max_dipole_A_m2: float,
                 q_SB=(1.0, 0.0, 0.0, 0.0), skip_coil_active: bool = True, duty_cycle: float = 1.0):
        self.board = board
        self.period_s = period_s
        self.gain = gain_A_m2_s_per_T
        self.max_dipole = max_dipole_A_m2
        self.dcm_BS = dcm(np.asarray(q_SB, dtype=float)).T.tolist()
        self.skip_coil_active = skip_coil_active
        self.duration_s = period_s * duty_cycle
        self._prev = None  # (t_s, b_B)
        self.last_command = (0.0, 0.0, 0.0)
        self.samples_used = 0
        self.samples_skipped = 0

    def update(self, t_s: float) -> None:
        sample = self.board.take_sample()  # polls the bus
        if sample is None:
            return
        if self.skip_coil_active and sample.coil_active or not sample.valid:
            self.samples_skipped += 1
            self._prev = None
            return
        # Component by component on floats: this runs every control tick, and indexing or a
        # generator over three components costs more than the arithmetic.
        sx, sy, sz = sample.b_T
        (c00, c01, c02), (c10, c11, c12), (c20, c21, c22) = self.dcm_BS
        bx = c00 * sx + c01 * sy + c02 * sz
        by = c10 * sx + c11 * sy + c12 * sz
        bz = c20 * sx + c21 * sy + c22 * sz
        self.samples_used += 1
        prev, self._prev = self._prev, (t_s, (bx, by, bz))
        if prev is None or t_s <= prev[0]:
            return
        t_prev, (px, py, pz) = prev
        k = -self.gain / (t_s - t_prev)
        lim = self.max_dipole
        m = (max(-lim, min(lim, k * (bx - px))), max(-lim, min(lim, k * (by - py))),
             max(-lim, min(lim, k * (bz - pz))))
        self.board.command_dipole(m, self.duration_s)
        self.last_command = m


def load_plugin(spec: str):
    """Import ``package.module:ClassName``; raises ValueError naming what could not be found."""
    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise ValueError(f"controller.module = {spec!r} must look like 'package.module:ClassName'.")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ValueError(f"controller.module = {spec!r}: module {module_name!r} cannot be imported ({exc}).") from None
    try:
        return getattr(module, attr)
    except AttributeError:
        raise ValueError(f"controller.module = {spec!r}: {module_name!r} has no {attr!r}.") from None

