"""Telemetry observes a device's link beside the flight code, never through the flight code's own driver.

For the gyro, the sun sensor, the star tracker and the reaction wheel: a flight code that never reads its driver
still gets telemetry of what the device sent, and the telemetry (``row``, ``activity`` and what ``publish`` keeps
for them) reads nothing the driver decoded or counted. The stand may still move bytes through the host's framing
layer (``poll``, as the flight code's next call would); what it records comes from the observer on that layer.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from types import SimpleNamespace

import numpy as np
import pytest

from stand import devices, scenario
from stand.compose import build
from stand.devices import BuildContext
from stand.scenario import SCENARIO_DIR, Table

_channel = itertools.count()

#: What the telemetry must never read of the flight code's host: what it decoded and kept, and the take/read calls
#: that hand it to the flight code.
FORBIDDEN_PREFIXES = ("latest_", "last_", "take_", "read_", "request_", "wait_", "_taken", "_solution_taken",
                      "_returned")
#: Counters that say what the host decoded (the silence watch used them); the frame totals stay readable, as the
#: stand's settling of the in-process line compares them with what the emulator wrote.
FORBIDDEN_COUNTERS = ("samples", "solutions", "samples_lost")


class GuardedCounters(Mapping):
    def __init__(self, counters: dict):
        self._counters = counters

    def __getitem__(self, key):
        if key in FORBIDDEN_COUNTERS:
            raise AssertionError(f"the telemetry read the flight code's driver: host.counters[{key!r}]")
        return self._counters[key]

    def __iter__(self):
        return (k for k in self._counters if k not in FORBIDDEN_COUNTERS)

    def __len__(self):
        return len(self._counters) - sum(k in self._counters for k in FORBIDDEN_COUNTERS)


class GuardedHost:
    """The flight code's host as the stand may touch it: its line can be pumped, nothing it decoded can be read."""

    def __init__(self, host):
        object.__setattr__(self, "_host", host)

    def __getattr__(self, name):
        if name.startswith(FORBIDDEN_PREFIXES):
            raise AssertionError(f"the telemetry read the flight code's driver: host.{name}")
        if name == "counters":
            return GuardedCounters(self._host.counters)
        return getattr(self._host, name)

    def __setattr__(self, name, value):
        raise AssertionError(f"the telemetry changed the flight code's driver: host.{name} = {value!r}")


def _swap_host(dev, host) -> None:
    # A device whose host is a property attaches its observer when the host is set: put the guard beside it.
    if isinstance(getattr(type(dev), "host", None), property):
        dev._host = host
    else:
        dev.host = host


def guarded(dev):
    """Run the telemetry's side of ``dev`` with its host guarded; returns the real host."""
    real = dev.host
    _swap_host(dev, GuardedHost(real))
    return real


def make(kind: str, data: dict, truth, tracks=None, step_s: float = 0.1, wheels: dict | None = None):
    t = Table({"name": "dev", "kind": kind, **data}, "devices[0]", None)
    spec = scenario._device(t, step_s)
    ctx = BuildContext(truth, tracks or {}, None, np.random.default_rng(1), step_s, None, {}, wheels or {})
    return devices.get(kind).build(spec, ctx)


def _ticks(n: int, step_s: float = 0.1):
    return [k * step_s for k in range(n)]


def test_gyro_telemetry_is_what_the_gyro_sent_without_reading_the_flight_codes_driver():
    dev = make("gyro", {"ideal": True, "output_rate_hz": 10.0}, SimpleNamespace(w=(0.01, -0.02, 0.03)))
    try:
        real = guarded(dev)
        rows = []
        for t in _ticks(20):
            dev.publish(t)
            rows.append(dev.row())
        sent = dev.emulator.latest_rate
        assert dev.activity() == dev.emulator.counters["sent"] == 20
        _swap_host(dev, real)
        assert not any(math.isnan(x) for x in rows[0])
        assert rows[-1] == (*sent.omega_rad_s, 1.0)
        # The flight code, reading only now, gets the newest sample: the telemetry took nothing from it.
        assert real.take_rate() == sent and real.counters["samples"] == 20
    finally:
        dev.close()


def test_sun_sensor_telemetry_is_what_the_sensor_sent_without_reading_the_flight_codes_driver():
    truth = SimpleNamespace(r_N=(7.0e6, 0.0, 0.0), q=(1.0, 0.0, 0.0, 0.0))
    sun = SimpleNamespace(position_gcrs=lambda t_s: np.array([1.5e11, 2.0e10, 1.0e10]))
    dev = make("sun_sensor", {"type": "coarse", "rate_hz": 10.0}, truth, tracks={"sun": sun})
    try:
        real = guarded(dev)
        rows = []
        for t in _ticks(20):
            dev.publish(t)
            rows.append(dev.row())
        sent = dev.emulator.latest_sample
        assert dev.activity() == dev.emulator.counters["sent"] == 20
        _swap_host(dev, real)
        assert not any(math.isnan(x) for x in rows[0])
        assert rows[-1][:6] == sent.currents_A and rows[-1][6] == 1.0 and max(sent.currents_A) > 0.0
        assert real.take_sun() == sent and real.counters["samples"] == 20
    finally:
        dev.close()


def test_star_tracker_telemetry_is_what_the_tracker_sent_without_reading_the_flight_codes_driver():
    sc = scenario.load(SCENARIO_DIR / "detumble_star_tracker.toml")
    with build(sc) as scene:
        dev = scene.devices[next(d.name for d in sc.devices if d.kind == "star_tracker")]
        real = guarded(dev)
        for _ in range(40):
            dev.publish(scene.truth.t_s)
            dev.row()
            scene.truth.step()
        solutions = dev.activity()
        last = dev.row()
        _swap_host(dev, real)
        assert solutions == real.counters["solutions"] >= 5
        sol = real.take_solution()  # the flight code reads only now and gets the newest, untaken
        assert sol is not None and last[1:5] == tuple(sol.q_TN) and last[5] == float(sol.valid)


def test_wheel_activity_is_what_the_wheel_sent_without_reading_the_flight_codes_driver():
    truth = SimpleNamespace(wheel_speeds_rad_s=(50.0,))
    data = {"channel": f"test-observe-{next(_channel)}", "inertia_kg_m2": 2e-3, "max_torque_Nm": 0.01,
            "ideal": True}
    dev = make("reaction_wheel", data, truth, wheels={"dev": 0})
    try:
        real = guarded(dev)
        for t in _ticks(20):
            dev.publish(t)
            dev.receive(t)
            dev.row()
        assert dev.activity() == dev.emulator._tlm_seq == 20
        _swap_host(dev, real)
        assert real.counters["samples"] == 20
        assert real.take_speed().speed_rad_s == pytest.approx(50.0, abs=1e-3)
    finally:
        dev.close()


def test_an_observer_sees_every_good_frame_and_leaves_the_driver_as_it_was():
    """The tap on the datagram layer: the same decoded messages reach the observer and the host, a corrupt datagram
    reaches neither, and the host's counters and newest sample do not depend on the observer."""
    from drivers.framing import FrameObserver
    from drivers.gyro.codec import GyroCodec, GyroRate
    from drivers.gyro.host import GyroHost
    from drivers.serial_port import pipe_pair

    codec = GyroCodec()
    lsb = codec.rate_lsb_rad_s
    frames = [codec.encode(GyroRate((k * lsb, -k * lsb, 2 * k * lsb), True, False, False, False, False, False, k,
                                    0.0005, 1000 * k)) for k in range(5)]
    bad = bytearray(frames[2])
    bad[3] ^= 0xFF
    stream = frames[0] + frames[1] + bytes(bad) + frames[3] + frames[4]
    counters = []
    for watched in (False, True):
        a, b = pipe_pair("observe")
        host = GyroHost(b, name="gyro")
        seen = FrameObserver()
        if watched:
            host.add_observer(seen)
        a.write(stream)
        host.poll()
        counters.append((dict(host.counters), host.latest_rate))
        if watched:
            assert seen.count(GyroRate) == 4 == host.counters["samples"] and host.counters["rejected_crc"] == 1
            assert seen.latest(GyroRate) == host.latest_rate == codec.decode(frames[4])
        host.close()
        a.close()
    assert counters[0] == counters[1]


def test_a_served_emulators_observer_sees_what_went_on_the_line_and_what_came_back():
    """The tap on a served datagram emulator: what it sent, decoded as a receiver decodes it (nothing while it is
    silent), and the commands it received."""
    from drivers.framing import FrameObserver
    from drivers.gyro.codec import GyroRate, SetOutputPeriod
    from drivers.gyro.emulator import GyroEmulator, GyroEmulatorConfig
    from drivers.gyro.host import GyroHost
    from drivers.serial_port import pipe_pair

    a, b = pipe_pair("served")
    emu = GyroEmulator(a, lambda _t: (0.01, -0.02, 0.03), GyroEmulatorConfig(output_period_s=0.1), name="emu")
    host = GyroHost(b, name="fc")
    seen = FrameObserver()
    emu.add_observer(seen)
    try:
        for k in range(5):
            emu.service(k * 0.1)
        host.poll()
        assert seen.count(GyroRate) == emu.counters["sent"] == host.counters["samples"] == 5
        assert seen.latest(GyroRate) == host.latest_rate
        emu.silent = True
        emu.service(0.5)
        assert seen.count(GyroRate) == 5  # a silent device sent nothing, so nothing was observed
        host.set_output_period(0.2)
        emu.service(0.6)
        assert seen.latest(SetOutputPeriod).period_s == emu.period_s == pytest.approx(0.2) and seen.frames == 6
    finally:
        host.close()
        emu.close()
        a.close()
        b.close()


def test_frame_observer_keeps_the_newest_of_several_types_and_counts_each():
    from drivers.framing import FrameObserver

    class A(float):
        pass

    class B(float):
        pass

    seen = FrameObserver()
    assert seen.latest(A, B) is None and seen.count(A) == 0
    for msg in (A(1.0), B(2.0), A(3.0)):
        seen(msg)
    assert seen.latest(A, B) == 3.0 and seen.latest(B) == 2.0 and seen.latest(B, A) == 3.0
    assert (seen.count(A), seen.count(B), seen.count(A, B), seen.frames) == (2, 1, 3, 3)
