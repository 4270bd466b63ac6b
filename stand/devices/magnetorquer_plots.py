"""The magnetorquer kind's plots: the dipole the controller commanded and the boards produced."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from stand.plots import (
    ENVELOPE_ABOVE,
    TIME_LABEL,
    WIDTH_IN,
    _column,
    _save,
    _time,
    envelope,
)


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
