"""Pointing and knowledge errors of a run, from the telemetry, against the truth.

They read the truth's ``q_BN`` and the columns the reference ADCS records by convention (any controller that
records the same names is scored the same way): ``adcs_q_BN_est`` (the filter's attitude), ``adcs_sigma3_B``
(its 3-sigma per body axis, rad), ``adcs_q_RN`` (the reference it points at) and ``adcs_mode``.
"""

from __future__ import annotations

import math

import numpy as np

ARCSEC = math.pi / 180.0 / 3600.0
#: Columns a controller records for these metrics.
ESTIMATE, SIGMA3, REFERENCE, MODE = "adcs_q_BN_est", "adcs_sigma3_B", "adcs_q_RN", "adcs_mode"


def _dcm(q: np.ndarray) -> np.ndarray:
    """Rows of attitude matrices (n, 3, 3) from scalar-first quaternions (n, 4), each normalised."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([w * w + x * x - y * y - z * z, 2 * (x * y + w * z), 2 * (x * z - w * y)], axis=-1),
        np.stack([2 * (x * y - w * z), w * w - x * x + y * y - z * z, 2 * (y * z + w * x)], axis=-1),
        np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), w * w - x * x - y * y + z * z], axis=-1),
    ], axis=1)


def error_angles_B(q_true: np.ndarray, q_other: np.ndarray) -> np.ndarray:
    """Small-rotation vectors (n, 3), rad, body axes, taking the true attitude to the other one; exact angle
    (not the small-angle value) in the norm, so a large error is not understated."""
    E = _dcm(q_other) @ np.transpose(_dcm(q_true), (0, 2, 1))
    v = 0.5 * np.stack([E[:, 1, 2] - E[:, 2, 1], E[:, 2, 0] - E[:, 0, 2], E[:, 0, 1] - E[:, 1, 0]], axis=1)
    s = np.linalg.norm(v, axis=1)
    c = np.clip(0.5 * (np.trace(E, axis1=1, axis2=2) - 1.0), -1.0, 1.0)
    angle = np.arctan2(s, c)
    scale = np.where(s > 0, angle / np.where(s > 0, s, 1.0), 1.0)
    return v * scale[:, None]


def _after(tel, at_s: float | None, column: str) -> np.ndarray | None:
    if column not in tel:
        return None
    sel = tel["t_s"] >= (at_s or 0.0) - 1e-9
    ok = sel & np.all(np.isfinite(tel[column]), axis=1)
    return ok


def knowledge_error_rad(tel, at_s: float | None = None) -> np.ndarray:
    """(n, 3) knowledge error of the filter's attitude against the truth after ``at_s`` (rad, body axes)."""
    ok = _after(tel, at_s, ESTIMATE)
    if ok is None or not np.any(ok):
        return np.zeros((0, 3))
    return error_angles_B(tel["q_BN"][ok], tel[ESTIMATE][ok])


def pointing_error_rad(tel, at_s: float | None = None) -> np.ndarray:
    """Angles (n,) between the true attitude and the reference after ``at_s`` (rad)."""
    ok = _after(tel, at_s, REFERENCE)
    if ok is None or not np.any(ok):
        return np.zeros(0)
    return np.linalg.norm(error_angles_B(tel["q_BN"][ok], tel[REFERENCE][ok]), axis=1)


def value(metric: str, at_s: float | None, tel) -> float:
    """One of :data:`METRICS` (NaN when the run recorded no estimate or reference after ``at_s``)."""
    if metric == "pointing_error_arcsec_p95_after":
        e = pointing_error_rad(tel, at_s)
        return float(np.percentile(e, 95)) / ARCSEC if len(e) else math.nan
    e = knowledge_error_rad(tel, at_s)
    if not len(e):
        return math.nan
    if metric == "knowledge_error_arcsec_p95_after":
        return float(np.percentile(np.linalg.norm(e, axis=1), 95)) / ARCSEC
    if metric == "knowledge_within_3sigma_fraction":
        ok = _after(tel, at_s, ESTIMATE)
        s3 = tel[SIGMA3][ok]
        return float(np.mean(np.abs(e) <= s3))
    raise ValueError(f"unknown pointing metric {metric!r}")


#: Metric -> description with the unit; all take at_s (the settle time).
METRICS = {
    "pointing_error_arcsec_p95_after": "95th percentile of the angle between the true attitude and the controller's "
                                       "reference (adcs_q_RN) after time at_s (arcsec)",
    "knowledge_error_arcsec_p95_after": "95th percentile of the angle between the true attitude and the controller's "
                                        "estimate (adcs_q_BN_est) after time at_s (arcsec)",
    "knowledge_within_3sigma_fraction": "fraction of the estimate's per-axis errors after time at_s within the "
                                        "filter's own 3-sigma (adcs_sigma3_B)",
}
