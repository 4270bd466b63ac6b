"""drivers.frozen_build: a frozen slotted dataclass made by its slots is the object its ``__init__`` makes."""

from __future__ import annotations

import pytest

from drivers.frozen_build import keyword_maker
from drivers.gyro.codec import GyroCodec, GyroRate
from drivers.star_tracker.codec import Solution, StarTrackerCodec


def test_keyword_maker_makes_what_the_dataclass_makes():
    """Every serial message (and the tracker's truth) made through its slots equals, hashes, prints and refuses
    assignment like the one its ``__init__`` makes; a class without slots or with a ``__post_init__`` is made by
    its ``__init__``."""
    import dataclasses

    from drivers.star_tracker.measurement import TrackerTruth
    from drivers.sun_sensor.codec import SunSensorCodec

    classes = [spec.cls for codec in (StarTrackerCodec(), GyroCodec(), SunSensorCodec())
               for spec in codec.messages.values()]
    assert Solution in classes and GyroRate in classes
    for cls in [*classes, TrackerTruth]:
        kw = {f.name: (i, f"v{i}", (i, -i)) for i, f in enumerate(dataclasses.fields(cls))}
        made, init = keyword_maker(cls)(kw), cls(**kw)
        assert type(made) is cls and made == init and hash(made) == hash(init) and repr(made) == repr(init)
        for f in dataclasses.fields(cls)[:1]:  # (a message without fields has nothing to assign)
            with pytest.raises(dataclasses.FrozenInstanceError):
                setattr(made, f.name, 0)

    calls = []

    @dataclasses.dataclass(frozen=True, slots=True)
    class Checked:
        x: int

        def __post_init__(self):
            calls.append(self.x)

    @dataclasses.dataclass(frozen=True)
    class Plain:
        x: int

    assert keyword_maker(Checked)({"x": 3}) == Checked(3) and calls == [3, 3]
    assert keyword_maker(Plain)({"x": 4}) == Plain(4)
