"""Scoring a star tracker's solution (``TrackerDevice._score``): the telemetry's flags byte is the ICD's SOLUTION flags
byte bit for bit, and the summary counts each flag that makes a solution invalid, for every combination of the flags
(the scoring looks the byte up per combination, issue 26)."""

from __future__ import annotations

import itertools
import math
from types import SimpleNamespace

from drivers.star_tracker.codec import Solution
from stand.devices.star_tracker_devices import FLAG_BITS, ICD_FLAG_BITS, TrackerDevice


def _solution(flags: dict[str, bool]) -> Solution:
    return Solution(time_us=1, q_TN=(1.0, 0.0, 0.0, 0.0), sigma_cross_rad=1e-5, sigma_roll_rad=1e-5,
                    stars_centroided=9, stars_matched=8, mode="TRACKING", stable_count=3, temperature_C=20.0, seq=1,
                    **flags)


def test_every_combination_of_the_flags_gives_the_icd_byte_and_counts_the_invalidating_flags():
    names = list(ICD_FLAG_BITS)
    device = SimpleNamespace(last_solution=None, solutions=0, valid=0, flags=dict.fromkeys(FLAG_BITS, 0),
                             truth_at={}, errors=[], last=None)
    expected_counts = dict.fromkeys(FLAG_BITS, 0)
    for round_ in range(2):  # the second round reads what the first one kept
        for n, on in enumerate(itertools.product((False, True), repeat=len(names))):
            flags = dict(zip(names, on, strict=True))
            TrackerDevice._score(device, _solution(flags), 0.1 * n)
            byte = sum(bit for name, bit in ICD_FLAG_BITS.items() if flags[name])
            assert device.last[7] == float(byte), (round_, flags)
            assert device.last[6] == 2.0 and math.isnan(device.last[8])  # TRACKING; no truth at that exposure
            for name in FLAG_BITS:
                expected_counts[name] += flags[name]
            assert device.flags == expected_counts
    assert device.solutions == 2 * 2 ** len(names)
    assert device.valid == 2 ** len(names)  # half the combinations have the valid bit
