"""The reaction wheel kind's plots: speed and the torques on the rotor."""

from __future__ import annotations

import math

from matplotlib.figure import Figure

from stand.plots import (
    TIME_LABEL,
    WIDTH_IN,
    _column,
    _legend_outside,
    _save,
    _time,
)


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
