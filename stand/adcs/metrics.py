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


# -- FDIR criteria (issue 24) -------------------------------------------------------------------------------------
#: The column a controller reports its FDIR in (bit flags, stand.adcs.fdir.FLAGS); adcs_mode is MODE above.
FDIR = "adcs_fdir"
#: adcs_fdir bits that are a reconfiguration (a wheel isolated, the rate taken from the tracker), not only a report.
RECONFIGURED_BITS = 1 | 2
#: Metric -> description with the unit; each names its fault (the criterion's ``fault``), whose start and clearing
#: are the run's ``fault_injected`` / ``fault_cleared`` events (the first injection and the first clearing after it).
FAULT_METRICS = {
    "fdir_detect_s": "seconds from the fault's start to the first change of the controller's adcs_fdir (s)",
    "fdir_safe_s": "seconds from the fault's start to a safe or reconfigured mode: adcs_mode falls back from its "
                   "value at the start, or adcs_fdir gains a reconfiguration bit (1 wheel isolated, 2 rate from the "
                   "tracker) (s)",
    "fault_worst_pointing_deg": "largest angle between the true attitude and the controller's reference "
                                "(adcs_q_RN) from the fault's start to its clearing, or to the end (deg)",
    "fault_recovery_s": "seconds from the fault's clearing until the pointing error is back within within_deg for "
                        "the rest of the run (s)",
}


class MetricUnavailable(ValueError):
    """A metric that cannot be computed from this run; the message says why in one sentence."""


def fault_windows(events) -> dict[str, tuple[float, float | None]]:
    """Fault name -> (start s, clearing s or None) from ``events.jsonl`` records (dicts): the first
    ``fault_injected`` of each fault and the first ``fault_cleared`` after it. Records without a name or a finite
    time are skipped."""
    out: dict[str, tuple[float, float | None]] = {}
    for e in events:
        name, t = e.get("fault"), e.get("t_s")
        if not isinstance(name, str) or not isinstance(t, int | float) or not math.isfinite(t):
            continue
        if e.get("kind") == "fault_injected" and name not in out:
            out[name] = (float(t), None)
        elif e.get("kind") == "fault_cleared" and name in out and out[name][1] is None and t >= out[name][0]:
            out[name] = (out[name][0], float(t))
    return out


def _column(tel, name: str) -> np.ndarray:
    if name not in tel:
        raise MetricUnavailable(f"the telemetry has no {name} column (the controller does not report it)")
    return np.asarray(tel[name])


def _before(t: np.ndarray, values: np.ndarray, t0: float):
    """The value on the last row before ``t0`` (the first row's when none is before)."""
    i = int(np.searchsorted(t, t0 - 1e-9)) - 1
    return values[max(i, 0)]


def fault_value(metric: str, fault: str, tel, windows: dict, within_deg: float | None = None) -> float:
    """One of :data:`FAULT_METRICS` for fault ``fault``; raises :class:`MetricUnavailable` saying why it cannot be
    computed (no such fault in the events, a column missing, no change after the fault)."""
    if fault not in windows:
        known = ", ".join(sorted(windows)) or "none"
        raise MetricUnavailable(f"the run's events.jsonl has no fault_injected event for fault {fault!r} (faults "
                                f"injected: {known})")
    start, clear = windows[fault]
    t = np.asarray(tel["t_s"])
    after = t >= start - 1e-9
    if metric == "fdir_detect_s":
        f = _column(tel, FDIR)
        hit = np.nonzero(after & (f != _before(t, f, start)))[0]
        if not len(hit):
            raise MetricUnavailable(f"adcs_fdir never changed after fault {fault!r} started at t = {start:g} s")
        return float(t[hit[0]] - start)
    if metric == "fdir_safe_s":
        f, mode = _column(tel, FDIR).astype(np.int64), _column(tel, MODE)
        new_bits = f & ~int(_before(t, f, start)) & RECONFIGURED_BITS
        hit = np.nonzero(after & ((new_bits != 0) | (mode < _before(t, mode, start))))[0]
        if not len(hit):
            raise MetricUnavailable(f"neither adcs_mode fell back nor adcs_fdir reported a reconfiguration after "
                                    f"fault {fault!r} started at t = {start:g} s")
        return float(t[hit[0]] - start)
    ok = _after(tel, 0.0, REFERENCE)
    if ok is None:
        raise MetricUnavailable("the telemetry has no adcs_q_RN column (the controller records no reference)")
    if metric == "fault_worst_pointing_deg":
        sel = ok & after & (t <= (clear if clear is not None else math.inf) + 1e-9)
        if not np.any(sel):
            raise MetricUnavailable(f"no row records the controller's reference while fault {fault!r} lasts")
        return math.degrees(float(np.max(np.linalg.norm(error_angles_B(tel["q_BN"][sel], tel[REFERENCE][sel]),
                                                        axis=1))))
    if metric == "fault_recovery_s":
        return _recovery_s(fault, clear, t, tel, ok, within_deg)
    raise ValueError(f"unknown fault metric {metric!r}")


def _recovery_s(fault: str, clear: float | None, t, tel, ok, within_deg: float | None) -> float:
    if within_deg is None:
        raise MetricUnavailable("fault_recovery_s needs the criterion's within_deg (the pointing limit)")
    if clear is None:
        raise MetricUnavailable(f"fault {fault!r} never cleared during the run")
    sel = ok & (t >= clear - 1e-9)
    if not np.any(sel):
        raise MetricUnavailable(f"no row records the controller's reference after fault {fault!r} cleared")
    ts = t[sel]
    e = np.degrees(np.linalg.norm(error_angles_B(tel["q_BN"][sel], tel[REFERENCE][sel]), axis=1))
    out = np.nonzero(e > within_deg)[0]
    if not len(out):
        return 0.0
    if out[-1] == len(e) - 1:
        raise MetricUnavailable(f"the pointing error is still {e[-1]:.3g} deg > within_deg = {within_deg:g} deg at "
                                f"the end of the run (t = {ts[-1]:g} s)")
    return float(ts[out[-1] + 1] - clear)
