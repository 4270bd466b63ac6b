"""Serial star tracker (ICD: ``fixtures/devices/star_tracker.toml``; document: ``docs/star_tracker_icd.md``).

- :mod:`.slip`: the shared SLIP framer of :mod:`drivers.framing`, named for the tracker;
- :mod:`.codec`: pure codec built from the TOML, messages as frozen dataclasses in SI units;
- :mod:`.host`: :class:`StarTrackerHost`, the stand talking to a tracker;
- :mod:`.emulator`: :class:`StarTrackerEmulator`, the stand being the tracker (truth plus noise);
- :mod:`.measurement`: what the emulator is given (:class:`TrackerTruth`), its settings (:class:`EmulatorConfig`)
  and its measurement model (attitude noise, bright bodies in the field);
- :mod:`.icd`: renders the ICD document from the TOML.

The host and emulator modules import pyserial lazily (only to open a URL).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from drivers.framing import SlipDecoder
from drivers.lazy import lazy_getattr
from drivers.star_tracker.codec import (
    Ack,
    Action,
    FrameRejected,
    GetParam,
    Nack,
    NackError,
    ParamValue,
    RequestTelemetry,
    SetParam,
    Solution,
    StarTrackerCodec,
    Status,
    Subscribe,
    Unsubscribe,
)

if TYPE_CHECKING:  # pragma: no cover
    from drivers.star_tracker.emulator import StarTrackerEmulator
    from drivers.star_tracker.host import StarTrackerHost
    from drivers.star_tracker.measurement import EmulatorConfig, TrackerTruth

__all__ = [
    "Ack",
    "Action",
    "EmulatorConfig",
    "FrameRejected",
    "GetParam",
    "Nack",
    "NackError",
    "ParamValue",
    "RequestTelemetry",
    "SetParam",
    "SlipDecoder",
    "Solution",
    "StarTrackerCodec",
    "StarTrackerEmulator",
    "StarTrackerHost",
    "Status",
    "Subscribe",
    "TrackerTruth",
    "Unsubscribe",
]

__getattr__ = lazy_getattr(__name__, {
    "StarTrackerHost": "drivers.star_tracker.host",
    "StarTrackerEmulator": "drivers.star_tracker.emulator",
    "EmulatorConfig": "drivers.star_tracker.measurement",
    "TrackerTruth": "drivers.star_tracker.measurement",
})
