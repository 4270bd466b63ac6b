"""Every fault type through a whole run, the way a scenario gives it: its effect on the wire (the host's counters,
what the device sent) or on the truth, and the run unchanged to the bit until the fault starts.

One short run per type (12 s, the fault from 4 s to 8 s) against the same run without it. The scenes: the
acquisition scene (star tracker, coarse sun sensor, gyro, four wheels, the reference ADCS), the detumble (the
magnetorquer board) and the detumble in the Helmholtz cage. The driver-level tests (tests/drivers/test_link_faults.py,
test_device_faults.py) check each effect's closed form; here the point is that the stand's fault types reach them.
"""

from __future__ import annotations

import copy
import functools
import tomllib

import numpy as np
import pytest

from stand import compose, loop, report, scenario
from stand.faults import FAULT_TYPES
from stand.telemetry import load

T0, T1, DURATION_S = 4.0, 8.0, 12.0


@functools.cache
def _base(name: str) -> dict:
    return tomllib.loads((scenario.SCENARIO_DIR / f"{name}.toml").read_text())


def _run(tmp_path, scene_name: str, faults, tag: str, keep=None):
    data = copy.deepcopy(_base(scene_name))
    data["scenario"]["duration_s"] = DURATION_S
    data["criteria"] = []
    if faults:
        data["faults"] = faults
    out = tmp_path / tag
    with compose.build(scenario.parse(data, tag)) as scene:
        result = loop.run(scene, out)
        assert result.status == "completed", result.error
        summary = report.write_summary(scene, result, out, plots=False)
        extra = keep(scene) if keep is not None else None
    return load(out), summary, extra


@pytest.fixture(scope="module")
def nominal(tmp_path_factory):
    cache = {}

    def get(scene_name, keep=None):
        key = (scene_name, keep)
        if key not in cache:
            cache[key] = _run(tmp_path_factory.mktemp("nominal"), scene_name, None, scene_name, keep)
        return cache[key]
    return get


def _inside(tel, lag_s=0.3):
    t = tel["t_s"]
    return (t >= T0 + lag_s) & (t < T1)


def _link(summary, name):
    return summary["faults"][name]["link_counters"]


def _counters(summary, device):
    return summary["device_counters"][device]


# Each case: (type, scene, device, params, check(tel, tel0, summary, summary0, extra, extra0)).
def _gyro_host(s):
    return _counters(s, "imu")["host_counters"]


def _check_drop(tel, tel0, s, s0, *_):
    dropped = _link(s, "f")["dropped"]
    assert dropped > 0
    assert _gyro_host(s)["frames_received"] == _gyro_host(s0)["frames_received"] - dropped


def _check_bits(tel, tel0, s, s0, *_):
    hit, h = _link(s, "f")["corrupted"], _gyro_host(s)
    # No corrupted datagram is taken: each is dropped whole (24 bytes), by the CRC check, or by the framing when
    # the flipped bit is in the identifier byte.
    assert hit > 0 and h["frames_received"] == _gyro_host(s0)["frames_received"] - hit
    assert h["bytes_dropped"] == 24 * hit and 0 < h["rejected_crc"] <= hit


def _check_truncated(tel, tel0, s, s0, *_):
    cut = _link(s, "f")["truncated"]
    h = _gyro_host(s)
    assert cut > 0 and h["frames_received"] <= _gyro_host(s0)["frames_received"] - cut + 1
    assert h["bytes_dropped"] > 0 or h["rejected_crc"] + h["rejected_other"] > 0


def _check_late(tel, tel0, s, s0, *_):
    assert _link(s, "f")["delayed"] > 0
    inside = _inside(tel)
    assert not np.array_equal(tel["imu.omega_S"][inside], tel0["imu.omega_S"][inside])


def _check_reorder(tel, tel0, s, s0, *_):
    swapped, h = _link(s, "f")["reordered"], _gyro_host(s)
    assert swapped > 0 and h["frames_received"] == _gyro_host(s0)["frames_received"]  # nothing lost, only swapped
    # A held sample arrives after a newer one: counted, not taken as the newest (two held in a row go out together,
    # in order, so there can be fewer stale samples than swaps).
    assert 0 < h["stale"] <= swapped


def _check_duplicate(tel, tel0, s, s0, *_):
    twice, h = _link(s, "f")["duplicated"], _gyro_host(s)
    assert twice > 0 and h["frames_received"] == _gyro_host(s0)["frames_received"] + twice
    # The host takes each sample once: a repeat is counted, never a gap of 255 samples.
    assert h["duplicates"] == twice and h["samples"] == _gyro_host(s0)["samples"] and h["samples_lost"] == 0


def _check_babble(tel, tel0, s, s0, *_):
    h = _gyro_host(s)
    assert _link(s, "f")["babbled"] > 0 and h["bytes_dropped"] + h["rejected_crc"] + h["rejected_other"] > 0


def _check_silence(tel, tel0, s, s0, *_):
    assert _link(s, "f")["silenced"] > 0
    held = tel["imu.omega_S"][_inside(tel)]
    assert np.all(held == held[0])  # nothing new reached the host: the telemetry holds the last sample


def _check_error_frames(tel, tel0, s, s0, *_):
    n = _link(s, "f")["error_frames"]
    host = _counters(s, "rw1")["host_counters"]
    assert n > 0 and host["rejected_other"] >= 1


def _check_reboot(tel, tel0, s, s0, *_):
    emu = _counters(s, "imu")["emulator_counters"]
    assert emu["reboots"] == 1
    held = tel["imu.omega_S"][(tel["t_s"] >= T0 + 0.1) & (tel["t_s"] < T0 + 0.9)]
    assert np.all(held == held[0])  # silent while it boots (boot_s = 1)


def _time_us(scene):
    from drivers.gyro.codec import GyroRate

    return scene.devices["imu"].observer.latest(GyroRate).time_us


def _check_jump(tel, tel0, s, s0, extra, extra0):
    assert extra - extra0 == 2_000_000  # the time tags shifted by the jump, 2 s


def _check_drift(tel, tel0, s, s0, extra, extra0):
    # 1000 ppm from t = 4 s to the last sample (t = 12 s): 8 ms, to the tag's microsecond.
    assert abs((extra - extra0) - 8000) <= 1


def _check_blinded(tel, tel0, s, s0, *_):
    inside = _inside(tel, 0.5)
    assert np.all(tel["st.valid"][inside] == 0.0) and np.any(tel0["st.valid"][inside] == 1.0)


def _check_misid(tel, tel0, s, s0, *_):
    inside = _inside(tel, 0.5) & (tel["st.valid"] == 1.0)
    assert inside.any()
    err = np.hypot(tel["st.err_cross"][inside], tel["st.err_roll"][inside])
    assert np.all(err > 0.9 * 3600.0)  # 1 deg, still valid


def _check_slow(tel, tel0, s, s0, *_):
    inside = _inside(tel, 1.0)
    lag = tel["t_s"][inside] - tel["st.t_exposure_s"][inside]
    lag0 = tel0["t_s"][inside] - tel0["st.t_exposure_s"][inside]
    assert np.nanmedian(lag) >= np.nanmedian(lag0) + 0.4  # 0.5 s later


def _check_seized(tel, tel0, s, s0, *_):
    speed = tel["rw1.speed_rad_s"]
    assert abs(speed[np.searchsorted(tel["t_s"], T1) - 1]) < 1.0 and abs(speed[0]) > 1.0


def _check_motor_off(tel, tel0, s, s0, *_):
    inside = _inside(tel)
    assert np.all(tel["rw1.motor_torque_Nm"][inside] == 0.0)


def _check_torque_loss(tel, tel0, s, s0, *_):
    inside = _inside(tel) & (np.abs(tel["rw1.torque_cmd_Nm"]) > 1e-6)
    ratio = tel["rw1.motor_torque_Nm"][inside] / tel["rw1.torque_cmd_Nm"][inside]
    assert inside.any() and np.allclose(ratio, 0.5, atol=0.05)


def _check_friction(tel, tel0, s, s0, *_):
    inside = _inside(tel)
    friction = np.abs(tel["rw1.net_torque_Nm"] - tel["rw1.motor_torque_Nm"])[inside]
    friction0 = np.abs(tel0["rw1.net_torque_Nm"] - tel0["rw1.motor_torque_Nm"])[inside]
    assert np.median(friction) > 5.0 * np.median(friction0)


def _wheel_speed(scene):
    w = scene.devices["rw1"].host.latest_speed
    return float(w), w.valid


def _check_speed_sensor(tel, tel0, s, s0, extra, extra0):
    # A dead tachometer: the flight code gets speed 0 flagged invalid while the rotor turns on (the truth's speed).
    assert extra == (0.0, False) and extra0[1] and abs(extra0[0]) > 1.0
    assert abs(tel["rw1.speed_rad_s"][-1]) > 1.0


def _check_sun_head(tel, tel0, s, s0, *_):
    inside = _inside(tel)
    assert np.all(tel["css.currents"][inside, 2] == 0.0)
    assert np.array_equal(tel["css.currents"][inside, :2], tel0["css.currents"][inside, :2])


def _check_coil_open(tel, tel0, s, s0, *_):
    inside = _inside(tel)
    assert np.all(tel["mtq.dipole_B"][inside, 0] == 0.0) and np.any(tel0["mtq.dipole_B"][inside, 0] != 0.0)


def _check_coil_reversed(tel, tel0, s, s0, *_):
    inside = _inside(tel) & (tel["dipole_cmd_B"][:, 0] != 0.0)
    assert inside.any()
    assert np.all(np.sign(tel["mtq.dipole_B"][inside, 0]) == -np.sign(tel["dipole_cmd_B"][inside, 0]))


def _check_coil_stuck(tel, tel0, s, s0, *_):
    x = np.abs(tel["mtq.dipole_B"][_inside(tel), 0])
    assert np.all(x == x.max()) and x.max() > 0.0


def _check_cage_pair(tel, tel0, s, s0, *_):
    assert np.all(tel["cage.currents"][_inside(tel), 0] == 0.0)


def _check_mag_bias(tel, tel0, s, s0, *_):
    d = (tel["mtq.mag_S"] - tel0["mtq.mag_S"])[_inside(tel, 0.3)]
    assert np.allclose(d[:, 1], 1e-6, atol=5e-9)


#: Faults left on until the run ends, so their effect is still there for the check at the end.
UNTIL_THE_END = ("clock_jump", "clock_drift", "wheel_speed_sensor_failure")

CASES = [
    ("frame_drop", "acquisition", "imu", {"probability": 0.5}, _check_drop, None),
    ("frame_burst_drop", "acquisition", "imu", {"frames": 5}, _check_drop, None),
    ("bit_error", "acquisition", "imu", {"probability": 0.5}, _check_bits, None),
    ("frame_truncated", "acquisition", "imu", {"probability": 0.5}, _check_truncated, None),
    ("frame_delay", "acquisition", "imu", {"latency_s": 0.5}, _check_late, None),
    ("frame_jitter", "acquisition", "imu", {"jitter_max_s": 0.3}, _check_late, None),
    ("frame_reorder", "acquisition", "imu", {"probability": 0.5}, _check_reorder, None),
    ("frame_duplicate", "acquisition", "imu", {"probability": 0.5}, _check_duplicate, None),
    ("babble", "acquisition", "imu", {"frames_per_s": 200.0}, _check_babble, None),
    ("silence", "acquisition", "imu", {}, _check_silence, None),
    ("can_error_frame", "acquisition", "rw1", {"probability": 0.5}, _check_error_frames, None),
    ("reboot", "acquisition", "imu", {"boot_s": 1.0}, _check_reboot, None),
    ("clock_jump", "acquisition", "imu", {"jump_s": 2.0}, _check_jump, _time_us),
    ("clock_drift", "acquisition", "imu", {"drift_ppm": 1000.0}, _check_drift, _time_us),
    ("tracker_blinded", "pointing_star_tracker", "st", {}, _check_blinded, None),
    ("tracker_lost", "pointing_star_tracker", "st", {}, _check_blinded, None),
    ("tracker_misidentified", "pointing_star_tracker", "st", {"angle_deg": 1.0}, _check_misid, None),
    ("tracker_slow", "pointing_star_tracker", "st", {"latency_s": 0.5}, _check_slow, None),
    ("wheel_seized", "acquisition", "rw1", {}, _check_seized, None),
    ("wheel_motor_off", "acquisition", "rw1", {}, _check_motor_off, None),
    ("wheel_torque_loss", "acquisition", "rw1", {"lost_fraction": 0.5}, _check_torque_loss, None),
    ("wheel_friction_rise", "acquisition", "rw1", {"factor": 20.0}, _check_friction, None),
    ("wheel_speed_sensor_failure", "acquisition", "rw1", {}, _check_speed_sensor, _wheel_speed),
    ("dead_axis", "acquisition", "css", {"axis": 2}, _check_sun_head, None),
    ("coil_open", "detumble", "mtq", {"axis": "x"}, _check_coil_open, None),
    ("coil_reversed", "detumble", "mtq", {"axis": "x"}, _check_coil_reversed, None),
    ("coil_stuck_on", "detumble", "mtq", {"axis": "x"}, _check_coil_stuck, None),
    ("bias_step", "detumble", "mtq", {"bias_T": [0.0, 1e-6, 0.0]}, _check_mag_bias, None),
    ("cage_coil_failure", "detumble_cage", "cage", {"axis": 0}, _check_cage_pair, None),
]


@pytest.mark.parametrize("ftype, scene_name, device, params, check, keep", CASES, ids=[c[0] for c in CASES])
def test_each_fault_type_acts_through_a_run(tmp_path, nominal, ftype, scene_name, device, params, check, keep):
    tel0, s0, extra0 = nominal(scene_name, keep)
    fault = {"name": "f", "device": device, "type": ftype, "at_s": T0, **params}
    if not FAULT_TYPES[ftype].instant and ftype not in UNTIL_THE_END:
        fault["duration_s"] = T1 - T0
    tel, s, extra = _run(tmp_path, scene_name, [fault], ftype, keep)
    before = tel["t_s"] < T0
    for col in tel:  # until the fault starts, the same bits in every column
        assert np.array_equal(tel[col][before], tel0[col][before], equal_nan=True), col
    check(tel, tel0, s, s0, extra, extra0)


def test_the_cases_cover_the_fault_types():
    # The measurement faults' own closed forms are in test_faults.py; the stimulator faults in
    # test_stimulus_faults.py.
    covered = {c[0] for c in CASES} | {"stuck", "bias_drift", "scale_factor", "noise_increase", "saturation",
                                        "screen_wrong_attitude", "cage_field_step"}
    assert covered == set(FAULT_TYPES)
