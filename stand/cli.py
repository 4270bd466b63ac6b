"""The ``stand`` command line.

Exit codes (DESIGN.md): 0 when the scenario's pass criteria hold, 1 when they fail (or a run
was aborted by a device or numerical error), 2 for a usage or scenario error. User mistakes get
one sentence naming the field, the value and what is allowed; never a bare traceback.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import sys
import time
from pathlib import Path

from .errors import ScenarioError

#: Subcommands contributed by other modules of the stand: ``module`` exposes ``register(subparsers)``.
EXTRA_COMMANDS = ("stand.commands.screen", "stand.commands.display", "stand.commands.emulate", "stand.commands.solve",
                  "stand.commands.shadow")


def _fail(message: str) -> int:
    print(f"stand: error: {message}", file=sys.stderr)
    return 2


def _load_scenario(arg: str | None, seed: int | None = None):
    from . import scenario as scenario_mod

    sc = scenario_mod.load(arg or scenario_mod.DEFAULT_SCENARIO)
    if seed is not None:
        if seed < 0:
            raise ScenarioError("--seed", seed, "a whole number >= 0")
        sc = dataclasses.replace(sc, seed=seed)
    return sc


def cmd_run(args) -> int:
    from drivers.errors import DriverError

    from .compose import build
    from .loop import run
    from .pacing import parse_speed
    from .report import write_summary

    try:
        speed = parse_speed(args.speed)
        sc = _load_scenario(args.scenario, args.seed)
        if args.duration is not None and not (0 < args.duration <= sc.duration_s * 100):
            raise ScenarioError("--duration", args.duration, "a positive number of seconds")
        out = Path(args.out) if args.out else Path("runs") / f"{sc.name}-{time.strftime('%Y%m%d-%H%M%S')}"
        if out.exists() and any(out.iterdir()):
            raise ScenarioError("--out", str(out), "an empty or new directory (a run never overwrites another)")
        out.mkdir(parents=True, exist_ok=True)
        scene = build(sc)
    except (ScenarioError, DriverError, ValueError) as exc:
        return _fail(str(exc))
    with scene:
        result = run(scene, out, speed=speed, duration_s=args.duration,
                     progress=args.progress if args.progress is not None else sys.stderr.isatty())
    summary = write_summary(scene, result, out)
    for c in summary["criteria"]:
        print(f"{'PASS' if c['pass'] else 'FAIL'}  {c['name']}: {c['value']:.4g} (limit {c['limit']})")
    if result.error:
        print(f"stand: run {result.status}: {result.error}", file=sys.stderr)
    print(f"{'PASS' if summary['pass'] else 'FAIL'}: {sc.name}, {result.sim_duration_s:g} s simulated in "
          f"{result.wall_time_s:.2f} s (x{summary['realtime_factor']} real time); results in {out}")
    return 0 if summary["pass"] else 1


def cmd_check(args) -> int:
    from .compose import plan

    try:
        sc = _load_scenario(args.scenario)
    except ScenarioError as exc:
        return _fail(str(exc))
    choices = plan(sc)
    if args.json:
        print(json.dumps({"scenario": sc.name, "valid": True,
                          "built": [{"model": c.model, "reason": c.reason} for c in choices if c.built],
                          "left_out": [{"model": c.model, "reason": c.reason} for c in choices if not c.built]},
                         indent=2))
        return 0
    print(f"{sc.name}: valid ({sc.source}); {sc.duration_s:g} s at {sc.step_s:g} s steps")
    print("built:")
    for c in choices:
        if c.built:
            print(f"  {c.model:32s} {c.reason}")
    print("left out:")
    for c in choices:
        if not c.built:
            print(f"  {c.model:32s} {c.reason}")
    return 0


def cmd_bench(args) -> int:
    from .benches import BENCHES, print_rows, run_bench

    if args.name not in BENCHES:
        return _fail(f"bench {args.name!r} is not known; available: {', '.join(BENCHES)}.")
    try:
        plot = str(Path(args.json).with_suffix(".png")) if args.json else None
        rows = run_bench(args.name, quick=args.quick, plot_path=plot)
    except ScenarioError as exc:
        return _fail(str(exc))
    print_rows(rows)
    if args.json:
        Path(args.json).write_text(json.dumps({"bench": args.name, "rows": rows}, indent=2, default=float) + "\n")
    return 0 if all(r.get("pass", True) for r in rows) else 1


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stand", description="Hardware-in-the-loop test stand for spacecraft ADCS.")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    r = sub.add_parser("run", help="run a scenario (default: the detumble on emulated CAN devices)")
    r.add_argument("scenario", nargs="?", help="scenario file or name in fixtures/scenarios (default: detumble)")
    r.add_argument("--out", help="output directory (default: runs/NAME-TIME)")
    r.add_argument("--speed", default="afap", help="afap (default), realtime, or a factor such as 10")
    r.add_argument("--duration", type=float, help="simulated seconds (default: the scenario's)")
    r.add_argument("--seed", type=int, help="random seed (default: the scenario's)")
    r.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="show a progress bar (default: when stderr is a terminal)")
    r.set_defaults(func=cmd_run)

    c = sub.add_parser("check", help="validate a scenario; list the models built and left out, and why")
    c.add_argument("scenario")
    c.add_argument("--json", action="store_true", help="print JSON")
    c.set_defaults(func=cmd_check)

    from .benches import BENCHES

    b = sub.add_parser("bench", help="measurements: " + ", ".join(BENCHES))
    b.add_argument("name", help=", ".join(BENCHES))
    b.add_argument("--json", help="also write the rows to this JSON file (and any figure beside it as .png)")
    b.add_argument("--quick", action="store_true", help="a shorter version (for smoke tests)")
    b.set_defaults(func=cmd_bench)

    for module in EXTRA_COMMANDS:
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
            continue
        mod.register(sub)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("stand: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
