"""Monte Carlo campaigns: one scenario run many times with dispersed inputs.

A dispersion file (TOML) names scenario fields by their dotted path, as ``stand run --set`` does (a
``[[devices]]`` entry by its name: ``devices.mtq.mag_noise_nT``), each with a distribution::

    [campaign]
    seed = 2026                        # optional; --seed wins; default: the scenario's seed

    [[dispersions]]
    field = "spacecraft.inertia_kg_m2"
    distribution = "normal"            # mean (default: the scenario's value), sigma or sigma_percent,
    sigma_percent = 5.0                #   optional min / max (a truncated normal)
    min = 0.001

    [[dispersions]]
    field = "devices.mtq.q_SB"
    distribution = "rotation"          # a small random rotation composed onto the scenario's quaternion
    sigma_deg = 0.5                    #   (rotation vector normal per axis, degrees)

    [[dispersions]]
    field = "scenario.epoch"
    distribution = "choice"            # one of a list, optionally weighted
    values = ["2026-03-20T12:00:00Z", "2026-06-21T00:00:00Z"]

Distributions: ``normal``, ``uniform`` (min, max; ``integer = true`` for whole numbers), ``rotation``,
``uniform_rotation`` (any attitude, uniformly), ``choice``. Every parameter is a number or, for a vector
field, a list with one number per axis (per-axis dispersions).

Values are applied to the scenario's parsed TOML dict and the result goes through ``stand.scenario.parse``, so
every dispersed value meets the same validation as a hand-written one: the file, every choice's values and case 0
before the first run starts, every other case in the worker that runs it (a value the scenario refuses is that
case's error, with the same sentence).

Case ``k`` of a campaign with seed ``S`` draws from ``numpy.random.SeedSequence((S, k))``: its first child seeds
the run (``[scenario] seed``), the next ones the dispersions in file order, so any case re-runs alone and adding
runs never changes the earlier ones.

Runs go to a local process pool or to a Dask distributed scheduler; a worker gets the spec once and each case as
its index. A local worker writes its case under ``DIR/cases/NNNNN.part`` and the client renames it; a Dask
worker does too where it sees the campaign folder, else it runs the case in a temporary folder and returns its
files for the client to write, so workers need no shared file system. Finished cases (a ``case.json``) are
never redone; a run that raises is recorded as an error and the others go on. ``aggregate`` turns the cases into
``campaign.json`` and ``write_report`` into ``report.md`` with plots.

The package, one job per module: ``dispersions`` (the file, dotted paths, the draws), ``spec`` (what fixes every
case; validation), ``case`` (one run and its digest), ``pool`` (local worker processes), ``dask_executor``,
``store`` (the campaign folder), ``runner`` (run or resume), ``results`` (campaign.json), ``summary_report``
(report.md and plots), ``rerun`` (one case alone). The core never imports it.
"""

from .case import RUN_FILES, WALL_CLOCK_KEYS, comparable, digest, run_case, warm
from .dask_executor import DASK_HTTP_ADDRESS
from .dispersions import (
                          DISTRIBUTIONS,
                          KEYS,
                          Dispersion,
                          Dispersions,
                          apply,
                          case_values,
                          get_field,
                          parse_dispersions,
                          put_field,
                          with_faults,
)
from .errors import CampaignError
from .fault_groups import case_faults, fault_lines
from .pool import WORKER_DEATHS
from .rerun import compare_case, load_case
from .results import CONFIDENCE, aggregate, clopper_pearson, metric_table
from .runner import CASE_TIMEOUT_S, MAX_CASE_TIMEOUT_S, CampaignProgress, run_campaign
from .spec import MAX_RUNS, Spec, make_spec, validate
from .store import CASE_DIGITS, case_dir, finished
from .summary_report import write_report

__all__ = ["CASE_DIGITS", "CASE_TIMEOUT_S", "CONFIDENCE", "DASK_HTTP_ADDRESS", "DISTRIBUTIONS", "KEYS",
           "MAX_CASE_TIMEOUT_S", "MAX_RUNS", "RUN_FILES", "WALL_CLOCK_KEYS", "WORKER_DEATHS", "CampaignError",
           "CampaignProgress", "Dispersion", "Dispersions", "Spec", "aggregate", "apply", "case_dir", "case_faults",
           "case_values", "clopper_pearson", "comparable", "compare_case", "digest", "fault_lines", "finished",
           "get_field", "load_case", "make_spec", "metric_table", "parse_dispersions", "put_field", "run_campaign",
           "run_case", "validate", "warm", "with_faults", "write_report"]
