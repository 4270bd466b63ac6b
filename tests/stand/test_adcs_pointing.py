"""The pointing plug-in in a closed loop: fake host drivers (the plug-in API's method names) around sim's truth
model with reaction wheels; no device kinds involved."""

import math

import numpy as np
import pytest

from sim.rotations import angle_between, compose, quat_from_axis_angle
from stand.adcs.modes import DETUMBLE, FINE_POINTING, SUN_ACQUISITION
from stand.adcs.pointing import PointingController, default_wheel_axes_B

from .adcs_harness import INERTIA, Q_GB, Q_TB, R_ORBIT, V_ORBIT, Loop

ARCSEC = math.radians(1.0 / 3600.0)
AXIS = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
Q_R = quat_from_axis_angle(AXIS, 1.0)


def _offset(q, deg, axis=(1.0, 1.0, 0.0)):
    a = np.asarray(axis, dtype=float)
    return compose(quat_from_axis_angle(a / np.linalg.norm(a), math.radians(deg)), q)


def _controller(loop, **extra):
    options = dict(inertia_kg_m2=INERTIA, star_tracker="st", star_tracker_q_TB=list(Q_TB), gyro="imu",
                   gyro_q_SB=list(Q_GB), wheels=[f"rw{i}" for i in range(len(loop.wheels))], wheel_inertia_kg_m2=0.02,
                   max_wheel_torque_Nm=loop.max_torque, guidance="inertial", q_RN=list(Q_R),
                   initial_mode=FINE_POINTING)
    options.update(extra)
    return PointingController(loop.devices, 0.1, **options)


def _run(loop, ctl, duration_s, ctl_every=2):
    log = {"t": [], "err": [], "mode": [], "gyro_only": [], "row": [], "covered": []}

    def record(lp, c):
        f = c.filter
        log["covered"].append(f is not None and angle_between(np.array(lp.truth.q), f.q)
                              <= np.linalg.norm(f.sigma3_attitude_rad))
        log["t"].append(lp.truth.t_s)
        log["err"].append(angle_between(np.array(lp.truth.q), c.last_q_RN if c.modes.mode == FINE_POINTING else Q_R))
        log["mode"].append(c.modes.mode)
        log["gyro_only"].append(c.modes.gyro_only)
        log["row"].append(c.telemetry())

    loop.run(ctl, duration_s, ctl_every=ctl_every, record=record)
    return {k: np.array(v) for k, v in log.items()}


@pytest.mark.parametrize("axes", [None, default_wheel_axes_B(4)])
def test_settles_from_a_5_deg_offset_to_below_30_arcsec_with_ideal_sensors(axes):
    loop = Loop(_offset(Q_R, 5.0), axes=axes, speeds=None if axes is None else [30.0, -20.0, 10.0, 0.0])
    ctl = _controller(loop)
    log = _run(loop, ctl, 240.0)
    settled = log["t"] >= 120.0
    assert log["err"][0] > math.radians(4.9)
    assert np.max(log["err"][settled]) < 30 * ARCSEC, np.max(log["err"][settled]) / ARCSEC
    assert set(log["mode"][settled]) == {FINE_POINTING}
    # The telemetry columns are what the controller says they are.
    widths = sum(w for _, w, _ in ctl.telemetry_columns())
    assert log["row"].shape[1] == widths
    # Wheels did the work, and stayed inside their torque limit.
    names = [name for name, w, _ in ctl.telemetry_columns() for _ in range(w)]
    cmd = log["row"][:, [k for k, name in enumerate(names) if name == "adcs_wheel_torque_cmd"]]
    assert cmd.shape[1] == len(loop.wheels) and 0.0 < np.max(np.abs(cmd)) <= loop.max_torque + 1e-15


def test_estimates_the_gyro_bias_through_the_tracker_and_points_with_noise():
    bias = np.array([2e-4, -1e-4, 3e-4])  # rad/s: ~ 40-60 deg/h, body axes
    loop = Loop(_offset(Q_R, 2.0), gyro_bias=bias, tracker_noise_rad=5 * ARCSEC, seed=4)
    ctl = _controller(loop, tracker_sigma_rad=[5 * ARCSEC, 5 * ARCSEC], sigma_bias_rad_s=1e-3)
    log = _run(loop, ctl, 400.0)
    settled = log["t"] >= 200.0
    np.testing.assert_allclose(ctl.filter.bias, bias, atol=5e-6)
    assert np.max(log["err"][settled]) < 30 * ARCSEC
    # The filter's own 3-sigma covers its true error through the run.
    assert np.mean(log["covered"]) >= 0.99
    assert np.all(np.isfinite(log["row"][:, :4]))


def test_rides_a_short_tracker_outage_on_the_gyro_and_falls_back_on_a_long_one():
    bias = np.array([5e-5, -5e-5, 2e-5])
    loop = Loop(_offset(Q_R, 1.0), gyro_bias=bias)
    loop.tracker.outages = [(100.0, 130.0), (200.0, 400.0)]
    ctl = _controller(loop, sigma_bias_rad_s=1e-3, modes={"outage_s": 60.0, "max_sigma3_rad": math.radians(0.5)})
    log = _run(loop, ctl, 500.0)
    short = (log["t"] >= 101.0) & (log["t"] < 130.0)
    assert set(log["mode"][short]) == {FINE_POINTING} and np.all(log["gyro_only"][short])
    assert np.max(log["err"][short]) < 60 * ARCSEC  # the calibrated gyro holds the attitude through 30 s
    long_ = (log["t"] >= 262.0) & (log["t"] < 400.0)
    assert set(log["mode"][long_]) == {SUN_ACQUISITION}
    assert any("outage" in tr[3] for tr in ctl.modes.transitions)
    back = log["t"] >= 450.0
    assert set(log["mode"][back]) == {FINE_POINTING}
    assert np.max(log["err"][back]) < 30 * ARCSEC


def test_detumbles_with_the_wheels_then_acquires_and_points():
    loop = Loop(Q_R, w0=np.radians([2.5, -1.5, 2.0]), max_torque=0.1)
    ctl = _controller(loop, initial_mode=DETUMBLE, max_wheel_torque_Nm=0.1,
                      modes={"hold_s": 5.0, "detumble_entry_rate_rad_s": math.radians(5.0)})
    log = _run(loop, ctl, 600.0)
    path = [m for i, m in enumerate(log["mode"]) if i == 0 or m != log["mode"][i - 1]]
    assert path == [DETUMBLE, SUN_ACQUISITION, FINE_POINTING]
    assert np.max(log["err"][log["t"] >= 500.0]) < 30 * ARCSEC


def test_dumps_wheel_momentum_through_the_magnetorquer_while_pointing():
    J = 0.02
    speeds = [0.6, -0.4, 0.5]  # rad/s: h ~ 0.017 N m s
    loop = Loop(Q_R, speeds=speeds, J=J, step_s=0.1, magnetic=True, inclination_deg=60.0)
    ctl = _controller(loop, magnetorquer="mtq", dump_gain_per_s=0.01, max_dipole_A_m2=1.0)
    h0 = np.linalg.norm(J * np.array(speeds))
    log = _run(loop, ctl, 700.0, ctl_every=1)
    h_end = np.linalg.norm(J * np.array(loop.truth.wheel_speeds_rad_s))
    assert h_end < 0.3 * h0, (h0, h_end)
    assert np.max(log["err"][log["t"] >= 100.0]) < 30 * ARCSEC  # the wheels absorb the dumping torque
    dip = log["row"][:, -3:]
    assert 0.0 < np.max(np.abs(dip)) <= 1.0 + 1e-12


def test_sun_acquisition_turns_the_sun_axis_onto_the_sun_without_a_tracker():
    from sim.rotations import dcm

    from .adcs_harness import FakeFineSunSensor

    sun_N = np.array([0.2, -0.6, 0.77])
    loop = Loop(_offset(Q_R, 0.0))
    s0 = dcm(np.array(loop.truth.q)) @ (sun_N / np.linalg.norm(sun_N))
    assert math.degrees(math.acos(s0[2])) > 20.0  # starts well off the Sun, inside the sensor's field
    loop.devices["sun"] = FakeFineSunSensor(loop, sun_N)
    ctl = _controller(loop, star_tracker=None, sun_sensor="sun", initial_mode=SUN_ACQUISITION)
    loop.run(ctl, 200.0)
    s = dcm(np.array(loop.truth.q)) @ (sun_N / np.linalg.norm(sun_N))
    assert math.degrees(math.acos(min(s[2], 1.0))) < 0.01
    assert np.linalg.norm(loop.truth.w) < 1e-5
    assert ctl.modes.mode == SUN_ACQUISITION


def test_tracks_a_ground_target_through_a_pass():
    from sim.frames import dcm_itrs_gcrs
    from sim.orbit import propagate_kepler
    from sim.rotations import dcm
    from sim.time import Epoch
    from stand.adcs import guidance as gd

    epoch = "2026-03-01T00:00:00Z"
    t0 = Epoch.from_iso(epoch)
    r0, v0 = np.array([R_ORBIT, 0.0, 0.0]), np.array([0.0, V_ORBIT, 0.0])
    # A site 3 deg (about 330 km) off the ground track, passed at t = 150 s.
    r150, _ = propagate_kepler(r0, v0, 150.0)
    site_N = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), math.radians(-3.0))
    site_N = dcm(site_N).T @ (6378137.0 * r150 / np.linalg.norm(r150))
    site_itrs = dcm_itrs_gcrs(t0 + 150.0) @ site_N
    omega_e = np.array([0.0, 0.0, 7.292115e-5])

    def los_N(t):
        r, _ = propagate_kepler(r0, v0, t) if t else (r0, v0)
        rt = dcm_itrs_gcrs(t0 + t).T @ site_itrs
        return (rt - r) / np.linalg.norm(rt - r), r

    rt0 = dcm_itrs_gcrs(t0).T @ site_itrs
    q0, w0 = gd.target_pointing(r0, v0, rt0, np.cross(omega_e, rt0))
    loop = Loop(q0, w0=w0, max_torque=0.05)
    ctl = _controller(loop, guidance="target", orbit_r_N_m=list(r0), orbit_v_N_m_s=list(v0), epoch=epoch,
                      target_itrs_m=list(site_itrs), q_RN=None)
    log = []
    loop.run(ctl, 300.0, record=lambda lp, c: log.append((lp.truth.t_s, *lp.truth.q)))
    log = np.array(log)
    err = []
    for row in log[::10]:
        los, _ = los_N(row[0])
        err.append(math.acos(min(1.0, (dcm(row[1:]) @ los)[2])))
    err = np.array(err)
    rates = np.linalg.norm([gd.target_pointing(*_state(r0, v0, t), dcm_itrs_gcrs(t0 + t).T @ site_itrs,
                                                np.cross(omega_e, dcm_itrs_gcrs(t0 + t).T @ site_itrs))[1]
                            for t in (0.0, 150.0)], axis=1)
    assert rates[1] > 3 * rates[0] and rates[1] > 0.01  # a real pass: the line of sight turns fast overhead
    assert np.max(err) < 30 * ARCSEC, np.max(err) / ARCSEC


def _state(r0, v0, t):
    from sim.orbit import propagate_kepler

    return propagate_kepler(r0, v0, t) if t else (r0, v0)


def test_nadir_guidance_tracks_lvlh():
    from sim.frames import dcm_lvlh_gcrs
    from sim.orbit import propagate_kepler
    from sim.rotations import quat_from_dcm

    r0, v0 = np.array([R_ORBIT, 0.0, 0.0]), np.array([0.0, V_ORBIT, 0.0])
    q_lvlh = quat_from_dcm(dcm_lvlh_gcrs(r0, v0))
    w0 = np.array([0.0, -V_ORBIT / R_ORBIT, 0.0])
    loop = Loop(_offset(q_lvlh, 3.0), w0=w0)
    ctl = _controller(loop, guidance="nadir", orbit_r_N_m=list(r0), orbit_v_N_m_s=list(v0), q_RN=None)
    log = []
    loop.run(ctl, 300.0, record=lambda lp, c: log.append((lp.truth.t_s, *lp.truth.q)))
    log = np.array(log)
    r, v = propagate_kepler(r0, v0, log[:, 0])
    errs = angle_between(log[:, 1:], quat_from_dcm(dcm_lvlh_gcrs(r, v)))
    assert np.max(errs[log[:, 0] >= 150.0]) < 30 * ARCSEC


@pytest.mark.parametrize(("options", "match"), [
    (dict(gyro="nope"), "not a device"),
    (dict(wheels=["rw0", "rw1"]), "at least three"),
    (dict(wheel_axes_B=[[1, 0, 0], [0, 1, 0]]), "one 3-vector per wheel"),
    (dict(speed=3), "not PointingController options"),
    (dict(law="pid"), "law"),
    (dict(guidance="sun"), "epoch"),
    (dict(star_tracker_q_TB=[1, 1, 0, 0]), "unit quaternion"),
    (dict(wheel_inertia_kg_m2=-1.0), "spin inertia"),
])
def test_bad_options_are_refused_in_one_sentence(options, match):
    loop = Loop(Q_R)
    with pytest.raises(ValueError, match=match):
        _controller(loop, **options)


def test_unusable_samples_are_dropped_and_counted_not_flown():
    from types import SimpleNamespace

    loop = Loop(_offset(Q_R, 1.0))
    good_gyro, good_tracker = loop.gyro.take_rate, loop.tracker.take_solution
    bad = {"on": False}
    loop.gyro.take_rate = lambda: (SimpleNamespace(omega_rad_s=(math.nan, 0.0, 0.0), valid=True) if bad["on"]
                                   else good_gyro())
    loop.tracker.take_solution = lambda: (SimpleNamespace(q_TN=(2.0, 0.0, 0.0, 0.0), valid=True) if bad["on"]
                                          else good_tracker())
    ctl = _controller(loop)
    loop.run(ctl, 60.0)
    bad["on"] = True
    loop.run(ctl, 2.0)
    assert ctl.counters["gyro_rejected"] == 20 and ctl.counters["tracker_invalid"] == 20  # 2 s at 10 Hz
    assert np.all(np.isfinite(ctl.filter.q)) and np.all(np.isfinite(ctl.last_wheel_cmd))
    bad["on"] = False
    loop.run(ctl, 120.0)
    assert angle_between(np.array(loop.truth.q), Q_R) < 30 * ARCSEC
