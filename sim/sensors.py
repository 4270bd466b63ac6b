"""Sun sensors that read the environment: coarse (cosine) heads and a two-axis fine sun sensor.

Inputs are the Sun direction in the body frame (``sHat_B``, unit, ``(..., 3)``, e.g.
``dcm(q_BN) @ unit(r_sun_N - r_sat_N)``) and the visible fraction of the Sun's disk
(``nu`` from :func:`sim.environment.shadow_fraction`: 1 full sun, 0 umbra), so eclipse and
penumbra dim every head. Noise comes only from the ``numpy.random.Generator`` passed in; with
``rng=None`` the output is noise-free. Earth albedo is not modelled (it adds up to ~30 % of the
Sun's signal to a nadir-facing coarse head; a known limitation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CoarseSunSensors", "FineSunSensor"]


def _unit_rows(v, name: str) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if v.shape[-1:] != (3,) or np.any(n == 0) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be finite non-zero vectors of shape (..., 3); got shape {v.shape}.")
    return v / n


@dataclass(frozen=True)
class CoarseSunSensors:
    """Cosine-law photodiode heads: ``I_k = I_max nu max(0, n_k . sHat_B) + noise``, clipped at 0.

    ``normals_B``: ``(k, 3)`` head normals in the body frame; ``i_max_A``: current at normal
    incidence in full sun (A); ``noise_A``: 1-sigma white noise (A); ``cutoff_deg``: incidence
    beyond which a head reads 0 (its housing; 90 is the bare cosine law).
    """

    normals_B: np.ndarray
    i_max_A: float = 1e-3
    noise_A: float = 0.0
    cutoff_deg: float = 90.0

    def __post_init__(self):
        object.__setattr__(self, "normals_B", _unit_rows(np.atleast_2d(self.normals_B), "normals_B"))
        if not (np.isfinite(self.i_max_A) and self.i_max_A > 0):
            raise ValueError(f"coarse sun sensor i_max_A = {self.i_max_A!r} must be a finite positive current.")
        if not (np.isfinite(self.noise_A) and self.noise_A >= 0):
            raise ValueError(f"coarse sun sensor noise_A = {self.noise_A!r} must be finite and >= 0.")
        if not 0 < self.cutoff_deg <= 90:
            raise ValueError(f"coarse sun sensor cutoff_deg = {self.cutoff_deg!r} is outside (0, 90].")

    def measure(self, sHat_B, nu, rng: np.random.Generator | None = None) -> np.ndarray:
        """Head currents (A), shape ``(..., k)``."""
        s = _unit_rows(sHat_B, "sHat_B")
        cosang = s @ self.normals_B.T
        lit = cosang >= np.cos(np.radians(self.cutoff_deg)) - 1e-15
        i = self.i_max_A * np.asarray(nu, dtype=float)[..., None] * np.where(lit, np.maximum(cosang, 0.0), 0.0)
        if rng is not None and self.noise_A > 0:
            i = i + rng.normal(0.0, self.noise_A, size=i.shape)
        return np.maximum(i, 0.0)

    def estimate_sun_B(self, currents_A) -> np.ndarray:
        """Least-squares Sun direction (unit, body) from head currents; needs >= 3 lit heads spanning 3D."""
        c = np.asarray(currents_A, dtype=float)
        x, *_ = np.linalg.lstsq(self.normals_B, c.T, rcond=None)
        x = x.T
        return x / np.linalg.norm(x, axis=-1, keepdims=True)


@dataclass(frozen=True)
class FineSunSensor:
    """Two-axis fine sun sensor, boresight +z of its frame: angles ``alpha = atan2(s_x, s_z)``,
    ``beta = atan2(s_y, s_z)`` (rad) with white noise ``noise_rad``; valid only with the Sun
    within ``fov_half_deg`` of the boresight and ``nu >= min_fraction`` (it needs a bright enough
    spot: penumbra below that and umbra read invalid, angles NaN).

    ``dcm_SB``: body -> sensor frame (from the mount quaternion).
    """

    dcm_SB: np.ndarray
    fov_half_deg: float = 60.0
    noise_rad: float = 0.0
    min_fraction: float = 0.5

    def __post_init__(self):
        d = np.asarray(self.dcm_SB, dtype=float)
        if d.shape != (3, 3) or not np.allclose(d @ d.T, np.eye(3), atol=1e-9) or np.linalg.det(d) < 0:
            raise ValueError("fine sun sensor dcm_SB must be a 3x3 proper rotation matrix.")
        object.__setattr__(self, "dcm_SB", d)
        if not 0 < self.fov_half_deg < 90:
            raise ValueError(f"fine sun sensor fov_half_deg = {self.fov_half_deg!r} is outside (0, 90).")
        if not (np.isfinite(self.noise_rad) and self.noise_rad >= 0):
            raise ValueError(f"fine sun sensor noise_rad = {self.noise_rad!r} must be finite and >= 0.")
        if not 0 < self.min_fraction <= 1:
            raise ValueError(f"fine sun sensor min_fraction = {self.min_fraction!r} is outside (0, 1].")

    def measure(self, sHat_B, nu, rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(angles (..., 2) rad, valid (...) bool)``; invalid samples carry NaN angles."""
        s = _unit_rows(sHat_B, "sHat_B") @ self.dcm_SB.T
        valid = (s[..., 2] >= np.cos(np.radians(self.fov_half_deg))) & (np.asarray(nu) >= self.min_fraction)
        ang = np.stack((np.arctan2(s[..., 0], s[..., 2]), np.arctan2(s[..., 1], s[..., 2])), axis=-1)
        if rng is not None and self.noise_rad > 0:
            ang = ang + rng.normal(0.0, self.noise_rad, size=ang.shape)
        return np.where(valid[..., None], ang, np.nan), valid
