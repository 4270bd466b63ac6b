"""The cage host driver against the emulator, over Modbus TCP on 127.0.0.1 and Modbus RTU on a
socat pty pair; the calibration (least squares, storage) and the driver's errors."""

from __future__ import annotations

import os
import subprocess
import threading
import time

import numpy as np
import pytest

from drivers.cage.calibration import CageCalibration, default_points, fit_calibration, run_calibration
from drivers.cage.emulator import CageEmulator
from drivers.cage.host import CageHost, parse_url
from drivers.cage.model import CageConfig
from drivers.errors import ConnectError, DeviceTimeoutError, DriverError, EncodeError, ProtocolError
from tests.oracles import require_tool


@pytest.fixture(autouse=True)
def no_server_thread_left():
    yield
    assert not [t for t in threading.enumerate() if t.name.startswith("cage-emulator")]


class SimTime:
    """Sim time for an emulator built with clock=None: ``wait(s)`` steps it."""

    def __init__(self, emu: CageEmulator) -> None:
        self.emu = emu
        self.t = 0.0

    def __call__(self, seconds: float) -> None:
        self.t += seconds
        self.emu.step(self.t)


@pytest.fixture
def rig():
    emu = CageEmulator(clock=None, rng=3)
    _, port = emu.serve_tcp()
    host = CageHost.open(f"tcp://127.0.0.1:{port}", timeout_s=2.0)
    yield emu, host, SimTime(emu)
    host.close()
    emu.close()


def test_command_currents_take_field_and_status(rig):
    emu, host, wait = rig
    st = host.enable()
    assert st.output_on and not st.interlocks
    host.command_currents((1.2, -0.4, 0.0))
    wait(0.5)
    sample = host.take_field()
    assert sample.valid and sample.output_on and not sample.interlocks
    assert sample.currents_A == pytest.approx((1.2, -0.4, 0.0), abs=2e-6)
    assert sample.t_s == pytest.approx(0.5, abs=emu.config.mag_period_s + 1e-9)
    truth = emu.cage_field_T()
    assert np.array(sample.b_T) == pytest.approx(truth, abs=5 * emu.config.mag_noise_T)
    st = host.status()
    assert st.setpoints_A == pytest.approx((1.2, 0.4, 0.0))
    assert st.polarity_request_negative == (False, True, False) == st.relay_negative
    assert st.limits["current_limit_A"] == pytest.approx(4.0)
    assert st.voltages_V[0] == pytest.approx(1.2 * emu.config.resistance_ohm[0], abs=2e-3)
    assert st.values["map_version"] == 256
    assert host.counters["sent"] == host.counters["received"] == emu.counters["received"] >= 5


def test_calibration_recovers_the_cage_and_command_field_reproduces_a_field(rig, tmp_path):
    emu, host, wait = rig
    host.enable()
    cal = run_calibration(host, wait=wait, settle_s=0.4, samples=8, bench="lab-a")
    k_true, b_true = np.array(emu.config.coil_T_per_A), np.array(emu.config.lab_field_T)
    assert np.array(cal.coil_T_per_A) == pytest.approx(k_true, abs=5e-9)  # 0.01 % of 50 uT/A
    assert np.array(cal.lab_field_T) == pytest.approx(b_true, abs=3e-9)
    assert cal.residual_rms_T < 3e-9 and cal.n_points == 15  # the noise, 5 nT / sqrt(8)
    path = cal.save(CageCalibration.path_for("lab-a", tmp_path))
    assert path == tmp_path / "lab-a" / "cage_calibration.json"
    host.calibration = CageCalibration.load(path)
    b_cmd = np.array([25e-6, -12e-6, -38e-6])
    currents = host.command_field(b_cmd)
    for _ in range(10):
        wait(0.1)
        host.heartbeat()
    # set points carry 0.1 mA: half a count is 2.7 nT at 53 uT/A; plus the calibration's own error
    assert np.array(host.take_field().currents_A) == pytest.approx(currents, abs=5e-5 + 2e-6)
    assert emu.cage_field_T() == pytest.approx(b_cmd, abs=8e-9)


def test_fit_is_exact_on_noiseless_data_and_refuses_what_it_cannot_determine():
    rng = np.random.default_rng(0)
    k = np.diag([5e-5, 4e-5, 6e-5]) + rng.normal(0, 5e-7, (3, 3))
    b0 = np.array([2e-5, -3e-6, 4e-5])
    pts = default_points(1.5)
    cal = fit_calibration(pts, pts @ k.T + b0)
    assert np.array(cal.coil_T_per_A) == pytest.approx(k, rel=1e-10, abs=1e-18)
    assert np.array(cal.lab_field_T) == pytest.approx(b0, rel=1e-10)
    assert cal.currents_for(cal.field_for([0.3, -1.0, 2.0])) == pytest.approx([0.3, -1.0, 2.0], rel=1e-10)
    with pytest.raises(ValueError, match="at least 4"):
        fit_calibration(pts[:3], pts[:3] @ k.T + b0)
    flat = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [-1, 0, 0]], dtype=float)  # z never driven
    with pytest.raises(ValueError, match="condition number"):
        fit_calibration(flat, flat @ k.T + b0)
    with pytest.raises(ValueError, match="bench"):
        CageCalibration.path_for("../x", "/tmp")


def test_the_exact_calibration_of_an_emulated_cage_inverts_its_field():
    cfg = CageConfig()
    cal = CageCalibration.from_config(cfg)
    i = cal.currents_for([10e-6, 20e-6, -30e-6])
    assert np.array(cfg.coil_T_per_A) @ i + np.array(cfg.lab_field_T) == pytest.approx([10e-6, 20e-6, -30e-6],
                                                                                         abs=1e-18)


def test_a_broken_calibration_file_is_refused_naming_it(tmp_path):
    p = tmp_path / "c.json"
    p.write_text('{"kind": "something else"}')
    with pytest.raises(ValueError, match="not a cage calibration"):
        CageCalibration.load(p)
    p.write_text("{")
    with pytest.raises(ValueError, match="cannot be read"):
        CageCalibration.load(p)


def test_enable_names_the_interlock_that_keeps_the_cage_off():
    cfg = CageConfig(thermal_time_constant_s=1.0, thermal_resistance_K_W=2.0)
    emu = CageEmulator(cfg, clock=None)
    _, port = emu.serve_tcp()
    wait = SimTime(emu)
    try:
        with CageHost.open(f"tcp://127.0.0.1:{port}") as host:
            host.enable()
            host.command_currents((4.0, 0.0, 0.0))
            while host.take_field().output_on and wait.t < 10.0:
                wait(0.05)
                host.heartbeat()
            with pytest.raises(DriverError, match="over_temperature"):
                host.enable()
    finally:
        emu.close()


def test_driver_errors_name_the_device_and_the_problem(rig):
    emu, host, _ = rig
    with pytest.raises(DriverError, match="needs a calibration"):
        host.command_field((0.0, 0.0, 0.0))
    with pytest.raises(EncodeError, match="current y"):
        host.command_currents((0.0, 7.0, 0.0))
    with pytest.raises(EncodeError, match="current z"):
        host.command_currents((0.0, 0.0, float("nan")))
    with pytest.raises(ProtocolError, match="exception 2 .illegal address.") as exc:
        host.read_registers("input", 1, 2)
    assert exc.value.frame_hex  # the exception response, in hex
    assert host.counters["rejected"] == 1
    host.device_id = 9
    host.client.comm_params.timeout_connect = 0.3
    with pytest.raises(DeviceTimeoutError, match="no answer"):
        host.take_field()
    host.close()
    host.close()  # idempotent
    with pytest.raises(DriverError, match="closed"):
        host.take_field()


def test_urls_and_connect_errors():
    assert parse_url("tcp://127.0.0.1:5020") == ("tcp", "127.0.0.1", 5020)
    assert parse_url("/dev/ttyUSB0") == ("rtu", "/dev/ttyUSB0", None)
    with pytest.raises(ValueError, match="tcp://HOST:PORT"):
        parse_url("tcp://localhost")
    emu = CageEmulator(clock=None)
    _, port = emu.serve_tcp()
    emu.close()  # nothing listens there any more
    with pytest.raises(ConnectError, match=f"127.0.0.1:{port}"):
        CageHost.open(f"tcp://127.0.0.1:{port}", timeout_s=0.5)


def test_an_emulator_cannot_serve_a_port_in_use():
    a = CageEmulator(clock=None)
    _, port = a.serve_tcp()
    b = CageEmulator(clock=None)
    try:
        with pytest.raises(ConnectError, match=str(port)):
            b.serve_tcp("127.0.0.1", port)
    finally:
        a.close()
        b.close()


def test_modbus_rtu_over_a_socat_pty_pair(tmp_path):
    require_tool("socat", "socat")
    a, b = tmp_path / "cage-dev", tmp_path / "cage-host"
    socat = subprocess.Popen(["socat", f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    emu = None
    try:
        deadline = time.monotonic() + 5.0
        while not (os.path.exists(a) and os.path.exists(b)) and time.monotonic() < deadline:
            time.sleep(0.02)
        assert a.exists() and b.exists(), "socat did not create its pty pair"
        emu = CageEmulator(clock=None)
        emu.serve_rtu(str(a), baudrate=115200)
        wait = SimTime(emu)
        with CageHost.open(str(b), baudrate=115200, timeout_s=2.0) as host:
            host.enable()
            host.command_currents((-0.5, 0.25, 1.0))
            wait(0.5)
            sample = host.take_field()
            assert sample.currents_A == pytest.approx((-0.5, 0.25, 1.0), abs=2e-6)
            assert sample.valid
            assert host.status().relay_negative == (True, False, False)
        assert emu.counters["received"] >= 5 and emu.counters["rejected"] == 0
    finally:
        if emu is not None:
            emu.close()
        socat.terminate()
        socat.wait(5)
