"""How the star-tracker emulator measures: what it is given (the truth at an exposure, :class:`TrackerTruth`,
from the stand's measurement source), its realism knobs (:class:`EmulatorConfig`, checked when made), the
attitude noise (a small rotation composed onto the truth) and the exclusion test of a bright body, whose float math
is :mod:`drivers.star_tracker.exposure_math` (compiled where the install could)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

import compiled_paths
from quat_floats import hamilton

__all__ = ["ARCSEC", "DEG", "EmulatorConfig", "MeasurementSource", "TrackerTruth", "checked_truth", "hamilton",
           "in_field", "small_rotation"]

ARCSEC = math.pi / 180.0 / 3600.0
DEG = math.pi / 180.0


@dataclass(frozen=True, slots=True)  # slotted: the stand makes one per exposure (drivers.frozen_build)
class TrackerTruth:
    """What the stand knows at one instant, in tracker axes (T: +z boresight).

    Attributes:
        q_TN: true attitude of T relative to GCRS, scalar first (normalised here).
        omega_TN_T: angular rate of T relative to GCRS, in T, rad/s.
        sun_T, moon_T, earth_T: direction to the body's centre in T (any length), or None when the
            stand left the body out (it then never counts as in the field).
        sun_radius_rad, moon_radius_rad, earth_radius_rad: angular radius of each disk (the Earth's
            with its atmosphere), rad.
        stars_in_field: stars bright enough to be centroided, if the stand knows it (else drawn).
        stars_matched, sigma_cross_rad, sigma_roll_rad: set by a source that measured the attitude
            itself (the stand's image-based solver): then the emulator reports these instead of
            drawing matches and quoting its configured noise.
    """

    q_TN: Sequence[float]
    omega_TN_T: Sequence[float] = (0.0, 0.0, 0.0)
    sun_T: Sequence[float] | None = None
    moon_T: Sequence[float] | None = None
    earth_T: Sequence[float] | None = None
    sun_radius_rad: float = 4.65e-3
    moon_radius_rad: float = 4.5e-3
    earth_radius_rad: float = 1.15
    stars_in_field: int | None = None
    stars_matched: int | None = None
    sigma_cross_rad: float | None = None
    sigma_roll_rad: float | None = None


MeasurementSource = Callable[[float], TrackerTruth]

#: ICD parameter attr -> (EmulatorConfig attribute, factor from the config unit to SI).
PARAM_FROM_CONFIG = {
    "output_interval_s": ("output_interval_s", 1.0),
    "min_stars_matched": ("min_stars_matched", 1.0),
    "stable_count": ("stable_count", 1.0),
    "rate_limit_rad_s": ("rate_limit_deg_s", DEG),
    "sun_exclusion_rad": ("sun_exclusion_deg", DEG),
    "moon_exclusion_rad": ("moon_exclusion_deg", DEG),
    "earth_exclusion_rad": ("earth_exclusion_deg", DEG),
    "track_loss_count": ("track_loss_count", 1.0),
}


@dataclass(frozen=True)
class EmulatorConfig:
    """Realism knobs; defaults are the S2E HILS settings of an Arcsec Sagitta (notes 1.1).

    Attributes:
        noise_cross_arcsec, noise_roll_arcsec: 1-sigma attitude noise across and about the
            boresight (2 and 10 arcsec).
        bias_arcsec: constant misalignment as a rotation vector in tracker axes, arcsec.
        output_delay_s: from mid-exposure to the solution being available (0.1 s).
        output_interval_s: time between exposures (0.2 s = 5 Hz); ICD parameter output_interval.
        clock_offset_s, clock_drift_ppm: the device clock before SET_TIME is
            ``clock_offset_s + t * (1 + drift)``; the drift also applies after SET_TIME.
        sun_exclusion_deg, moon_exclusion_deg, earth_exclusion_deg: exclusion half-angles (40, 40, 30).
        rate_limit_deg_s: above it the solution is invalid (1 deg/s).
        boot_time_s: from BOOT to LOST_IN_SPACE (1 s); auto_boot: boot at power-up.
        min_stars_matched, stable_count, track_loss_count: see the module docstring (6, 5, 3).
        mean_stars: mean stars in the field when the truth does not say (12); match_probability (0.95).
        temperature_C: reported detector temperature.
        address: device address (the ICD's default, 0x21, when None).
        reported_sigma: report the configured sigmas as the solution's sigmas (else 0).
    """

    noise_cross_arcsec: float = 2.0
    noise_roll_arcsec: float = 10.0
    bias_arcsec: tuple[float, float, float] = (0.0, 0.0, 0.0)
    output_delay_s: float = 0.1
    output_interval_s: float = 0.2
    clock_offset_s: float = 0.0
    clock_drift_ppm: float = 0.0
    sun_exclusion_deg: float = 40.0
    moon_exclusion_deg: float = 40.0
    earth_exclusion_deg: float = 30.0
    rate_limit_deg_s: float = 1.0
    boot_time_s: float = 1.0
    auto_boot: bool = True
    min_stars_matched: int = 6
    stable_count: int = 5
    track_loss_count: int = 3
    mean_stars: float = 12.0
    match_probability: float = 0.95
    temperature_C: float = 20.0
    address: int | None = None
    reported_sigma: bool = True

    def __post_init__(self) -> None:
        nonneg = ("noise_cross_arcsec", "noise_roll_arcsec", "output_delay_s", "boot_time_s", "mean_stars",
                  "sun_exclusion_deg", "moon_exclusion_deg", "earth_exclusion_deg")
        for name in nonneg:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"EmulatorConfig.{name} must be a finite number >= 0; got {v!r}.")
        for name in ("output_interval_s", "rate_limit_deg_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"EmulatorConfig.{name} must be a finite number > 0; got {v!r}.")
        for name in ("clock_offset_s", "clock_drift_ppm", "temperature_C"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ValueError(f"EmulatorConfig.{name} must be a finite number; got {v!r}.")
        if not abs(self.clock_drift_ppm) < 1e5:
            raise ValueError(f"EmulatorConfig.clock_drift_ppm must be within +-1e5 ppm; got {self.clock_drift_ppm!r}.")
        if not (0.0 <= self.match_probability <= 1.0):
            raise ValueError(f"EmulatorConfig.match_probability must be in [0, 1]; got {self.match_probability!r}.")
        b = np.asarray(self.bias_arcsec, dtype=float)
        if b.shape != (3,) or not np.all(np.isfinite(b)):
            raise ValueError(f"EmulatorConfig.bias_arcsec must be 3 finite numbers; got {self.bias_arcsec!r}.")
        if self.address is not None and not (isinstance(self.address, int) and 0 <= self.address <= 255):
            raise ValueError(f"EmulatorConfig.address must be an int from 0 to 255; got {self.address!r}.")


#: The exposure's float math: compiled where the install could (compiled_paths), the same to the bit.
_math = compiled_paths.load("drivers.star_tracker.exposure_math")
small_rotation = _math.small_rotation
in_field = _math.in_field
checked_truth = _math.checked_truth
