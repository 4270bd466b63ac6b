"""The gyro kind's plots: the rates each gyro's host decoded."""

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
    _time,
)


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
