"""The star tracker kind's plots: each tracker's solution errors, validity, mode and flags."""

from __future__ import annotations

import math

import numpy as np
from matplotlib.figure import Figure

from stand.plots import (
    TIME_LABEL,
    WIDTH_IN,
    _column,
    _legend_outside,
    _log_axis,
    _save,
    _spans,
    _time,
)

#: Codes of ``NAME.mode`` and bits of ``NAME.flags`` as a star tracker link records them.
TRACKER_MODES = {"BOOT": 0, "LOST_IN_SPACE": 1, "TRACKING": 2}
#: (The ICD's flags byte: bit 0 is "valid", bit 5 "time synced"; these are the bits that say why not valid.)
TRACKER_FLAG_BITS = {"sun_in_field": 2, "moon_in_field": 4, "earth_in_field": 8, "rate_too_high": 16}


def tracker_solutions(tel, name: str) -> dict[str, np.ndarray]:
    """One row per solution of tracker ``name`` (telemetry repeats the newest until the next):
    ``t`` (exposure time, s), ``valid``, ``mode``, ``flags``, ``cross`` and ``roll`` (arcsec)."""
    t = _column(tel, f"{name}.t_exposure_s")
    ok = np.isfinite(t)
    _, first = np.unique(t[ok], return_index=True)
    idx = np.flatnonzero(ok)[np.sort(first)]
    out = {"t": t[idx]}
    for key, col in (("valid", "valid"), ("mode", "mode"), ("flags", "flags"), ("cross", "err_cross"),
                     ("roll", "err_roll")):
        out[key] = _column(tel, f"{name}.{col}")[idx]
    return out


def _p95(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.percentile(x, 95)) if len(x) else math.nan


def _running_p95(t: np.ndarray, e: np.ndarray, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """95th percentile of ``e`` in consecutive windows of ``window_s``; windows with fewer than 20
    values are left out (NaN), as their percentile says little."""
    ok = np.isfinite(e)
    t, e = t[ok], e[ok]
    if not len(t):
        return np.empty(0), np.empty(0)
    edges = np.arange(t[0], t[-1] + window_s, window_s)
    which = np.digitize(t, edges) - 1
    out = np.full(len(edges), np.nan)
    for k in np.unique(which):
        sel = e[which == k]
        if len(sel) >= 20:
            out[k] = np.percentile(sel, 95)
    # the last window ends with the last value, not a whole window later
    return np.minimum(edges, t[-1]), out


FLAG_COLOURS = {"sun_in_field": "tab:orange", "moon_in_field": "tab:gray", "earth_in_field": "tab:brown",
                "rate_too_high": "tab:red"}


def tracker_figure(tel, name: str, cross_limit_arcsec: float | None = None, roll_limit_arcsec: float | None = None,
                   availability: tuple[float, float] | None = None, modes: dict | None = None,
                   flag_bits: dict | None = None, window_s: float = 100.0) -> Figure:
    t_run = _time(tel)
    sol = tracker_solutions(tel, name)
    modes = TRACKER_MODES if modes is None else modes
    flag_bits = TRACKER_FLAG_BITS if flag_bits is None else flag_bits
    valid = sol["valid"] == 1.0
    fig = Figure(figsize=(WIDTH_IN, 8.0), layout="constrained")
    ax_cross, ax_roll, strip = fig.subplots(3, 1, sharex=True, height_ratios=(1.2, 1.2, 1.3))
    tv = sol["t"][valid]
    log = _log_scale_wanted(np.concatenate((sol["cross"][valid], sol["roll"][valid])))
    for ax, key, colour, dark, what, limit in (
            (ax_cross, "cross", "tab:blue", "navy", "cross-boresight", cross_limit_arcsec),
            (ax_roll, "roll", "tab:orange", "saddlebrown", "roll about the boresight", roll_limit_arcsec)):
        e = sol[key][valid]
        if np.isfinite(e).any():
            ax.plot(tv, e, ".", ms=1.5, color=colour, alpha=0.35, label="each valid solution")
            te, p95 = _running_p95(tv, e, window_s)
            ax.step(te, p95, where="post", color=dark, lw=1.6, zorder=3,
                    label=f"95th percentile per {window_s:g} s\n(whole run: {_p95(e):.3g} arcsec)")
        else:
            ax.text(0.5, 0.5, "no valid solution with a known error in this run", transform=ax.transAxes,
                    ha="center", va="center")
        if limit is not None:
            ax.axhline(limit, color="k", ls="--", lw=1.0, zorder=4, label=f"pass limit on the p95:\n{limit:g} arcsec")
        if log:
            _log_axis(ax)
        else:
            ax.set_ylim(bottom=0.0)
        ax.set_ylabel(f"{what}\nerror (arcsec)")
        ax.grid(alpha=0.3)
        _legend_outside(ax)
    pct = 100.0 * valid.mean() if len(valid) else 0.0
    ax_cross.set_title(f"Star tracker {name}: attitude error of valid solutions against the truth; "
                       f"{len(sol['t'])} solutions, {int(valid.sum())} valid ({pct:.0f} %)", fontsize=10)
    _status_strip(strip, t_run, sol, valid, modes, flag_bits, availability)
    return fig


def _log_scale_wanted(errs: np.ndarray) -> bool:
    """Gaussian errors read best on a linear axis; a log axis only when a few solutions are far off."""
    errs = errs[np.isfinite(errs) & (errs > 0)]
    return bool(len(errs)) and np.percentile(errs, 99.5) > 30 * np.median(errs)


def _status_strip(strip, t_run, sol, valid, modes, flag_bits, availability) -> None:
    """One row per state, a bar wherever the state held (each solution holds until the next)."""
    words = {"BOOT": "booting", "LOST_IN_SPACE": "lost in space", "TRACKING": "tracking"}
    rows = [("valid solution", valid, "tab:green")]
    rows += [(f"mode: {words.get(m, m.lower().replace('_', ' '))}", sol["mode"] == code,
              "tab:cyan" if m == "TRACKING" else "tab:olive") for m, code in modes.items()]
    flags = np.nan_to_num(sol["flags"]).astype(int)
    rows += [(f"flag: {f.replace('_', ' ')}", (flags & bit) != 0, FLAG_COLOURS.get(f, "tab:red"))
             for f, bit in flag_bits.items()]
    for k, (_, on, colour) in enumerate(rows):
        strip.broken_barh(_spans(sol["t"], on), (len(rows) - 1 - k - 0.35, 0.7), color=colour, lw=0)
    if len(sol["t"]) and sol["t"][0] > t_run[0]:
        strip.axvspan(t_run[0], sol["t"][0], color="0.85", lw=0)
    strip.set_yticks(range(len(rows)), [r[0] for r in reversed(rows)], fontsize=8)
    strip.set_ylim(-0.6, len(rows) - 0.4)
    if availability is not None:
        least, after_s = availability
        sel = sol["t"] >= after_s
        got = 100.0 * valid[sel].mean() if sel.any() else math.nan
        strip.axvline(after_s, color="k", lw=1.0, ls="--")
        strip.annotate(f"valid {got:.0f} % from t = {after_s:g} s (pass limit: at least {100 * least:g} %)",
                       (after_s, len(rows) - 0.4), xytext=(-4, 2), textcoords="offset points", ha="right",
                       va="bottom", fontsize=8)
    strip.set_xlim(t_run[0], t_run[-1])
    strip.set_xlabel(TIME_LABEL)
    strip.grid(alpha=0.3, axis="x")


def plot_tracker(tel, out_dir, name: str, cross_limit_arcsec: float | None = None,
                 roll_limit_arcsec: float | None = None, availability: tuple[float, float] | None = None,
                 modes: dict | None = None, flag_bits: dict | None = None, file_name: str | None = None) -> str:
    """Errors of the valid solutions of star tracker ``name`` (each solution and a running 95th
    percentile) and a strip of its validity, mode and flags over time. Limits: the p95 error limits
    in arcsec and ``availability = (least valid fraction, from t_s)``. ``modes`` and ``flag_bits``
    give the codes of ``NAME.mode`` and ``NAME.flags`` (default: those of the stand's tracker link).
    Writes ``tracker_NAME.png``."""
    fig = tracker_figure(tel, name, cross_limit_arcsec, roll_limit_arcsec, availability, modes, flag_bits)
    return _save(fig, out_dir, file_name or f"tracker_{name}.png")
