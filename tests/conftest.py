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
