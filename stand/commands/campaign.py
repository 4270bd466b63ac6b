"""``stand campaign``: a scenario run many times with dispersed inputs (Monte Carlo).

    stand campaign SCENARIO --runs N --dispersions FILE --out DIR [--workers K | --scheduler ADDRESS]
                   [--seed S] [--duration S] [--set KEY=VALUE] [--case-timeout S]

Runs on a local process pool (``--workers``, default 1) or on a Dask distributed scheduler
(``--scheduler tcp://HOST:PORT``; ``pip install 'adcs-stand[campaign]'``). Every case is reproducible from
(seed, index) and writes its summary and telemetry under ``DIR/cases/NNNNN/``; running the same command again
resumes (finished cases are not redone, more runs extend the campaign). ``DIR/campaign.json`` holds pass rates
with 95 % intervals, metric distributions and the worst cases; ``DIR/report.md`` the plots.
``stand run --campaign DIR --case K`` re-runs one case alone. A case that raises anything (``sys.exit`` too), ends
its worker process twice or runs longer than ``--case-timeout`` is recorded as an error and the others go on; so is
a case whose draw the scenario refuses (the dispersion file, every choice and case 0 are checked before anything
runs; each later case is checked by its worker, which parses it to run it anyway).
Exit codes: 0 the pass rate reached --min-pass-rate (default: every run passed), 1 it did not, 2 usage or
dispersion error found before the first run, 130 stopped (finished cases kept; run again to resume).
"""

from __future__ import annotations

import argparse
import sys


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("campaign", help="Monte Carlo: run a scenario many times with dispersed inputs",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("scenario", help="scenario file or shipped name")
    p.add_argument("--runs", type=int, required=True, help="number of cases")
    p.add_argument("--dispersions", required=True, help="dispersion file (TOML; see docs/campaigns.md)")
    p.add_argument("--out", required=True, help="campaign folder (new, empty, or this campaign's to resume)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, help="processes of the local pool (default 1)")
    where.add_argument("--scheduler", help="address of a Dask distributed scheduler, e.g. tcp://10.0.0.5:8786")
    p.add_argument("--seed", type=int, help="campaign seed (default: the dispersion file's, else the scenario's)")
    p.add_argument("--duration", type=float, help="simulated seconds of every run (default: the scenario's)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario value for every case (repeatable)")
    p.add_argument("--case-timeout", type=float, default=None, metavar="S",
                   help="wall-clock seconds after which a case still running is recorded as an error and its worker "
                        "ended (default 3600; 0: no limit)")
    p.add_argument("--min-pass-rate", type=float, default=1.0,
                   help="exit 0 when at least this fraction of the runs pass (default 1)")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="show a progress bar (default: when stderr is a terminal)")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from stand.campaign import CASE_TIMEOUT_S, CampaignError, fault_lines, make_spec, run_campaign
    from stand.errors import ScenarioError, fail, make_out_dir

    workers = 1 if args.workers is None else args.workers
    try:
        if not 0 <= workers <= 256:
            raise ScenarioError("--workers", workers, "a whole number from 1 to 256 (0: in this process)")
        if not 0.0 <= args.min_pass_rate <= 1.0:
            raise ScenarioError("--min-pass-rate", args.min_pass_rate, "a fraction from 0 to 1")
        spec = make_spec(args.scenario, args.dispersions, args.seed, args.set, args.duration)
        make_out_dir(args.out)
        progress = args.progress if args.progress is not None else sys.stderr.isatty()
        timeout = CASE_TIMEOUT_S if args.case_timeout is None else args.case_timeout
        result = run_campaign(spec, args.out, args.runs, workers=workers, scheduler=args.scheduler,
                              progress=progress, case_timeout_s=timeout)
    except (CampaignError, ScenarioError) as exc:
        return fail(str(exc))
    except KeyboardInterrupt:
        print(f"stand: campaign stopped; finished cases are kept in {args.out}: run the same command to resume",
              file=sys.stderr)
        return 130
    ex = result["execution"]
    lo, hi = result["pass_rate_ci95"]
    for name, c in result["criteria"].items():
        print(f"{name}: {c['passed']}/{c['runs']} passed ({100 * c['rate']:.1f} %, 95 % interval "
              f"{100 * c['ci95'][0]:.1f} to {100 * c['ci95'][1]:.1f} %)")
    for line in fault_lines(result):  # a campaign of faults: pass rates by fault type and by device
        print(line)
    for w in result["worst_cases"][:3]:
        print(f"worst: case {w['case']} ({w['criterion']}"
              + (f", margin {w['margin']:+.4g}" if w["margin"] is not None else "")
              + (f": {w['error']}" if w["error"] else "") + ")")
    for line in ex.get("lost", []):
        print(f"stand: lost (not recorded; run again to resume): {line}", file=sys.stderr)
    rate = f", {ex['runs_per_min']:g} runs/min on {ex['executor']} x{ex['workers']}" if ex.get("runs_per_min") else ""
    print(f"{result['finished']}/{result['runs']} runs: {result['passed']} passed, {result['failed']} failed "
          f"({result['errors']} errors); pass rate {100 * (result['pass_rate'] or 0):.1f} % "
          f"[{100 * lo:.1f}, {100 * hi:.1f}]{rate}; results in {args.out}")
    if result["status"] != "complete":
        return 1
    return 0 if (result["pass_rate"] or 0.0) >= args.min_pass_rate else 1
