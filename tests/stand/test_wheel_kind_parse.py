"""Loading a scenario with reaction wheels reads the DBC's command ranges once, not once per wheel per load: every
check of a scenario (the loader, a campaign's validation of each case, the fuzz tests' thousands of mutants) paid a
whole CAN codec (the DBC parsed, every packer made) per wheel only to read two numbers."""

from __future__ import annotations

import math

import pytest

from drivers.reaction_wheel import codec as codec_mod
from stand import scenario
from stand.devices import reaction_wheel as wheel_kind
from stand.errors import ScenarioError


def test_loading_wheel_scenarios_builds_the_ranges_codec_once(monkeypatch):
    built = []
    real = codec_mod.ReactionWheelCodec

    class Counting(real):
        def __init__(self, *args, **kwargs):
            built.append(args)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(codec_mod, "ReactionWheelCodec", Counting)
    _clear_cache()
    try:
        first = scenario.load("acquisition")  # four wheels
        again = scenario.load("acquisition")
        assert len(built) == 1, built
        wheels = [d for d in first.devices if d.kind == "reaction_wheel"]
        assert len(wheels) == 4 and [repr(d) for d in wheels] == [repr(d) for d in again.devices
                                                                  if d.kind == "reaction_wheel"]
    finally:
        _clear_cache()  # the next caller builds the ranges from the real class


def _clear_cache() -> None:
    cached = getattr(wheel_kind, "_command_ranges", None)
    if cached is not None:
        cached.cache_clear()


@pytest.mark.parametrize("key, top", [
    ("max_torque_Nm", lambda c: c.torque_range_Nm[1]),
    ("max_speed_rpm", lambda c: c.speed_range_rad_s[1] * 60.0 / (2.0 * math.pi)),
])
def test_a_wheel_limit_beyond_what_the_dbc_carries_is_still_refused(key, top):
    limit = top(codec_mod.ReactionWheelCodec(0))
    scenario.load("acquisition", [f"devices.rw0.{key}={0.99 * limit!r}"])
    with pytest.raises(ScenarioError, match=f"devices\\[\\d+\\]\\.{key} = "):
        scenario.load("acquisition", [f"devices.rw0.{key}={1.01 * limit!r}"])
