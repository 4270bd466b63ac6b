"""What the receiver measures, from the stand's truth: the spacecraft's position and velocity in frame N with
white Gaussian noise (one sigma per axis, from the scenario), and GPS time.

GPS time runs with TAI, 19 s behind it, from 1980-01-06T00:00:00 UTC (when UTC was TAI - 19 s): so the GPS
seconds of an instant are the SI seconds since that epoch, and the stand's epoch arithmetic (TAI based) gives
them with leap seconds honoured.
"""

from __future__ import annotations

from sim.time import Epoch
from stand_gnss.emulator import Measured

__all__ = ["GPS_EPOCH", "fix_source", "gps_seconds"]

GPS_EPOCH = "1980-01-06T00:00:00Z"


def gps_seconds(epoch: Epoch) -> float:
    """GPS seconds (since 1980-01-06T00:00:00 GPS) of ``epoch``."""
    return epoch - Epoch.from_iso(GPS_EPOCH)


def fix_source(truth, epoch: Epoch, rng, position_noise_m: float, velocity_noise_m_s: float, satellites: int):
    """``source(t_s) -> Measured`` for the emulator: the truth's state now (the emulator asks at the tick it
    publishes, before the truth steps), noise drawn from the device's own seeded stream ``rng``."""
    gps0 = gps_seconds(epoch)

    def source(t_s: float) -> Measured:
        r = truth.r_N
        v = truth.v_N
        if position_noise_m > 0.0 or velocity_noise_m_s > 0.0:
            n = rng.standard_normal(6)
            r = [r[i] + position_noise_m * n[i] for i in range(3)]
            v = [v[i] + velocity_noise_m_s * n[3 + i] for i in range(3)]
        return Measured(tuple(r), tuple(v), gps0 + t_s, satellites)

    return source
