"""The sun sensor kind's plots: head currents or angles, the visible Sun fraction and validity."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from stand.plots import (
    AXIS_COLOURS,
    TIME_LABEL,
    WIDTH_IN,
    _column,
    _legend_outside,
    _save,
    _shade_shadow,
    _time,
)


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
    if np.all(np.nan_to_num(frac, nan=1.0) <= 0.0):
        # a run wholly in the Earth's shadow: say why the panel is grey
        ax.set_title(ax.get_title() + "\nthe Sun is behind the Earth for the whole run (no direct sunlight)",
                     fontsize=10)
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
