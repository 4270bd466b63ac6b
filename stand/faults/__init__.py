"""Faults: what goes wrong in orbit and on the bench, injected into a run, and the flight code's FDIR judged.

``[[faults]]`` in a scenario (:mod:`.spec`: validated before t = 0), the fault types at three layers
(:mod:`.types`: device physics, protocol, time), where each acts on a device (:mod:`.taps`) and the schedule that
starts and clears them during a run and takes them live from the operator (:mod:`.schedule`). A run without faults
builds no schedule: the loop never calls into this package. docs/faults.md is the user's guide.
"""

from __future__ import annotations

from .schedule import FaultSchedule, build
from .spec import FaultSpec, parse
from .taps import TAPS, TapError
from .types import FAULT_TYPES, LAYERS, FaultType

__all__ = ["FAULT_TYPES", "LAYERS", "TAPS", "FaultSchedule", "FaultSpec", "FaultType", "TapError", "build", "parse"]
