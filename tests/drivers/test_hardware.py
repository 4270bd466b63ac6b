"""The same contract against real devices, when a bench names them (skipped otherwise).

    STAND_STAR_TRACKER_URL=/dev/ttyUSB0 pytest -m hardware
    STAND_MAGNETORQUER_URL=socketcan:can0 pytest -m hardware
    STAND_GYRO_URL=/dev/ttyUSB1 STAND_SUN_SENSOR_URL=/dev/ttyUSB2 pytest -m hardware
    STAND_REACTION_WHEEL_URL=socketcan:can0:0 pytest -m hardware     (interface:channel:wheel number)
    STAND_CAGE_URL=tcp://192.0.2.10:502 pytest -m hardware      (or a serial port for Modbus RTU)

A device emulated elsewhere (`stand emulate ...` on a pty, a socat link or another machine) is a
fine stand-in: these tests only speak the protocol.
"""

import math
import os

import pytest

pytestmark = pytest.mark.hardware


def _url(name: str) -> str:
    url = os.environ.get(name)
    if not url:
        pytest.skip(f"{name} is not set: no real device to test against")
    return url


def test_star_tracker_answers_a_solution_request():
    from drivers.star_tracker.host import StarTrackerHost

    with StarTrackerHost(_url("STAND_STAR_TRACKER_URL"), timeout_s=2.0) as host:
        status = host.request_status()
        sol = host.request_solution()
    assert status.mode in ("BOOT", "LOST_IN_SPACE", "TRACKING")
    assert abs(math.sqrt(sum(x * x for x in sol.q_TN)) - 1.0) < 1e-6 or not sol.valid
    assert host.counters["rejected_crc"] == 0


def test_magnetorquer_board_sends_magnetometer_samples():
    from drivers.magnetorquer.host import MagnetorquerBoard

    interface, _, channel = _url("STAND_MAGNETORQUER_URL").partition(":")
    with MagnetorquerBoard.open(interface, channel) as board:
        sample = board.read_sample(timeout_s=2.0)
    assert all(abs(b) < 100e-6 for b in sample.b_T)  # an Earth-like field, not garbage


def test_gyro_streams_rate_datagrams():
    from drivers.gyro.host import GyroHost

    with GyroHost(_url("STAND_GYRO_URL"), timeout_s=2.0) as gyro:
        a = gyro.read_rate()
        b = gyro.read_rate()
    assert (b.seq - a.seq) % 256 >= 1 and b.time_us > a.time_us
    assert all(abs(w) < 0.2 for w in b.omega_rad_s) or not b.valid  # a gyro on a bench sits nearly still
    assert gyro.counters["rejected_crc"] == 0


def test_sun_sensor_answers_a_sample_request():
    from drivers.sun_sensor.host import SunSensorHost

    with SunSensorHost(_url("STAND_SUN_SENSOR_URL"), timeout_s=2.0) as sun:
        sample = sun.request_sun()
    assert sample.time_us >= 0 and sun.counters["rejected_crc"] == 0


def test_reaction_wheel_reports_its_speed_and_acknowledges_a_zero_torque():
    from drivers.reaction_wheel.host import ReactionWheelHost

    interface, _, rest = _url("STAND_REACTION_WHEEL_URL").partition(":")
    channel, _, wheel = rest.partition(":")
    with ReactionWheelHost.open(interface, channel, wheel=int(wheel or 0)) as rw:
        seq = rw.command_torque(0.0, timeout_s=1.0)  # zero torque: safe on any bench
        tlm = rw.read_speed(timeout_s=2.0)
        for _ in range(20):
            if rw.latest_status is not None and rw.latest_status.seq_ack == seq:
                break
            rw.read_speed(timeout_s=2.0)
    assert abs(tlm.speed_rad_s) < 2000.0
    assert rw.latest_status is not None and rw.latest_status.seq_ack == seq
def test_cage_reports_its_map_version_limits_and_field_without_driving_the_coils():
    from drivers.cage.host import CageHost

    with CageHost.open(_url("STAND_CAGE_URL"), timeout_s=2.0) as cage:
        st = cage.status()
    assert st.values["map_version"] == 256  # map 1.0
    assert all(v > 0 for k, v in st.limits.items() if not k.startswith("temperature"))
    assert st.field.valid and all(abs(b) < 1e-3 for b in st.field.b_T)
