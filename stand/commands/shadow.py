"""``stand shadow``: shadows on the docking target over an approach (a scenario's ``[rendezvous]``).

    stand shadow SCENARIO [--out DIR] [--step S] [--refine on|off] [--camera-times T1,T2,...]

Writes into DIR (default ``runs/NAME-shadow-TIME``): ``obscuration.csv`` (per sample: obscured
percentage of the marks' area, each mark's shadowed fraction, each body's share, the Earth-shadow
factor, the Sun's elevation on the plate, the chaser's LVLH position and range), ``summary.json``
(intervals with start, end, peak and the bodies that cast them; Earth-shadow intervals),
``obscured.png``, ``tracks.png`` (shadows drawn on the plate and the tracks of the bodies' shadows),
``report.md`` and ``camera_<t>s.png`` (what the docking camera sees at the scenario's
``[rendezvous.camera] times_s`` or ``--camera-times``). Prints the intervals.
Exit codes: 0 written, 2 usage or scenario error (one sentence naming the field, value and what is allowed).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("shadow", help="shadows on the docking target over an approach ([rendezvous])",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("scenario", help="scenario file or name in fixtures/scenarios with a [rendezvous] section")
    p.add_argument("--out", help="output directory (default: runs/NAME-shadow-TIME)")
    p.add_argument("--step", type=float, help="sampling step, s (default: rendezvous.step_s)")
    p.add_argument("--refine", choices=("on", "off"), help="bisect interval ends (default: rendezvous.refine)")
    p.add_argument("--camera-times", help="comma-separated times (s) for camera images (default: the scenario's)")
    p.set_defaults(func=run)
    return p


def _fail(msg: str) -> int:
    print(f"stand: error: {msg}", file=sys.stderr)
    return 2


def _times(text: str | None, duration_s: float):
    if text is None:
        return None
    try:
        times = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        times = None
    if not times or any(not 0.0 <= x <= duration_s for x in times):
        raise ValueError(f"--camera-times {text!r} is not allowed: comma-separated times in [0, {duration_s:g}] s.")
    return times


def run(args) -> int:
    from stand.errors import ScenarioError, make_out_dir
    from stand.rendezvous import run_shadow
    from stand.scenario import load

    try:
        sc = load(args.scenario)
        if sc.rendezvous is None:
            raise ScenarioError("rendezvous", "<missing>", "a [rendezvous] section: 'stand shadow' studies an "
                                "approach (see fixtures/scenarios/rendezvous_shadow.toml)", sc.source)
        if args.step is not None and not (1e-3 <= args.step <= sc.duration_s / 2):
            raise ScenarioError("--step", args.step, f"a sampling step from 0.001 to {sc.duration_s / 2:g} s")
        times = _times(args.camera_times, sc.duration_s)
        out = Path(args.out) if args.out else Path("runs") / f"{sc.name}-shadow-{time.strftime('%Y%m%d-%H%M%S')}"
        if out.exists() and any(out.iterdir()):
            raise ScenarioError("--out", str(out), "an empty or new directory (a run never overwrites another)")
        make_out_dir(out)
    except (ScenarioError, ValueError) as exc:
        return _fail(str(exc))
    refine = None if args.refine is None else args.refine == "on"
    summary = run_shadow(sc, out, step_s=args.step, refine=refine, camera_times_s=times)
    for k, iv in enumerate(summary["intervals"]):
        print(f"obscured {k + 1}: {iv['start_s']:.3f} s to {iv['end_s']:.3f} s ({iv['duration_s']:.3f} s, peak "
              f"{iv['max_percent']:.1f} %) by {', '.join(iv['causes']) or '-'}")
    for iv in summary["eclipses"]:
        print(f"Earth shadow: {iv['start_s']:.1f} s to {iv['end_s']:.1f} s")
    print(f"{sc.name}: {len(summary['intervals'])} obscuration intervals, peak {summary['max_obscured_percent']:.1f} %,"
          f" computed in {summary['wall_time_s']:.2f} s; results in {out}")
    return 0
