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

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from stand.adcs.metrics import ARCSEC, error_angles_B

DPI = 110
#: Wider than the matplotlib default, so a whole orbit (about 6000 s) keeps its detail.
WIDTH_IN = 10.0
TIME_LABEL = "time since start (s)"
AXIS_COLOURS = ("tab:blue", "tab:orange", "tab:green")
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


#: Pitch (the middle Tait-Bryan angle) this close to +-90 deg makes yaw and roll ill-defined (gimbal lock).
GIMBAL_LOCK_MARGIN_DEG = 10.0


def angle_limits(y: np.ndarray, lo: float, hi: float, min_span: float = 0.2) -> tuple[float, float]:
    """y limits around the finite data in ``y`` (deg) with a 8 % margin, never wider than the angle's own
    range ``lo``..``hi`` (plus a little) and never narrower than ``min_span``, so a pointing run's nearly
    constant angle shows its wander instead of a flat line on a +-180 deg axis."""
    y = np.asarray(y, dtype=float)
    y = y[np.isfinite(y)]
    if not len(y):
        return lo - 8.0, hi + 8.0
    a, b = float(y.min()), float(y.max())
    if b - a < min_span:
        mid = 0.5 * (a + b)
        a, b = mid - 0.5 * min_span, mid + 0.5 * min_span
    pad = 0.08 * (b - a)
    return max(a - pad, lo - 8.0), min(b + pad, hi + 8.0)


def _angle_axis(ax, y, lo: float, hi: float) -> None:
    """Autoscaled around the data; ticks every 90 (or 45) deg only when the data span most of the range."""
    from matplotlib.ticker import MaxNLocator

    y0, y1 = angle_limits(y, lo, hi)
    ax.set_ylim(y0, y1)
    if y1 - y0 > 0.75 * (hi - lo):
        ax.set_yticks(np.arange(lo, hi + 1, 90 if hi - lo > 180 else 45))
    else:
        ax.yaxis.set_major_locator(MaxNLocator(nbins=5, steps=(1, 2, 2.5, 5, 10)))


def attitude_error_deg(tel) -> np.ndarray | None:
    """Per body axis rotation (n, 3) in deg from the controller's reference ``adcs_q_RN`` to the true attitude
    (``-error_angles_B(q_BN, q_RN)``), NaN where there is no reference; None without any reference."""
    if "adcs_q_RN" not in tel:
        return None
    q, ref = _column(tel, "q_BN"), _column(tel, "adcs_q_RN")
    ok = np.all(np.isfinite(ref), axis=1)
    if not ok.any():
        return None
    err = np.full((len(q), 3), np.nan)
    err[ok] = -np.degrees(error_angles_B(q[ok], ref[ok]))
    return err


def _error_panel(ax, t, err) -> None:
    # arcsec when the whole error is below 0.05 deg after the start, so the axis reads 10, 20 not 0.0025
    settled = np.abs(err[int(0.2 * len(err)):])
    small = np.isfinite(settled).any() and float(np.nanmax(settled)) < 0.05
    unit, err = ("arcsec", err * 3600.0) if small else ("deg", err)
    for k in range(3):
        ax.plot(t, err[:, k], lw=0.7, color=AXIS_COLOURS[k], label=f"about body {'xyz'[k]}")
    mag = np.linalg.norm(err, axis=1)
    ax.plot(t, mag, "k", lw=0.8, label="angle of the error")
    big = np.nanmax(mag)
    # the last 80 % of the run sets the scale when the start (the slew to the reference) is far larger, so the
    # settled error stays readable; the clipped start is said in the title
    tail = mag[int(0.2 * len(mag)):]
    tail_max = float(np.nanmax(tail)) if np.isfinite(tail).any() else big
    lim = max(1.2 * (tail_max if big > 5.0 * tail_max else big), 1e-3)
    ax.set_ylim(-lim, lim)
    clipped = " (the start is off the axes)" if big > lim else ""
    ax.set_title(f"attitude error: rotation from the controller's reference (adcs_q_RN) to the true attitude, "
                 f"per body axis{clipped}", fontsize=9, loc="left")
    ax.set_ylabel(f"error ({unit})")
    ax.axhline(0.0, color="0.5", lw=0.5)
    ax.grid(alpha=0.3)
    _legend_outside(ax)


def _gimbal_lock_spans(ax, t_raw, pitch_raw) -> bool:
    near = np.abs(np.asarray(pitch_raw)) > 90.0 - GIMBAL_LOCK_MARGIN_DEG
    for j, (a, w) in enumerate(_spans(t_raw, near)):
        ax.axvspan(a, a + w, color="tab:red", alpha=0.12, lw=0,
                   label=f"pitch within {GIMBAL_LOCK_MARGIN_DEG:g} deg of +-90:\nyaw and roll ill-defined"
                   if j == 0 else None)
    return bool(near.any())


def attitude_figure(tel, seq: str = "321") -> Figure:
    """Euler angles of ``q_BN`` (one panel per angle, axes around the data, wraps broken, gimbal lock shaded),
    and above them, when the run has a controller reference, the attitude error relative to it: for a pointing
    run the angles themselves barely move and near gimbal lock say little, the error is what is judged."""
    t_raw = _time(tel)
    q = _column(tel, "q_BN")
    t, ang = euler_series(t_raw, q, seq)
    tait_bryan = len(set(seq)) == 3
    err = attitude_error_deg(tel)
    fig = Figure(figsize=(WIDTH_IN, 6.5 if err is None else 8.5), layout="constrained")
    axes = list(fig.subplots(3 + (err is not None), 1, sharex=True,
                             height_ratios=(1.3, 1, 1, 1) if err is not None else None))
    if err is not None:
        _error_panel(axes.pop(0), t_raw, err)
    locked = False
    for i, (ax, label) in enumerate(zip(axes, _angle_labels(seq), strict=True)):
        ax.plot(t, ang[:, i], lw=0.6, color=AXIS_COLOURS[i])
        middle = i == 1
        lo, hi = ((-90, 90) if tait_bryan else (0, 180)) if middle else (-180, 180)
        _angle_axis(ax, ang[:, i], lo, hi)
        ax.set_ylabel(f"{label.split(' (')[0]} (deg)")
        ax.set_title(label, fontsize=9, loc="left")
        ax.grid(alpha=0.3)
    if tait_bryan:
        from sim.rotations import euler_from_quat

        raw_mid = np.degrees(euler_from_quat(q, seq))[:, 1]
        for ax in (axes[0], axes[2]):
            locked = _gimbal_lock_spans(ax, t_raw, raw_mid) or locked
        if locked:
            _legend_outside(axes[0])
    fig.axes[0].set_xlim(t_raw[0], t_raw[-1])
    axes[-1].set_xlabel(TIME_LABEL)
    fig.suptitle(f"Attitude of the body relative to the inertial frame (q_BN) as {'-'.join(seq)} Euler angles; "
                 "gaps mark wraps through +-180 deg", fontsize=10)
    return fig


def plot_attitude(tel, out_dir, seq: str = "321", name: str = "attitude.png") -> str:
    """Euler angles of q_BN, one panel per angle, lines broken at wraps."""
    return _save(attitude_figure(tel, seq), out_dir, name)


# ------------------------------------------------------------------------------------- envelopes
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


# -------------------------------------------------------------------------------------- pointing
def pointing_figure(tel, modes=("detumble", "sun_acquisition", "fine_pointing")) -> Figure:
    """Pointing error (truth against the reference), knowledge error per body axis with the filter's 3-sigma,
    and the mode timeline, from the controller's ``adcs_*`` columns."""
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
