"""Test-wide settings.

Hypothesis explores new random examples on every developer run; under CI (``CI`` set) it runs a
fixed, derandomised set so a landing never depends on the luck of the draw. A failure found
locally is reproduced with the seed Hypothesis prints and becomes a regression test.

Independent oracles and compiled paths are asked for through tests/oracles.py: skipped locally when missing, a
failure under CI.
"""

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


def pytest_collection_modifyitems(items):
    """The tests marked ``slow`` first, each group in collection order (a stable sort).

    xdist (``--dist worksteal``) hands each worker a contiguous half of this list and lets an idle worker steal the
    tail of the other's queue, so the tests left at the end are the last ones in the list. There, a 75 s test (the
    acquisition) ran alone on one worker while the other had nothing left to take. Started first, the long tests
    overlap with the short ones, and the run ends on short tests that both workers share. The order changes nothing
    a test checks: each test makes its own scene, files and processes.
    """
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
