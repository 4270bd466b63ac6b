"""The default scenario on python-can's ``virtual`` bus and on the stand's ``stand_loopback`` bus:
the transport must not change a single bit of what the run records."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from stand import telemetry
from stand.compose import build
from stand.loop import run
from stand.scenario import DEFAULT_SCENARIO, load

_runs = itertools.count()


def _on(sc, interface: str):
    k = next(_runs)
    devices = tuple(
        dataclasses.replace(d, interface=interface, channel=f"bit-identity-{k}-{d.name}")
        if d.kind == "magnetorquer" else d
        for d in sc.devices
    )
    return dataclasses.replace(sc, devices=devices)


@pytest.mark.parametrize("mag_noise_T", [0.0, 50e-9])
def test_default_scenario_records_the_same_bits_on_both_buses(tmp_path, mag_noise_T):
    sc = load(DEFAULT_SCENARIO)
    assert any(d.kind == "magnetorquer" for d in sc.devices)
    devices = tuple(dataclasses.replace(d, mag_noise_T=mag_noise_T) if d.kind == "magnetorquer" else d
                    for d in sc.devices)
    sc = dataclasses.replace(sc, duration_s=300.0, devices=devices)
    logs, counters = {}, {}
    for interface in ("virtual", "stand_loopback"):
        with build(_on(sc, interface)) as scene:
            assert {type(b).__name__ for d in scene.devices.values() for b in getattr(d, "_buses", ())} == {
                "VirtualBus" if interface == "virtual" else "LoopbackBus"}
            result = run(scene, tmp_path / interface)
        logs[interface] = telemetry.load(tmp_path / interface)
        counters[interface] = result.counters
    a, b = logs["virtual"], logs["stand_loopback"]
    assert a.keys() == b.keys() and len(a["t_s"]) == 3001
    for name in a:
        assert a[name].dtype == b[name].dtype and np.array_equal(a[name], b[name], equal_nan=True), name
    assert counters["virtual"] == counters["stand_loopback"]
    assert counters["virtual"]["mtq"]["sent"] > 2000  # the chain did carry the commands
