"""The magnetometer's measurement model, one implementation for every device that carries one.

A standalone magnetometer (:mod:`drivers.magnetometer.emulator`) and the magnetometer on the magnetorquer board
(:mod:`drivers.magnetorquer.emulator`) both measure through :class:`MagnetometerModel`: the true field at the
sensor (sensor axes, T) plus a fixed bias, white noise and, on the board, the field its own coils add, quantised to
the sensor's step and saturated at what its ICD can carry. No bus, no clock: the caller passes the time and sends
the result in its own message.

Noise is drawn from the caller's ``numpy.random.Generator`` in blocks of ``noise_block`` 3-vectors (one Generator
call per block), so a run consumes the random stream the same way whichever device carries the sensor.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

__all__ = ["FieldSource", "MagnetometerModel"]

#: ``field_source(t_s) -> (3,)``: the true flux density at the sensor, sensor axes, T.
FieldSource = Callable[[float], Sequence[float]]


class MagnetometerModel:
    """Bias, noise, quantisation and saturation of a 3-axis magnetometer.

    Args:
        field_source: ``field_source(t_s)`` the true field at the sensor, sensor axes, T.
        noise_T: 1-sigma white noise per axis, T.
        bias_T: bias per axis, sensor axes, T.
        lsb_T: quantisation step, T: a whole multiple of ``wire_lsb_T``.
        wire_lsb_T, range_T: one LSB and the (lo, hi) range of the sample message of the ICD, T.
        rng: the Generator the noise is drawn from.
        noise_block: how many 3-axis noise vectors to draw at once.
        what: how errors name the quantisation step (the caller's configuration field).

    ``saturations`` counts samples clipped at the range (reported not valid).
    """

    def __init__(self, field_source: FieldSource, *, noise_T: float, bias_T: Sequence[float], lsb_T: float,
                 wire_lsb_T: float, range_T: tuple[float, float], rng: np.random.Generator, noise_block: int,
                 what: str = "lsb_T") -> None:
        ratio = lsb_T / wire_lsb_T
        if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6:
            raise ValueError(f"{what} = {lsb_T!r} T must be a whole multiple of the DBC's sample LSB {wire_lsb_T!r} T.")
        self.field_source = field_source
        self.rng = rng
        self._noise_T = noise_T
        self._noise_block = noise_block
        self._bias_xyz = tuple(float(x) for x in bias_T)
        self._lsb = lsb_T
        # The sensor's range in LSB counts (the ICD's range, on this sensor's quantisation grid).
        lo, hi = range_T
        self._n_lo = math.ceil(lo / lsb_T - 1e-9)
        self._n_hi = math.floor(hi / lsb_T + 1e-9)
        self._noise: list[list[float]] = []  # the current block of pre-drawn noise, T
        self._noise_i = 0
        self.saturations = 0

    def measure(self, t_s: float, coil_field_T: tuple[float, float, float] | None = None
                ) -> tuple[tuple[float, float, float], bool]:
        """``(b_T, valid)`` measured at ``t_s`` (consumes one noise vector); ``coil_field_T`` is what nearby coils add
        at the sensor (sensor axes, T), None when they are off. ``valid`` is false when the sensor saturated."""
        truth = self.field_source(t_s)
        i = self._noise_i
        if i >= len(self._noise):  # draw the next block: one Generator call per noise_block samples
            block = self.rng.standard_normal((self._noise_block, 3)) * self._noise_T
            self._noise = block.tolist()
            i = 0
        self._noise_i = i + 1
        nx, ny, nz = self._noise[i]
        bias_x, bias_y, bias_z = self._bias_xyz
        lsb = self._lsb
        n_lo, n_hi = self._n_lo, self._n_hi
        try:
            tx, ty, tz = truth
            bx, by, bz = float(tx) + bias_x + nx, float(ty) + bias_y + ny, float(tz) + bias_z + nz
            if coil_field_T is not None:
                cx, cy, cz = coil_field_T
                bx, by, bz = bx + cx, by + cy, bz + cz
            # Counts of the quantiser, written out per axis (this runs once per sample).
            kx, ky, kz = round(bx / lsb), round(by / lsb), round(bz / lsb)
        except (ValueError, TypeError, OverflowError):  # wrong length, not numbers, NaN, infinity
            raise ValueError(
                f"field_source({t_s!r}) must return 3 finite floats (T, sensor axes); got {truth!r}."
            ) from None
        valid = n_lo <= kx <= n_hi and n_lo <= ky <= n_hi and n_lo <= kz <= n_hi
        if not valid:  # the sensor saturates at the ICD's range
            kx, ky, kz = (min(max(k, n_lo), n_hi) for k in (kx, ky, kz))
            self.saturations += 1
        return (kx * lsb, ky * lsb, kz * lsb), valid
