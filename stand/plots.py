"""Plots of a run: one function per figure, each writes one PNG and returns its file name.

Every function takes the telemetry columns (``stand.telemetry.load(run_dir)``: a dict of numpy
arrays keyed by column name), the output directory and explicit arguments, never a Scene, so a
device kind can supply its own plots from the columns it records. Figures are built on
matplotlib's ``Figure`` directly (Agg canvas, no pyplot state), so plotting from a worker thread or
after another library chose a GUI backend is safe.

Conventions: time on x in seconds since the start of the run, labels in words with units, legends
outside the data (to the right of the axes), pass limits drawn as dashed black lines.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

DPI = 110
#: Wider than the matplotlib default, so a whole orbit (about 6000 s) keeps its detail.
WIDTH_IN = 10.0
TIME_LABEL = "time since start (s)"
AXIS_COLOURS = ("tab:blue", "tab:orange", "tab:green")
#: Codes of ``NAME.mode`` and bits of ``NAME.flags`` as a star tracker link records them.
TRACKER_MODES = {"BOOT": 0, "LOST_IN_SPACE": 1, "TRACKING": 2}
TRACKER_FLAG_BITS = {"sun_in_field": 1, "moon_in_field": 2, "earth_in_field": 4, "rate_too_high": 8}
#: Euler angle names for the sequences people name (the rest are "angle 1 about axis i", ...).
EULER_NAMES = {"321": ("yaw", "pitch", "roll"), "123": ("roll", "pitch", "yaw"), "313": ("precession", "nutation",
                                                                                       "spin")}


# ------------------------------------------------------------------------------------------ helpers
def _save(fig: Figure, out_dir, name: str) -> str:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / name, dpi=DPI)
    return name


def _legend_outside(ax, **kw) -> None:
    """A legend to the right of the axes, so it never covers data (none when nothing is labelled)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8, frameon=False,
                  **kw)


def _column(tel, name: str) -> np.ndarray:
    if name not in tel:
        known = ", ".join(sorted(tel)) or "none"
        raise KeyError(f"telemetry has no column {name!r}; columns: {known}.")
    return np.asarray(tel[name], dtype=float)


def _time(tel) -> np.ndarray:
    t = _column(tel, "t_s")
    if len(t) < 2:
        raise ValueError(f"telemetry has {len(t)} rows; a plot needs at least 2.")
    return t


def break_at_jumps(t: np.ndarray, y: np.ndarray, max_jump: float) -> tuple[np.ndarray, np.ndarray]:
    """``(t, y)`` with a NaN row inserted wherever ``y`` jumps by more than ``max_jump`` between
    samples, so a line plot leaves a gap there instead of drawing a vertical line across the axes.

    ``y`` may be (n,) or (n, k); a jump in any column breaks that column only.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    cols = y.reshape(len(t), -1)
    jump = np.abs(np.diff(cols, axis=0)) > max_jump  # (n-1, k)
    rows = np.flatnonzero(jump.any(axis=1))
    if not len(rows):
        return t, y
    t_out = np.insert(t, rows + 1, 0.5 * (t[rows] + t[rows + 1]))
    gap = np.where(jump[rows], np.nan, 0.5 * (cols[rows] + cols[rows + 1]))
    y_out = np.insert(cols, rows + 1, gap, axis=0)
    return t_out, y_out.reshape((len(t_out),) + y.shape[1:])


def euler_series(t, q_BN, seq: str = "321") -> tuple[np.ndarray, np.ndarray]:
    """Euler angles of ``q_BN`` in degrees, ``(t, angles (m, 3))`` ready to plot: a wrap from
    +180 to -180 deg (or a jump through gimbal lock) becomes a gap, never a vertical line."""
    from sim.rotations import euler_from_quat

    ang = np.degrees(euler_from_quat(np.asarray(q_BN, dtype=float), seq))
    return break_at_jumps(t, ang, 180.0)


def _spans(t: np.ndarray, on: np.ndarray) -> list[tuple[float, float]]:
    """Time spans ``(start, width)`` where ``on`` is true; each sample holds until the next."""
    on = np.asarray(on, dtype=bool)
    if not len(t):
        return []
    edges = np.diff(np.concatenate(([False], on, [False])).astype(int))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    t_end = np.append(t[1:], t[-1] + (t[-1] - t[-2] if len(t) > 1 else 0.0))
    return [(float(t[a]), float(t_end[b - 1] - t[a])) for a, b in zip(starts, ends, strict=True)]


def _shade_shadow(ax, t, sun_fraction, label: bool) -> None:
    """Grey bands where the Sun is (partly) hidden by the Earth: darker in umbra."""
    frac = np.nan_to_num(np.asarray(sun_fraction, dtype=float), nan=1.0)
    for span, alpha, what in ((_spans(t, frac < 1.0), 0.15, "Earth shadow (penumbra or umbra)"),
                              (_spans(t, frac <= 0.0), 0.15, None)):
        for i, (a, w) in enumerate(span):
            ax.axvspan(a, a + w, color="0.3", alpha=alpha, lw=0, label=what if label and i == 0 else None)


def _log_axis(ax) -> None:
    """A log y axis labelled 0.1, 0.2, 0.5, 1, 2, 5, ... in plain numbers, readable without powers."""
    from matplotlib.ticker import LogLocator, StrMethodFormatter

    ax.set_yscale("log")
    ax.yaxis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
    ax.yaxis.set_major_formatter(StrMethodFormatter("{x:g}"))
    ax.yaxis.set_minor_formatter(StrMethodFormatter(""))


def _limit_line(ax, t_end: float, label: str, value: float, at_s: float | None) -> None:
    """A pass limit: a dashed line over the whole run, or from ``at_s`` on with a dotted mark there."""
    start = ax.get_xlim()[0] if at_s is None else at_s
    ax.hlines(value, start, t_end, colors="k", linestyles="--", lw=1.0, label=f"pass limit: {label}")
    if at_s is not None:
        ax.axvline(at_s, color="k", lw=0.6, ls=":")


# ------------------------------------------------------------------------------------------ rate
def rate_figure(tel, limits=()) -> Figure:
    t = _time(tel)
    w = np.degrees(_column(tel, "omega_BN_B"))
    mag = np.linalg.norm(w, axis=1)
    fig = Figure(figsize=(WIDTH_IN, 6.0), layout="constrained")
    ax1, ax2 = fig.subplots(2, 1, sharex=True, height_ratios=(1, 1.2))
    for i, axis in enumerate("xyz"):
        ax1.plot(t, w[:, i], lw=0.7, color=AXIS_COLOURS[i], label=f"about body {axis}")
    ax1.set(ylabel="body rate component (deg/s)",
            title="Body rate relative to the inertial frame (omega_BN_B)")
    ax1.axhline(0.0, color="0.5", lw=0.5)
    _legend_outside(ax1)
    ax2.plot(t, mag, "k", lw=1.0, label=f"magnitude |omega|\n({mag[-1]:.3g} deg/s at the end)")
    ax2.plot(t[-1], mag[-1], "ko", ms=4)
    if np.all(mag > 0):
        _log_axis(ax2)
    ax2.set_xlim(t[0], t[-1])
    for label, value, at_s in limits:
        _limit_line(ax2, t[-1], label, value, at_s)
    ax2.set(xlabel=TIME_LABEL, ylabel="rate magnitude (deg/s, log scale)")
    _legend_outside(ax2)
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    return fig


def plot_rate(tel, out_dir, limits=(), name: str = "rate.png") -> str:
    """Body rate components and magnitude (log scale) with pass limits: ``limits`` are
    ``(label, value_deg_s, at_s or None)``, the label in words (it is shown as "pass limit: LABEL");
    a limit with ``at_s`` is drawn from that time on."""
    return _save(rate_figure(tel, limits), out_dir, name)


# -------------------------------------------------------------------------------------- attitude
def _angle_labels(seq: str) -> list[str]:
    names = EULER_NAMES.get(seq)
    order = ("1st", "2nd", "3rd")
    if names:
        return [f"{names[i]} (about {'xyz'[int(seq[i]) - 1]}, {order[i]} rotation)" for i in range(3)]
    return [f"angle {i + 1} (about {'xyz'[int(seq[i]) - 1]}, {order[i]} rotation)" for i in range(3)]


def attitude_figure(tel, seq: str = "321") -> Figure:
    t, ang = euler_series(_time(tel), _column(tel, "q_BN"), seq)
    tait_bryan = len(set(seq)) == 3
    fig = Figure(figsize=(WIDTH_IN, 6.5), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    for i, (ax, label) in enumerate(zip(axes, _angle_labels(seq), strict=True)):
        ax.plot(t, ang[:, i], lw=0.6, color=AXIS_COLOURS[i])
        middle = i == 1
        lo, hi = ((-90, 90) if tait_bryan else (0, 180)) if middle else (-180, 180)
        ax.set_ylim(lo - 8, hi + 8)
        ax.set_yticks(np.arange(lo, hi + 1, 90 if hi - lo > 180 else 45))
        ax.set_ylabel(f"{label.split(' (')[0]} (deg)")
        ax.set_title(label, fontsize=9, loc="left")
        ax.grid(alpha=0.3)
    axes[0].set_xlim(t[0], t[-1])
    axes[-1].set_xlabel(TIME_LABEL)
    fig.suptitle(f"Attitude of the body relative to the inertial frame (q_BN) as {'-'.join(seq)} Euler angles; "
                 "gaps mark wraps through +-180 deg", fontsize=10)
    return fig


def plot_attitude(tel, out_dir, seq: str = "321", name: str = "attitude.png") -> str:
    """Euler angles of q_BN, one panel per angle, lines broken at wraps."""
    return _save(attitude_figure(tel, seq), out_dir, name)


# ---------------------------------------------------------------------------------------- dipole
#: Above this many samples per panel a line is drawn as its envelope (min and max per bin).
ENVELOPE_ABOVE = 3000
ENVELOPE_BINS = 900


def envelope(t: np.ndarray, y: np.ndarray, bins: int = ENVELOPE_BINS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t_bin, low, high)``: the least and greatest ``y`` (n,) in each of ``bins`` equal runs of
    samples, so a signal that swings faster than the pixels can show keeps its extremes."""
    if len(t) <= bins:
        return t, y, y
    start = np.unique(np.linspace(0, len(t), bins + 1).astype(int)[:-1])
    lo, hi = np.minimum.reduceat(y, start), np.maximum.reduceat(y, start)
    # the last value again at the last time, so a step plot reaches the end of the run
    return np.append(t[start], t[-1]), np.append(lo, lo[-1]), np.append(hi, hi[-1])


def _dipole_panel(ax, t, series: dict, cmd, axis: int, colours) -> None:
    dense = len(t) > ENVELOPE_ABOVE
    for k, (label, m) in enumerate(series.items()):
        colour = colours[k % len(colours)]
        if dense:
            tb, lo, hi = envelope(t, m[:, axis])
            ax.fill_between(tb, lo, hi, step="post", color=colour, alpha=0.35, lw=0, label=label)
        else:
            ax.step(t, m[:, axis], where="post", lw=3.5, alpha=0.4, color=colour, label=label)
    if cmd is not None:
        label = "commanded by the controller"
        if dense:
            tb, lo, hi = envelope(t, cmd[:, axis])
            ax.step(tb, lo, where="post", lw=0.7, color="k", label=label)
            ax.step(tb, hi, where="post", lw=0.7, color="k")
        else:
            ax.step(t, cmd[:, axis], where="post", lw=0.8, color="k", label=label)


def dipole_figure(tel, produced: dict, commanded: str | None = None, detail_s: float = 10.0) -> Figure:
    t = _time(tel)
    series = {f"produced by board {dev}": _column(tel, col) for dev, col in produced.items()}
    cmd = _column(tel, commanded) if commanded else None
    if not series and cmd is None:
        raise ValueError("plot_dipole needs a produced or a commanded dipole column; got neither.")
    t_detail = t[0] + min(detail_s, t[-1] - t[0])
    both = cmd is not None and bool(series)
    fig = Figure(figsize=(WIDTH_IN + 2, 8.0 if both else 6.5), layout="constrained")
    rows = 3 + both
    axes = fig.subplots(rows, 2, sharex="col", width_ratios=(3, 1), squeeze=False,
                        height_ratios=(1, 1, 1, 0.7)[:rows])
    colours = ["tab:red", "tab:blue", "tab:green", "tab:purple"]
    full = max((float(np.nanmax(np.abs(m))) for m in [*series.values(), *([cmd] if cmd is not None else [])]),
               default=0.0)
    for col, (x_lo, x_hi) in enumerate(((t[0], t[-1]), (t[0], t_detail))):
        n = len(t) if col == 0 else int(np.searchsorted(t, t_detail, side="right"))
        for i, axis in enumerate("xyz"):
            ax = axes[i, col]
            _dipole_panel(ax, t[:n], {k: v[:n] for k, v in series.items()}, None if cmd is None else cmd[:n], i,
                          colours)
            ax.set_xlim(x_lo, x_hi)
            ax.grid(alpha=0.3)
            if col == 0:
                ax.set_ylabel(f"dipole along body {axis}\n(A m^2)")
        if both:
            ax = axes[3, col]
            for k, (label, m) in enumerate(series.items()):
                d = np.abs(m[:n] - cmd[:n]).max(axis=1)
                tb, _, hi = envelope(t[:n], d) if n > ENVELOPE_ABOVE else (t[:n], d, d)
                ax.step(tb, hi, where="post", lw=0.8, color=colours[k % len(colours)],
                        label=f"|produced - commanded|, largest axis ({label.removeprefix('produced by ')})")
            # A difference at rounding level is drawn as zero, not blown up to fill the panel.
            ax.set_ylim(0.0, max(ax.get_ylim()[1], 0.02 * full, 1e-9))
            ax.set_xlim(x_lo, x_hi)
            ax.grid(alpha=0.3)
            if col == 0:
                ax.set_ylabel("difference\n(A m^2)")
        axes[-1, col].set_xlabel(TIME_LABEL)
    axes[0, 0].set_title("whole run" + (" (band: least to greatest value in each pixel column)"
                                        if len(t) > ENVELOPE_ABOVE else ""), fontsize=9, loc="left")
    axes[0, 1].set_title(f"first {t_detail - t[0]:g} s", fontsize=9, loc="left")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    if both:
        h, lab = axes[3, 0].get_legend_handles_labels()
        handles, labels = handles + h, labels + lab
    fig.suptitle("Magnetorquer dipole in body axes: commanded and produced", fontsize=11)
    fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 3), fontsize=9, frameon=False)
    return fig


def plot_dipole(tel, out_dir, produced: dict, commanded: str | None = None, name: str = "dipole.png") -> str:
    """Dipole per body axis, whole run and its first 10 s, and their difference. ``produced`` maps a
    device name to its dipole column (A m^2), ``commanded`` names the controller's command column or is None."""
    return _save(dipole_figure(tel, produced, commanded), out_dir, name)


# --------------------------------------------------------------------------------------- tracker
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


# ------------------------------------------------------------------------------------ sun sensor
def sun_sensor_figure(tel, name: str, head_labels=None) -> Figure:
    t = _time(tel)
    coarse = f"{name}.currents" in tel
    if not coarse and f"{name}.angles" not in tel:
        raise KeyError(f"telemetry has neither {name}.currents nor {name}.angles; is {name!r} a sun sensor?")
    valid = _column(tel, f"{name}.valid") == 1.0
    frac = _column(tel, f"{name}.sun_fraction")
    fig = Figure(figsize=(WIDTH_IN, 6.0), layout="constrained")
    ax, strip = fig.subplots(2, 1, sharex=True, height_ratios=(2.5, 1))
    if coarse:
        i_mA = _column(tel, f"{name}.currents") * 1e3
        labels = head_labels or [f"head {k + 1}" for k in range(i_mA.shape[1])]
        for k in range(i_mA.shape[1]):
            ax.plot(t, i_mA[:, k], lw=0.7, label=labels[k])
        ax.set(ylabel="head current (mA)", title=f"Coarse sun sensor {name}: photocurrent of each head")
    else:
        ang = np.degrees(_column(tel, f"{name}.angles"))
        ang = np.where(valid[:, None], ang, np.nan)
        for k, what in enumerate(("towards sensor x", "towards sensor y")):
            ax.plot(t, ang[:, k], lw=0.8, color=AXIS_COLOURS[k], label=f"Sun angle {what}")
        ax.set(ylabel="Sun angle from the boresight (deg)",
               title=f"Fine sun sensor {name}: Sun angles of valid samples "
                     f"({100.0 * valid.mean():.0f} % of samples valid)")
        if not valid.any():
            ax.text(0.5, 0.5, "no valid sample in this run", transform=ax.transAxes, ha="center", va="center")
    _shade_shadow(ax, t, frac, label=True)
    ax.grid(alpha=0.3)
    _legend_outside(ax)
    strip.plot(t, frac, "k", lw=1.0, label="visible fraction of the Sun's disk")
    strip.fill_between(t, 0, 1, where=valid, step="post", color="tab:green", alpha=0.25, lw=0,
                       label="sensor reports valid")
    _shade_shadow(strip, t, frac, label=False)
    strip.set(ylim=(-0.05, 1.1), ylabel="fraction", xlabel=TIME_LABEL, xlim=(t[0], t[-1]))
    strip.grid(alpha=0.3)
    _legend_outside(strip)
    return fig


def plot_sun_sensor(tel, out_dir, name: str, head_labels=None, file_name: str | None = None) -> str:
    """Readings of sun sensor ``name`` (coarse: head currents; fine: Sun angles of valid samples),
    Earth shadow shaded, the visible Sun fraction and validity below. Writes ``sun_NAME.png``."""
    return _save(sun_sensor_figure(tel, name, head_labels), out_dir, file_name or f"sun_{name}.png")


# ------------------------------------------------------------------------------ gyro, wheels, pointing
def gyro_figure(tel, name: str) -> Figure:
    t = _time(tel)
    w = np.degrees(_column(tel, f"{name}.omega_S"))
    valid = _column(tel, f"{name}.valid") == 1.0
    fig = Figure(figsize=(WIDTH_IN, 4.5), layout="constrained")
    ax = fig.subplots()
    for k in range(3):
        ax.plot(t, np.where(valid, w[:, k], np.nan), lw=0.7, color=AXIS_COLOURS[k], label=f"sensor {'xyz'[k]}")
    ax.set(xlabel=TIME_LABEL, ylabel="rate (deg/s)", xlim=(t[0], t[-1]),
           title=f"Gyro {name}: the newest valid sample the host decoded ({100.0 * valid.mean():.0f} % of rows valid)")
    ax.grid(alpha=0.3)
    _legend_outside(ax)
    return fig


def plot_gyro(tel, out_dir, name: str) -> str:
    """Rates of gyro ``name`` in sensor axes. Writes ``gyro_NAME.png``."""
    return _save(gyro_figure(tel, name), out_dir, f"gyro_{name}.png")


def wheel_figure(tel, name: str) -> Figure:
    t = _time(tel)
    fig = Figure(figsize=(WIDTH_IN, 6.0), layout="constrained")
    ax, tq = fig.subplots(2, 1, sharex=True)
    ax.plot(t, _column(tel, f"{name}.speed_rad_s") * 30.0 / math.pi, "k", lw=0.9)
    ax.set(ylabel="speed (rpm)", title=f"Reaction wheel {name}: speed relative to the body, torques on the rotor")
    ax.grid(alpha=0.3)
    for col, label, style in (("torque_cmd_Nm", "held command", "tab:blue"),
                              ("motor_torque_Nm", "motor (after its lag)", "tab:orange"),
                              ("net_torque_Nm", "net (motor minus friction)", "tab:green")):
        tq.plot(t, _column(tel, f"{name}.{col}") * 1e3, lw=0.7, color=style, label=label)
    tq.set(ylabel="torque (mN m)", xlabel=TIME_LABEL, xlim=(t[0], t[-1]))
    tq.grid(alpha=0.3)
    _legend_outside(tq)
    return fig


def plot_wheel(tel, out_dir, name: str) -> str:
    """Speed and torques of reaction wheel ``name``. Writes ``wheel_NAME.png``."""
    return _save(wheel_figure(tel, name), out_dir, f"wheel_{name}.png")


def pointing_figure(tel, modes=("detumble", "sun_acquisition", "fine_pointing")) -> Figure:
    """Pointing error (truth against the reference), knowledge error per body axis with the filter's 3-sigma,
    and the mode timeline, from the controller's ``adcs_*`` columns."""
    from stand.adcs.metrics import ARCSEC, error_angles_B

    t = _time(tel)
    q = _column(tel, "q_BN")
    fig = Figure(figsize=(WIDTH_IN, 8.0), layout="constrained")
    pe, ke, strip = fig.subplots(3, 1, sharex=True, height_ratios=(2, 2.5, 1))
    ref = _column(tel, "adcs_q_RN")
    ok = np.all(np.isfinite(ref), axis=1)
    err = np.full(len(t), np.nan)
    if ok.any():
        err[ok] = np.linalg.norm(error_angles_B(q[ok], ref[ok]), axis=1) / ARCSEC
    pe.semilogy(t, err, "k", lw=0.8, label="|attitude - reference|")
    pe.set(ylabel="pointing error (arcsec)", title="Pointing: truth against the controller's reference and estimate")
    pe.grid(alpha=0.3, which="both")
    _legend_outside(pe)
    est = _column(tel, "adcs_q_BN_est")
    s3 = _column(tel, "adcs_sigma3_B") / ARCSEC
    ok = np.all(np.isfinite(est), axis=1)
    e = np.full((len(t), 3), np.nan)
    if ok.any():
        e[ok] = error_angles_B(q[ok], est[ok]) / ARCSEC
    for k in range(3):
        ke.plot(t, e[:, k], lw=0.6, color=AXIS_COLOURS[k], label=f"knowledge error body {'xyz'[k]}")
        ke.plot(t, s3[:, k], lw=0.8, ls="--", color=AXIS_COLOURS[k], label=f"filter 3-sigma {'xyz'[k]}")
        ke.plot(t, -s3[:, k], lw=0.8, ls="--", color=AXIS_COLOURS[k])
    finite = np.abs(e[np.isfinite(e)])
    if len(finite):
        lim = 3.0 * float(np.percentile(finite, 99))
        ke.set_ylim(-max(lim, 1.0), max(lim, 1.0))
    ke.set(ylabel="estimate - truth (arcsec)")
    ke.grid(alpha=0.3)
    _legend_outside(ke)
    mode = _column(tel, "adcs_mode")
    strip.step(t, mode, "k", where="post", lw=1.0)
    strip.set(yticks=range(len(modes)), yticklabels=modes, ylim=(-0.5, len(modes) - 0.5), xlabel=TIME_LABEL,
              xlim=(t[0], t[-1]))
    strip.grid(alpha=0.3)
    return fig


def plot_pointing(tel, out_dir, name: str = "pointing.png") -> str:
    """:func:`pointing_figure` written to ``pointing.png``."""
    return _save(pointing_figure(tel), out_dir, name)
