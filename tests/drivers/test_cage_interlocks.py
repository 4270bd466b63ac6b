"""Acceptance of the cage emulator's interlocks, by an independent Modbus client: pymodbus's own
``ModbusTcpClient`` writing and reading raw registers at the addresses and scales of
``docs/cage_register_map.md`` (copied below by hand, not taken from our codec; a test checks the
copy against the document). Over-limit currents, slew beyond the limit, a stopped heartbeat, a
polarity flip under current and an over-temperature are each held, and the registers say why.

The emulator runs in sim time (``clock=None``) and the test steps it, so every check is exact and
no test waits on the wall clock, except the one that shows the watchdog in real time.
"""

from __future__ import annotations

import re
import threading
import time
from pathlib import Path

import pytest
from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ModbusIOException

from drivers.cage.emulator import CageEmulator
from drivers.cage.model import CageConfig

DOC = Path(__file__).resolve().parents[2] / "docs" / "cage_register_map.md"

# Holding registers, from the document.
HR_ENABLE, HR_POLARITY, HR_SETPOINT_X, HR_HEARTBEAT = 0, 1, 2, 5
SETPOINT_A_PER_COUNT = 1e-4
# Input registers, from the document.
IR_CURRENT_X, IR_STATUS, IR_INTERLOCKS, IR_LAST, IR_LAST_AXIS = 0, 14, 15, 16, 17
IR_CURRENT_LIMIT_EVENTS, IR_SLEW_EVENTS, IR_HEARTBEAT_TRIPS, IR_POLARITY_HOLDS, IR_OVERTEMP_TRIPS = 18, 19, 20, 21, 22
IR_REFUSED, IR_TEMP_X, IR_CURRENT_LIMIT = 23, 24, 30
CURRENT_A_PER_COUNT, TEMP_C_PER_COUNT = 1e-6, 0.01
STATUS_OUTPUT_ON, STATUS_RELAY_NEG_X, STATUS_DEAD_TIME_X = 1 << 0, 1 << 2, 1 << 5
IL_HEARTBEAT_LOST, IL_OVER_TEMPERATURE, IL_CURRENT_LIMIT_X, IL_SLEW_LIMIT_X, IL_POLARITY_HELD_X = (
    1 << 0, 1 << 1, 1 << 2, 1 << 5, 1 << 8)
LAST = {"none": 0, "current_limit": 1, "slew_limit": 2, "heartbeat_lost": 3, "polarity_held": 4,
        "over_temperature": 5}
AXIS_ALL, AXIS_X = 0, 1


def test_the_addresses_used_here_are_those_of_the_document():
    text = DOC.read_text()
    rows = {name: addr for addr, name in re.findall(r"^\| (\d+)(?:-\d+)? \| `(\w+)` \|", text, flags=re.M)}
    assert {k: int(v) for k, v in rows.items() if k in {
        "output_enable", "polarity_request", "current_setpoint_x_A", "heartbeat"}} == {
        "output_enable": HR_ENABLE, "polarity_request": HR_POLARITY, "current_setpoint_x_A": HR_SETPOINT_X,
        "heartbeat": HR_HEARTBEAT}
    expected_inputs = {"current_x_A": IR_CURRENT_X, "status": IR_STATUS, "interlocks": IR_INTERLOCKS,
                       "last_interlock": IR_LAST, "last_interlock_axis": IR_LAST_AXIS,
                       "current_limit_events": IR_CURRENT_LIMIT_EVENTS, "slew_limit_events": IR_SLEW_EVENTS,
                       "heartbeat_trips": IR_HEARTBEAT_TRIPS, "polarity_holds": IR_POLARITY_HOLDS,
                       "over_temperature_trips": IR_OVERTEMP_TRIPS, "refused_writes": IR_REFUSED,
                       "coil_temperature_x_C": IR_TEMP_X, "current_limit_A": IR_CURRENT_LIMIT}
    assert {k: int(rows[k]) for k in expected_inputs} == expected_inputs
    assert "bits: 0 heartbeat_lost, 1 over_temperature, 2 current_limit_x, 3 current_limit_y, 4 current_limit_z, " \
           "5 slew_limit_x, 6 slew_limit_y, 7 slew_limit_z, 8 polarity_held_x" in text
    assert "values: 0 none, 1 current_limit, 2 slew_limit, 3 heartbeat_lost, 4 polarity_held, 5 over_temperature" \
           in text
    assert "bits: 0 output_on, 1 field_valid, 2 relay_negative_x, 3 relay_negative_y, 4 relay_negative_z, " \
           "5 dead_time_x" in text
    assert "| `current_setpoint_x_A` | u16 | 0.0001 |" in text and "| `current_x_A` | i32 | 1e-06 |" in text


@pytest.fixture(autouse=True)
def no_server_thread_left():
    yield
    assert not [t for t in threading.enumerate() if t.name.startswith("cage-emulator")]


class Bench:
    """The emulator in sim time on 127.0.0.1 and a raw pymodbus client; ``t`` is sim time."""

    def __init__(self, config: CageConfig | None = None) -> None:
        self.emu = CageEmulator(config, clock=None)
        _, port = self.emu.serve_tcp("127.0.0.1", 0)
        self.client = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
        assert self.client.connect()
        self.t = 0.0
        self.hb = 0

    def close(self) -> None:
        self.client.close()
        self.emu.close()

    def write(self, address: int, values: list[int]) -> None:
        rsp = self.client.write_registers(address, values, device_id=1)
        assert not rsp.isError(), rsp

    def ir(self, address: int, count: int = 1) -> list[int]:
        rsp = self.client.read_input_registers(address, count=count, device_id=1)
        assert not rsp.isError(), rsp
        return rsp.registers

    def current_x(self) -> float:
        hi, lo = self.ir(IR_CURRENT_X, 2)
        raw = hi << 16 | lo
        return (raw - (1 << 32) if raw >= 1 << 31 else raw) * CURRENT_A_PER_COUNT

    def heartbeat(self) -> None:
        self.hb += 1
        self.write(HR_HEARTBEAT, [self.hb])

    def enable(self) -> None:
        self.heartbeat()
        self.write(HR_ENABLE, [1])

    def advance(self, seconds: float, heartbeat: bool = True, every: float = 0.1) -> None:
        end = self.t + seconds
        while self.t < end - 1e-12:
            self.t = min(self.t + every, end)
            self.emu.step(self.t)
            if heartbeat:
                self.heartbeat()


@pytest.fixture
def bench():
    b = Bench()
    yield b
    b.close()


def test_over_limit_current_is_held_at_the_limit_and_the_register_says_why(bench):
    limit = bench.ir(IR_CURRENT_LIMIT)[0] * SETPOINT_A_PER_COUNT
    assert limit == pytest.approx(4.0)
    bench.enable()
    bench.write(HR_SETPOINT_X, [60000])  # 6.0 A, within what the register carries, above the limit
    assert bench.ir(IR_INTERLOCKS)[0] & IL_CURRENT_LIMIT_X
    assert bench.ir(IR_LAST, 2) == [LAST["current_limit"], AXIS_X]  # (then the ramp engages the slew limit)
    bench.advance(2.0)
    assert bench.current_x() == pytest.approx(limit, abs=1e-6)
    assert bench.ir(IR_INTERLOCKS)[0] & IL_CURRENT_LIMIT_X
    assert bench.ir(IR_CURRENT_LIMIT_EVENTS)[0] == 1
    assert bench.client.read_holding_registers(HR_SETPOINT_X, count=1, device_id=1).registers == [60000]
    bench.write(HR_SETPOINT_X, [65535])  # the largest the register carries: still the limit
    bench.advance(0.5)
    assert bench.current_x() == pytest.approx(limit, abs=1e-6)
    bench.write(HR_SETPOINT_X, [20000])  # back within the limit: the flag clears, the output follows
    bench.advance(1.0)
    assert not bench.ir(IR_INTERLOCKS)[0] & IL_CURRENT_LIMIT_X
    assert bench.current_x() == pytest.approx(2.0, abs=1e-6)


def test_a_step_beyond_the_slew_limit_is_ramped_and_the_register_says_why(bench):
    slew = bench.ir(31)[0] * 1e-3  # slew_limit_A_s, 1 mA/s per count
    assert slew == pytest.approx(10.0)
    bench.enable()
    bench.write(HR_SETPOINT_X, [30000])  # 0 -> 3 A at once
    previous, t_prev = 0.0, 0.0
    ramping_seen = False
    for _ in range(40):
        bench.advance(0.01, every=0.01)
        i = bench.current_x()
        assert abs(i - previous) <= slew * (bench.t - t_prev) + 2e-6  # never faster than the slew limit
        if i < 3.0 - 1e-3:
            assert bench.ir(IR_INTERLOCKS)[0] & IL_SLEW_LIMIT_X
            ramping_seen = True
        previous, t_prev = i, bench.t
    assert ramping_seen and bench.current_x() == pytest.approx(3.0, abs=1e-5)  # 0.3 s at 10 A/s
    assert not bench.ir(IR_INTERLOCKS)[0] & IL_SLEW_LIMIT_X
    assert bench.ir(IR_SLEW_EVENTS)[0] == 1
    assert bench.ir(IR_LAST, 2) == [LAST["slew_limit"], AXIS_X]


def test_a_stopped_heartbeat_switches_the_outputs_off_and_latches(bench):
    bench.enable()
    bench.write(HR_SETPOINT_X, [20000])
    bench.advance(1.0)
    assert bench.ir(IR_STATUS)[0] & STATUS_OUTPUT_ON
    bench.advance(0.45, heartbeat=False, every=0.05)  # still within the 0.5 s timeout
    assert bench.ir(IR_STATUS)[0] & STATUS_OUTPUT_ON
    bench.advance(0.1, heartbeat=False, every=0.05)
    assert not bench.ir(IR_STATUS)[0] & STATUS_OUTPUT_ON
    assert bench.client.read_holding_registers(HR_ENABLE, count=1, device_id=1).registers == [0]
    assert bench.ir(IR_INTERLOCKS)[0] & IL_HEARTBEAT_LOST
    assert bench.ir(IR_LAST, 2) == [LAST["heartbeat_lost"], AXIS_ALL]
    assert bench.ir(IR_HEARTBEAT_TRIPS)[0] == 1
    bench.advance(0.3, heartbeat=False)
    assert abs(bench.current_x()) < 1e-6  # decayed through the coil at V = 0
    # enabling again without a new heartbeat is held: still off, still latched
    bench.write(HR_ENABLE, [1])
    bench.advance(0.1, heartbeat=False)
    assert not bench.ir(IR_STATUS)[0] & STATUS_OUTPUT_ON and bench.ir(IR_INTERLOCKS)[0] & IL_HEARTBEAT_LOST
    # a new heartbeat, then enable: on again, latch cleared
    bench.enable()
    bench.advance(0.5)
    assert bench.ir(IR_STATUS)[0] & STATUS_OUTPUT_ON and not bench.ir(IR_INTERLOCKS)[0] & IL_HEARTBEAT_LOST
    assert bench.current_x() == pytest.approx(2.0, abs=1e-5)


def test_rewriting_the_same_heartbeat_value_does_not_feed_the_watchdog(bench):
    bench.enable()
    for _ in range(10):
        bench.t += 0.1
        bench.emu.step(bench.t)
        bench.write(HR_HEARTBEAT, [bench.hb])  # a host stuck replaying its last write
    assert bench.ir(IR_INTERLOCKS)[0] & IL_HEARTBEAT_LOST


def test_a_polarity_flip_under_current_is_held_until_zero_current_and_dead_time(bench):
    bench.enable()
    bench.write(HR_SETPOINT_X, [20000])
    bench.advance(1.0)
    assert bench.current_x() == pytest.approx(2.0, abs=1e-5)
    bench.write(HR_POLARITY, [1])  # flip x under 2 A
    assert not bench.ir(IR_STATUS)[0] & STATUS_RELAY_NEG_X  # the relay has not moved
    assert bench.ir(IR_INTERLOCKS)[0] & IL_POLARITY_HELD_X
    assert bench.ir(IR_LAST, 2) == [LAST["polarity_held"], AXIS_X]
    assert bench.ir(IR_POLARITY_HOLDS)[0] == 1
    trace = []
    for k in range(600):
        bench.advance(0.001, heartbeat=k % 100 == 0, every=0.001)
        status = bench.ir(IR_STATUS)[0]
        trace.append((bench.t, bench.current_x(), bool(status & STATUS_RELAY_NEG_X), bool(status & STATUS_DEAD_TIME_X)))
    first_negative_relay = next(k for k, s in enumerate(trace) if s[2])
    before = trace[:first_negative_relay]
    assert all(i >= 0.0 for _, i, _, _ in before)  # never a negative current before the relay switched
    assert abs(before[-1][1]) < 1e-3  # switched at (below) the zero-current threshold
    dead = [t for t, _, _, d in trace if d]
    assert dead and dead[-1] - dead[0] >= 0.02 - 0.002  # the dead time, with the output held off
    assert all(abs(i) < 1e-3 for t, i, _, d in trace if d)
    assert trace[-1][1] == pytest.approx(-2.0, abs=1e-5) and trace[-1][2]
    assert not bench.ir(IR_INTERLOCKS)[0] & IL_POLARITY_HELD_X


def test_over_temperature_switches_off_and_holds_until_cooled():
    config = CageConfig(thermal_time_constant_s=5.0, thermal_resistance_K_W=1.0, temperature_trip_C=60.0,
                        temperature_reset_C=45.0)
    bench = Bench(config)
    try:
        bench.enable()
        bench.write(HR_SETPOINT_X, [40000])  # 4 A into 4.9 ohm: 78 W, steady 100 degC
        for _ in range(200):
            bench.advance(0.1)
            if not bench.ir(IR_STATUS)[0] & STATUS_OUTPUT_ON:
                break
        assert bench.ir(IR_INTERLOCKS)[0] & IL_OVER_TEMPERATURE
        assert bench.ir(IR_LAST, 2) == [LAST["over_temperature"], AXIS_ALL]
        assert bench.ir(IR_OVERTEMP_TRIPS)[0] == 1
        temp = bench.ir(IR_TEMP_X)[0] * TEMP_C_PER_COUNT
        assert 59.0 < temp < 61.0  # tripped at 60 degC, cooling since (at most 0.1 s)
        bench.write(HR_ENABLE, [1])  # still hot: held off
        bench.advance(0.1)
        assert not bench.ir(IR_STATUS)[0] & STATUS_OUTPUT_ON
        bench.advance(10.0)  # cools towards 22 degC with tau 5 s: below 45 degC
        assert bench.ir(IR_TEMP_X)[0] * TEMP_C_PER_COUNT < 45.0
        bench.enable()
        bench.advance(0.1)
        assert bench.ir(IR_STATUS)[0] & STATUS_OUTPUT_ON and not bench.ir(IR_INTERLOCKS)[0] & IL_OVER_TEMPERATURE
    finally:
        bench.close()


def test_requests_the_map_does_not_allow_get_modbus_exceptions_and_change_nothing(bench):
    bench.enable()
    rsp = bench.client.write_registers(HR_POLARITY, [8, 30000, 0, 0, 99], device_id=1)  # polarity 8: no such bit
    assert rsp.isError() and rsp.exception_code == 3
    assert bench.client.read_holding_registers(0, count=6, device_id=1).registers == [1, 0, 0, 0, 0, bench.hb]
    rsp = bench.client.write_register(HR_ENABLE, 2, device_id=1)
    assert rsp.isError() and rsp.exception_code == 3
    rsp = bench.client.write_register(100, 1, device_id=1)
    assert rsp.isError() and rsp.exception_code == 2
    assert bench.ir(IR_REFUSED)[0] == 3
    rsp = bench.client.read_input_registers(1, count=2, device_id=1)  # splits current_x_A
    assert rsp.isError() and rsp.exception_code == 2
    rsp = bench.client.read_coils(0, count=1, device_id=1)
    assert rsp.isError() and rsp.exception_code == 1
    assert bench.emu.counters["rejected"] == 5


def test_another_unit_id_gets_no_answer(bench):
    bench.client.comm_params.timeout_connect = 0.3
    with pytest.raises(ModbusIOException):
        bench.client.read_input_registers(0, count=2, device_id=7)
    assert bench.emu.counters["ignored_other_id"] == 1
    assert len(bench.ir(0, 2)) == 2  # the link is still fine for the cage's own id


def test_in_wall_time_the_watchdog_trips_without_any_request():
    # Runs on time.monotonic: the heartbeat, the enable and the status read must fit in the timeout, on a loaded
    # machine too; the 5 s deadline below still shows the trip comes from the server's own tick.
    emu = CageEmulator(CageConfig(heartbeat_timeout_s=1.0))
    _, port = emu.serve_tcp()
    client = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
    try:
        assert client.connect()
        client.write_registers(HR_HEARTBEAT, [1], device_id=1)
        client.write_registers(HR_ENABLE, [1], device_id=1)
        assert client.read_input_registers(IR_STATUS, count=1, device_id=1).registers[0] & STATUS_OUTPUT_ON
        deadline = time.monotonic() + 5.0
        while emu.model.output_on and time.monotonic() < deadline:  # the server's own tick trips it
            time.sleep(0.05)
        assert not emu.model.output_on
        assert client.read_input_registers(IR_INTERLOCKS, count=1, device_id=1).registers[0] & IL_HEARTBEAT_LOST
    finally:
        client.close()
        emu.close()
    assert not [t for t in threading.enumerate() if t.name.startswith("cage-emulator")]
