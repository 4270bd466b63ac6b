"""Run plots from synthetic telemetry: every function writes a readable PNG, and what it draws is
what the columns say (no wrap lines, limits where asked, words in the legends)."""

import math

import numpy as np
import pytest
from matplotlib.image import imread

from sim.rotations import euler_from_quat, quat_from_axis_angle
from stand import devices, plots
from stand.devices import magnetorquer_plots, star_tracker_plots, sun_sensor_plots
from stand.report import rate_limits, write_plots
from stand.scenario import Criterion

N = 3000  # 300 s at 10 Hz


def _tel(n: int = N) -> dict:
    """A spacecraft spinning at 10 deg/s about a skewed axis and slowing down, with a magnetorquer,
    a star tracker reporting at 5 Hz and two sun sensors, in the layout of ``stand.telemetry.load``."""
    t = np.arange(n) * 0.1
    axis = np.array([1.0, 2.0, 3.0]) / math.sqrt(14.0)
    rate = np.radians(10.0) * np.exp(-t / 200.0)
    angle = np.radians(10.0) * 200.0 * (1.0 - np.exp(-t / 200.0))
    q = np.array([quat_from_axis_angle(axis, a) for a in angle])
    rng = np.random.default_rng(0)
    cmd = np.clip(0.3 * np.sin(np.outer(t, [0.5, 0.7, 0.9])), -0.2, 0.2)
    tel = {"t_s": t, "q_BN": q, "omega_BN_B": np.outer(rate, axis), "dipole_cmd_B": cmd,
           "mtq.dipole_B": np.round(cmd / 1e-3) * 1e-3}
    # tracker: a new solution every other row, repeated in between; invalid while the rate is high
    t_exp = np.where(t >= 1.0, np.floor(t / 0.2) * 0.2 - 0.1, np.nan)
    valid = (rate < np.radians(5.0)).astype(float)
    tel.update({"st1.t_exposure_s": t_exp, "st1.q_TN": q, "st1.valid": valid,
                "st1.mode": np.where(valid == 1.0, 2.0, 1.0), "st1.flags": np.where(valid == 1.0, 1.0, 16.0),
                "st1.err_cross": np.abs(rng.normal(0, 2, n)), "st1.err_roll": np.abs(rng.normal(0, 10, n))})
    # sun sensors: the Sun along inertial x, an eclipse from 100 s to 150 s
    frac = np.clip(np.abs(t - 125.0) - 25.0, 0.0, 1.0)
    from sim.rotations import dcm

    s_B = np.einsum("nij,j->ni", dcm(q), [1.0, 0.0, 0.0])
    faces = np.vstack([np.eye(3), -np.eye(3)])[[0, 3, 1, 4, 2, 5]]
    tel["css.currents"] = 1e-3 * np.clip(s_B @ faces.T, 0.0, None) * frac[:, None]
    tel["css.valid"] = (frac > 0).astype(float)
    tel["css.sun_fraction"] = frac
    fine_valid = (s_B[:, 0] > 0.5) & (frac == 1.0)
    tel["fss.angles"] = np.where(fine_valid[:, None], np.c_[np.arctan2(s_B[:, 1], s_B[:, 0]),
                                                               np.arctan2(s_B[:, 2], s_B[:, 0])], np.nan)
    tel["fss.valid"] = fine_valid.astype(float)
    tel["fss.sun_fraction"] = frac
    return tel


def _png(path, min_kb: float = 20.0) -> np.ndarray:
    """The image of a written plot, after checking it is a PNG of plausible size."""
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert path.stat().st_size > min_kb * 1024, f"{path.name} is only {path.stat().st_size} bytes"
    img = imread(path)
    assert img.shape[1] >= 800 and img.shape[0] >= 400
    assert img[..., :3].std() > 0.05  # not a blank canvas
    return img


@pytest.fixture(scope="module")
def tel():
    return _tel()


# ------------------------------------------------------------------------------------------ rate
def test_rate_plot_draws_limits_from_their_time_with_words_and_units(tel, tmp_path):
    limits = [("detumbled at the end", 0.5, None), ("slow after 200 s", 4.0, 200.0)]
    assert plots.plot_rate(tel, tmp_path, limits) == "rate.png"
    _png(tmp_path / "rate.png")
    fig = plots.rate_figure(tel, limits)
    comp, mag = fig.axes
    assert mag.get_yscale() == "log"
    assert "deg/s" in comp.get_ylabel() and "deg/s" in mag.get_ylabel() and "time" in mag.get_xlabel()
    labels = [t.get_text() for t in mag.get_legend().get_texts()]
    assert "pass limit: slow after 200 s" in labels and "pass limit: detumbled at the end" in labels
    segs = {round(float(c.get_segments()[0][0, 1]), 6): c.get_segments()[0] for c in mag.collections}
    assert segs[4.0][0, 0] == 200.0 and segs[4.0][1, 0] == tel["t_s"][-1]
    assert segs[0.5][0, 0] == tel["t_s"][0]
    # the legend sits right of the axes, not over the data
    fig.canvas.draw()
    leg = mag.get_legend().get_window_extent()
    assert leg.x0 >= mag.get_window_extent().x1


def test_rate_limits_come_from_the_rate_criteria_only():
    cs = [Criterion("detumbled", "final_rate_deg_s", max=0.5, min=None, at_s=None),
          Criterion("slow", "max_rate_deg_s_after", max=1.0, min=None, at_s=600.0),
          Criterion("no rejected frames", "frames_rejected", max=0, min=None, at_s=None)]
    got = rate_limits(cs)
    assert [(v, at) for _, v, at in got] == [(0.5, None), (1.0, 600.0)]
    assert "at the end" in got[0][0] and "after t = 600 s" in got[1][0]


# -------------------------------------------------------------------------------------- attitude
def test_break_at_jumps_inserts_a_gap_only_at_a_jump():
    t = np.arange(5.0)
    y = np.array([[170.0, 0.0], [179.0, 1.0], [-179.0, 2.0], [-170.0, 3.0], [-160.0, 4.0]])
    tb, yb = plots.break_at_jumps(t, y, 180.0)
    assert tb.tolist() == [0.0, 1.0, 1.5, 2.0, 3.0, 4.0]
    assert np.isnan(yb[2, 0]) and yb[2, 1] == 1.5  # only the column that jumped is broken
    assert np.array_equal(yb[[0, 1, 3, 4, 5]], y)


def test_attitude_lines_never_jump_more_than_180_deg(tel, tmp_path):
    raw = np.degrees(euler_from_quat(tel["q_BN"], "321"))
    assert np.abs(np.diff(raw, axis=0)).max() > 300  # the spin wraps, so the test can fail
    assert plots.plot_attitude(tel, tmp_path) == "attitude.png"
    _png(tmp_path / "attitude.png")
    fig = plots.attitude_figure(tel, "321")
    lines = [ln for ax in fig.axes for ln in ax.get_lines()]
    assert len(lines) == 3
    for i, ln in enumerate(lines):
        y = np.asarray(ln.get_ydata(), dtype=float)
        steps = np.abs(np.diff(y))
        assert np.nanmax(steps) < 180.0
        # every sample is drawn, unchanged (the inserted rows lie between samples)
        x = np.asarray(ln.get_xdata(), dtype=float)
        np.testing.assert_array_equal(y[np.isin(x, tel["t_s"])], raw[:, i])
    assert sum(np.isnan(ln.get_ydata()).sum() for ln in lines) > 0  # the wraps became gaps
    assert [ax.get_ylabel() for ax in fig.axes] == ["yaw (deg)", "pitch (deg)", "roll (deg)"]


# ---------------------------------------------------------------------------------------- dipole
def test_dipole_plot_shows_commanded_and_produced_in_words(tel, tmp_path):
    assert magnetorquer_plots.plot_dipole(tel, tmp_path, {"mtq": "mtq.dipole_B"}, "dipole_cmd_B") == "dipole.png"
    _png(tmp_path / "dipole.png")
    fig = magnetorquer_plots.dipole_figure(tel, {"mtq": "mtq.dipole_B"}, "dipole_cmd_B")
    labels = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert "produced by board mtq" in labels and "commanded by the controller" in labels
    assert not any("dipole_B" in lab or "dipole_cmd" in lab for lab in labels)
    assert all("A m^2" in ax.get_ylabel() for ax in fig.axes if ax.get_ylabel())
    # the detail column draws the produced dipole wider than the command, so both stay visible
    detail = fig.axes[1]
    widths = {ln.get_label(): ln.get_linewidth() for ln in detail.get_lines()}
    assert widths["produced by board mtq"] > 2 * widths["commanded by the controller"]


def test_envelope_keeps_the_extremes_of_each_bin():
    t = np.arange(1000.0)
    y = np.sin(t * 2.5)
    y[333] = 7.0
    tb, lo, hi = plots.envelope(t, y, bins=100)
    assert len(tb) == 101 and hi.max() == 7.0 and tb[33] <= 333 < tb[34]
    assert np.all(lo <= hi) and lo.min() == y.min()


def test_dipole_plot_needs_a_column():
    with pytest.raises(ValueError, match="produced or a commanded"):
        magnetorquer_plots.dipole_figure(_tel(10), {}, None)
    with pytest.raises(KeyError, match="no column 'mtq.dipole_X'"):
        magnetorquer_plots.dipole_figure(_tel(10), {"mtq": "mtq.dipole_X"}, None)


# --------------------------------------------------------------------------------------- tracker
def test_tracker_solutions_are_one_row_per_exposure(tel):
    sol = star_tracker_plots.tracker_solutions(tel, "st1")
    t = tel["st1.t_exposure_s"]
    assert len(sol["t"]) == len(np.unique(t[np.isfinite(t)])) < np.isfinite(t).sum()
    assert np.all(np.diff(sol["t"]) > 0)


def test_tracker_plot_errors_limits_and_status_strip(tel, tmp_path):
    assert star_tracker_plots.plot_tracker(tel, tmp_path, "st1", 6.0, 30.0, (0.3, 200.0)) == "tracker_st1.png"
    _png(tmp_path / "tracker_st1.png")
    fig = star_tracker_plots.tracker_figure(tel, "st1", 6.0, 30.0, (0.3, 200.0))
    cross, roll, strip = fig.axes
    assert "arcsec" in cross.get_ylabel() and "arcsec" in roll.get_ylabel()
    assert [ln.get_ydata()[0] for ln in cross.get_lines() if ln.get_linestyle() == "--"] == [6.0]
    assert [ln.get_ydata()[0] for ln in roll.get_lines() if ln.get_linestyle() == "--"] == [30.0]
    # plotted errors are those of valid solutions only
    sol = star_tracker_plots.tracker_solutions(tel, "st1")
    dots = cross.get_lines()[0]
    np.testing.assert_array_equal(dots.get_xdata(), sol["t"][sol["valid"] == 1.0])
    rows = [t.get_text() for t in strip.get_yticklabels()]
    assert rows[-1] == "valid solution" and "flag: rate too high" in rows and "mode: tracking" in rows


def test_tracker_codes_match_the_tracker_link():
    from stand.devices.star_tracker import FLAG_BITS, MODES

    assert star_tracker_plots.TRACKER_MODES == MODES and star_tracker_plots.TRACKER_FLAG_BITS == FLAG_BITS


# ------------------------------------------------------------------------------------ sun sensor
@pytest.mark.parametrize("name, unit", [("css", "mA"), ("fss", "deg")])
def test_sun_sensor_plot(tel, tmp_path, name, unit):
    assert sun_sensor_plots.plot_sun_sensor(tel, tmp_path, name) == f"sun_{name}.png"
    _png(tmp_path / f"sun_{name}.png")
    fig = sun_sensor_plots.sun_sensor_figure(tel, name)
    main, strip = fig.axes
    assert unit in main.get_ylabel()
    labels = [t.get_text() for t in main.get_legend().get_texts()]
    assert "Earth shadow (penumbra or umbra)" in labels
    if name == "fss":  # invalid samples are gaps, not zeros
        y = main.get_lines()[0].get_ydata()
        assert np.isnan(y).sum() == (tel["fss.valid"] == 0).sum()


def test_sun_sensor_plot_names_a_missing_sensor(tel):
    with pytest.raises(KeyError, match="neither xss.currents nor xss.angles"):
        sun_sensor_plots.sun_sensor_figure(tel, "xss")


# ------------------------------------------------------------------------------------ the report
def test_write_plots_keeps_its_files(tel, tmp_path):
    made = write_plots(tel, tmp_path, rate_limits=[("detumbled", 0.5, None)])
    assert made == ["rate.png", "attitude.png"]
    # The dipole is the magnetorquer kind's figure, drawn once for all its boards.
    made += devices.get("magnetorquer").kind_plots(tel, ["mtq"], tmp_path)
    assert made == ["rate.png", "attitude.png", "dipole.png"]
    bare = {k: v for k, v in tel.items() if "dipole" not in k}
    assert devices.get("magnetorquer").kind_plots(bare, ["mtq"], tmp_path / "none") == []
    for name in made:
        _png(tmp_path / name)
    assert write_plots({"t_s": np.zeros(1)}, tmp_path / "empty") == []


def _pointing_tel(n: int = 3000) -> dict:
    """A pointing run: the body holds yaw 30, pitch 85 deg (near gimbal lock) within 0.01 deg, and the
    controller's reference is that attitude, with a 2 deg slew error that decays over the first 30 s."""
    from sim.rotations import compose, quat_from_euler

    t = np.arange(n) * 0.1
    rng = np.random.default_rng(1)
    ref = np.tile(quat_from_euler(np.radians([30.0, 85.0, 0.0]), "321"), (n, 1))
    wobble = np.radians(0.01) * rng.standard_normal((n, 3)) + np.radians(2.0) * np.exp(-t / 10.0)[:, None]
    q = compose(quat_from_axis_angle(wobble, np.linalg.norm(wobble, axis=1)), ref)
    return {"t_s": t, "q_BN": q, "adcs_q_RN": ref}


def test_attitude_axes_follow_the_data_and_a_pointing_run_shows_its_error(tmp_path):
    tel = _pointing_tel()
    assert plots.plot_attitude(tel, tmp_path) == "attitude.png"
    _png(tmp_path / "attitude.png")
    fig = plots.attitude_figure(tel, "321")
    err_ax, yaw, pitch, roll = fig.axes[:4]
    assert "error" in err_ax.get_ylabel() and "adcs_q_RN" in err_ax.get_title(loc="left")
    raw = np.degrees(euler_from_quat(tel["q_BN"], "321"))
    # pitch sits near 85 deg: its axis spans the data, not the fixed -98..98 deg it had
    lo, hi = pitch.get_ylim()
    assert lo <= raw[:, 1].min() and hi >= raw[:, 1].max()
    assert hi - lo < 20.0
    # the error panel's scale follows the settled error (0.01 deg = 36 arcsec noise), not the 2 deg start
    lo, hi = err_ax.get_ylim()
    assert hi < 0.5 * 3600.0
    # near gimbal lock: shaded and said in the legend
    labels = [t.get_text() for t in yaw.get_legend().get_texts()]
    assert any("ill-defined" in lab for lab in labels)


def test_attitude_of_a_tumble_keeps_the_full_angle_range(tel):
    fig = plots.attitude_figure(tel, "321")
    yaw = fig.axes[0]
    lo, hi = yaw.get_ylim()
    assert lo < -170 and hi > 170 and -180 in list(yaw.get_yticks())


def test_sun_sensor_plot_says_when_the_whole_run_is_in_shadow(tel):
    dark = {**tel, "css.sun_fraction": np.zeros(len(tel["t_s"])), "css.valid": np.zeros(len(tel["t_s"]))}
    assert "whole run" in sun_sensor_plots.sun_sensor_figure(dark, "css").axes[0].get_title()
    assert "whole run" not in sun_sensor_plots.sun_sensor_figure(tel, "css").axes[0].get_title()
