"""The ``stand`` command line.

Exit codes (``stand --help``, ``docs/public_surface.md``): 0 the run passed its criteria, 1 a criterion failed,
2 a usage or scenario error, 3 the run was aborted (a device fault, a plug-in exception, a full disk),
130 stopped by the operator (Ctrl-C or SIGTERM). User mistakes get one sentence naming the field, the value and
what is allowed; never a bare traceback.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import math
import os
import signal
import sys
import time
from pathlib import Path

from .errors import ScenarioError, fail

#: Subcommands contributed by other modules of the stand: ``module`` exposes ``register(subparsers)``.
EXTRA_COMMANDS = ("stand.commands.screen", "stand.commands.display", "stand.commands.emulate", "stand.commands.solve",
                  "stand.commands.shadow", "stand.commands.view", "stand.commands.campaign",
                  "stand.commands.fault_proxy", "stand.commands.export", "stand.commands.fault")
EXIT_PASS, EXIT_FAIL, EXIT_USAGE, EXIT_ABORTED, EXIT_STOPPED = 0, 1, 2, 3, 130
EXIT_CODES = """exit codes:
  0    the run passed its criteria, or completed with none to judge (NOT JUDGED) (other commands: success)
  1    a criterion failed
  2    a usage or scenario error (one sentence names the field, the value and what is allowed)
  3    the run was aborted: a device fault, a plug-in exception, a full disk, a record that is not whole
       (summary and log kept)
  130  stopped by the operator (Ctrl-C or SIGTERM; summary and log kept)"""


def _load_scenario(arg: str | None, seed: int | None = None, overrides: list[str] | None = None):
    from . import scenario as scenario_mod

    sc = scenario_mod.load(arg or scenario_mod.DEFAULT_SCENARIO, overrides)
    if seed is not None:
        if not 0 <= seed < 2**63:
            raise ScenarioError("--seed", seed, "a whole number from 0 to 2**63 - 1")
        sc = dataclasses.replace(sc, seed=seed)
    return sc


class _Signals:
    """SIGTERM stops a run as Ctrl-C does; while the summary is written, further signals are noted, not acted
    on, so the report is whole."""

    def __init__(self):
        self.old = {}
        self.deferred = False

    def __enter__(self):
        from .loop import Stopped

        def term(signum, frame):
            raise Stopped(signal.Signals(signum).name)

        self.old[signal.SIGTERM] = signal.signal(signal.SIGTERM, term)
        return self

    def defer(self):
        def note(signum, frame):
            self.deferred = True

        for sig in (signal.SIGINT, signal.SIGTERM):
            self.old.setdefault(sig, signal.getsignal(sig))
            signal.signal(sig, note)

    def __exit__(self, *exc):
        for sig, handler in self.old.items():
            signal.signal(sig, handler)


def _linger_seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not value >= 0:  # NaN too
        raise argparse.ArgumentTypeError(f"--view-linger-s {text!r} is not allowed: seconds from 0, or inf (until "
                                          "Ctrl-C or SIGTERM)")
    return value


def _speed(args, sc) -> float | None:
    from .pacing import parse_speed

    wall = sc.wall_time_links
    if args.speed is None:
        return 1.0 if wall else None
    speed = parse_speed(args.speed)
    if speed is None and wall:
        raise ScenarioError("--speed", args.speed, f"realtime or a factor: devices {', '.join(wall)} run on "
                            "hardware or served links in wall time, and a run as fast as possible would outrun them")
    return speed


def _reserve_out(args, sc) -> tuple[Path, bool]:
    """The run's folder, made now, and whether this run created it. ``--out`` may name a new or empty folder; the
    default ``runs/NAME-TIME`` is made with an exclusive mkdir, with ``-2``, ``-3``, ... when another run started
    in the same second took the name, so two runs never share a folder. Any failure is a ScenarioError on --out."""
    if args.out:
        out = Path(args.out)
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            raise ScenarioError("--out", str(out), "an empty or new directory (a run never overwrites another)")
        created = not out.exists()
        _mkdir_out(out, exist_ok=True)
        return out, created
    base = Path("runs") / f"{sc.name}-{time.strftime('%Y%m%d-%H%M%S')}"
    _mkdir_out(base.parent, exist_ok=True)
    for k in range(1, MAX_SAME_SECOND + 1):
        out = base if k == 1 else base.with_name(f"{base.name}-{k}")
        try:
            _mkdir_out(out, exist_ok=False)
            return out, True
        except FileExistsError:
            continue
    raise ScenarioError("--out", None, f"a folder name: {base} and {MAX_SAME_SECOND - 1} numbered ones beside it are "
                        "taken; name one with --out")


#: Runs started in the same second that still get a folder of their own (runs/NAME-TIME-2 ... -N).
MAX_SAME_SECOND = 1000


def _mkdir_out(path: Path, exist_ok: bool) -> None:
    try:
        path.mkdir(parents=True, exist_ok=exist_ok)
    except FileExistsError:
        if not exist_ok:
            raise
        raise ScenarioError("--out", str(path), "a directory (a file of that name is in the way)") from None
    except OSError as exc:
        raise ScenarioError("--out", str(path), f"a folder the stand can create and write in "
                            f"({exc.strerror or exc})") from None


def _unreserve(out: Path | None, created: bool) -> None:
    """Nothing ran: take back the placeholder summary and the folder this run made, leaving no empty folder."""
    if out is None:
        return
    for name in ("summary.json", "view.json"):
        (out / name).unlink(missing_ok=True)
    if created and out.is_dir() and not any(out.iterdir()):
        out.rmdir()


def _prepare(args):
    """Scenario, speed, case, the run's folder (made, with a placeholder summary) and the scene, before t = 0."""
    from .compose import build
    from .report import reserve_summary

    case = base = None
    if args.campaign is not None or args.case is not None:
        sc, base, case = _campaign_case(args)
    else:
        sc = _load_scenario(args.scenario, args.seed, args.set)
    speed = _speed(args, sc)
    if args.duration is not None and not (sc.step_s <= args.duration <= sc.duration_s * 100):
        raise ScenarioError("--duration", args.duration, f"seconds from the step ({sc.step_s:g} s) to "
                            f"100 times the scenario's duration ({sc.duration_s * 100:g} s)")
    out, created = _reserve_out(args, sc)
    try:
        try:
            reserve_summary(out, sc)
        except OSError as exc:
            raise ScenarioError("--out", str(out), f"a folder the stand can write in ({exc.strerror or exc})") from None
        from . import scenario as scenario_mod

        if case is None:
            base = scenario_mod.find(args.scenario).parent if args.scenario else None
        scene = build(sc, speed, base, duration_s=args.duration, out_dir=out,
                      allow_remote=getattr(args, "allow_remote", ()),
                      live_faults=getattr(args, "view", None) is not None)  # the page can inject faults
    except BaseException:
        _unreserve(out, created)
        raise
    return sc, speed, case, out, created, scene


def _escaped(exc: BaseException, out: Path, stopped: bool = False):
    """The result of a run that something escaped the loop from (a plug-in's ``sys.exit()``, another
    BaseException, a signal outside the loop's own handling): aborted (stopped for a signal), with what the
    telemetry shows; the loop's own handling comes first, this is the backstop so that `stand run` never ends
    without its summary."""
    from .loop import RunResult
    from .telemetry import load

    try:
        t = load(out)["t_s"]
        end_s = float(t[-1]) if len(t) else 0.0
    except (OSError, ValueError, KeyError):
        end_s = 0.0
    if stopped:
        return RunResult("stopped", end_s, 0.0, 0, {"ticks": 0}, f"stopped by the operator ({type(exc).__name__}) "
                         f"after t = {end_s:g} s")
    return RunResult("aborted", end_s, 0.0, 0, {"ticks": 0}, f"the run was ended from inside the loop by "
                     f"{type(exc).__name__}({exc}) after t = {end_s:g} s (a plug-in may not end the stand's process)")


def _summary_on_disk(out: Path) -> dict | None:
    """summary.json read back (None when it cannot be): the exit code follows what the run left, not what it meant
    to write, so a run never exits 0 without its summary."""
    try:
        data = json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def cmd_run(args) -> int:
    held: dict = {}  # the live page's session, when --view: it outlives the run (_linger)
    try:
        code = _cmd_run(args, held)
        if held.get("live") is not None and held.get("status") not in (None, "stopped"):
            _linger(args, held["live"])
        return code
    finally:
        if held.get("live") is not None:
            held["live"].close()


def _linger(args, live) -> None:
    """A finished run's page stays served (a run at the default speed ends before a browser opens it): for
    --view-linger-s, by default until Ctrl-C or SIGTERM when the stand runs in a terminal, else not at all."""
    seconds = args.view_linger_s
    if seconds is None and not sys.stdin.isatty():
        print(f"stand: the run has ended and its page's server stops (not run from a terminal): pass --view-linger-s "
              f"SECONDS to keep serving, or replay it with `stand view {live.run_dir}`", flush=True)
        return
    live.linger(seconds)


def _cmd_run(args, held: dict) -> int:
    from drivers.errors import DriverError

    from .adcs import PluginError
    from .loop import Stopped, run
    from .report import limit_text, write_summary

    out = live = None
    try:
        with _Signals() as signals:
            try:
                if getattr(args, "view", None) is not None:
                    from .view.server import LiveSession

                    live = held["live"] = LiveSession.from_args(args.view, args.view_token)
                sc, speed, case, out, created, scene = _prepare(args)
            except (ScenarioError, PluginError, DriverError, ValueError) as exc:
                return fail(str(exc))
            except (KeyboardInterrupt, Stopped):
                print("stand: stopped by the operator before the run started; nothing was written", file=sys.stderr)
                return EXIT_STOPPED
            with scene:
                from .view.state import write_view_json

                write_view_json(sc, out, args.duration)
                if live is not None:
                    from .view.server import ViewError

                    try:
                        print(f"stand: live view at {live.start(sc, out, args.duration)} (Ctrl-C stops the run)",
                              flush=True)
                    except ViewError as exc:
                        _unreserve(out, created)  # nothing ran: leave no folder behind
                        return fail(str(exc))
                result = None
                try:
                    result = run(scene, out, speed=speed, duration_s=args.duration,
                                 progress=args.progress if args.progress is not None else sys.stderr.isatty(),
                                 observer=live.observer if live is not None else None)
                except BaseException as exc:  # noqa: BLE001 - a plug-in's sys.exit(): the run still ends with a summary
                    result = _escaped(exc, out, stopped=isinstance(exc, KeyboardInterrupt | Stopped))
                finally:
                    held["status"] = result.status if result is not None else "aborted"
                    if live is not None:
                        live.finish(held["status"])
                signals.defer()
            summary = write_summary(scene, result, out, plots=args.plots, duration_s=args.duration)
            if live is not None:
                live.summary_ready()
    except OSError as exc:
        print(f"stand: error: the run's results could not be written in {out}: {exc.strerror or exc}", file=sys.stderr)
        return EXIT_ABORTED
    return _report(summary, result, sc, out, case, limit_text)


def _report(summary: dict, result, sc, out: Path, case, limit_text) -> int:
    """Print the criteria, the timing and the verdict; the exit code from the summary as written."""
    for c in summary["criteria"]:
        print(f"{'PASS' if c['pass'] else 'FAIL'}  {c['name']}: {limit_text(c)}")
    t = result.timing
    if t.get("paced"):
        print(f"paced at x{t['speed_factor']:g} real time: {t['overruns']} overruns (ticks more than a period late), "
              f"lateness p99 {t.get('lateness_ms_p99', 0):.3f} ms, worst {t.get('lateness_ms_max', 0):.3f} ms")
    status = summary["status"]
    if summary["error"]:
        print(f"stand: run {status}: {summary['error']}", file=sys.stderr)
    on_disk = _summary_on_disk(out)
    if on_disk is None or on_disk.get("status") != status:
        print(f"stand: error: {out / 'summary.json'} does not hold this run's summary after writing it",
              file=sys.stderr)
        status = "aborted"
    passed = summary["pass"] is True and on_disk is not None and on_disk.get("pass") is True
    # "PASS, paced with N % overruns" when a paced run's overruns exceed the stated share (stand.report.verdict_text)
    verdict = summary.get("verdict", "PASS") if passed or status == "completed" and not summary["criteria"] \
        else {"aborted": "ABORTED", "stopped": "STOPPED"}.get(status, "FAIL")
    print(f"{verdict}: {sc.name}, {result.sim_duration_s:g} s simulated in {result.wall_time_s:.2f} s "
          f"(x{summary['realtime_factor']} real time); results in {out}")
    if case is not None:
        from .campaign import compare_case

        same, text = compare_case(case, out)
        print(text, file=sys.stdout if same is not False else sys.stderr)
    if status == "aborted":
        return EXIT_ABORTED
    if status == "stopped":
        return EXIT_STOPPED
    # A scenario with no criteria (a study such as rendezvous_shadow) completed: nothing failed, nothing was judged;
    # the verdict and summary say NOT JUDGED (pass false), the exit code does not fail a script that ran it.
    not_judged = status == "completed" and not summary["criteria"]
    return EXIT_PASS if passed or not_judged else EXIT_FAIL


def _campaign_case(args):
    """``stand run --campaign DIR --case K``: the case's scenario exactly as the campaign ran it."""
    from .campaign import load_case

    if args.campaign is None or args.case is None:
        from .errors import MISSING

        raise ScenarioError("--campaign" if args.campaign is None else "--case", MISSING,
                            "--campaign DIR and --case K together")
    for flag, value in (("--seed", args.seed), ("--duration", args.duration), ("--set", args.set or None)):
        if value is not None:
            raise ScenarioError(flag, value, "nothing with --campaign: a case runs with the campaign's seed, "
                                "duration and values")
    sc, base, case = load_case(args.campaign, args.case)  # a CampaignError is a ValueError: one sentence, exit 2
    name = sc.source.split("#")[0]
    if args.scenario is not None and Path(args.scenario).name not in (name, name.removesuffix(".toml")):
        raise ScenarioError("SCENARIO", args.scenario, f"the campaign's scenario ({name}) or none with --campaign")
    return sc, base, case


def cmd_check(args) -> int:
    from .adcs import PluginError
    from .compose import plan
    from .controllers import check_controller

    try:
        sc = _load_scenario(args.scenario, overrides=args.set)
        from . import scenario as scenario_mod

        check_controller(sc, scenario_mod.find(args.scenario).parent)
        choices = plan(sc)
    except (ScenarioError, PluginError) as exc:
        return fail(str(exc))
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


def cmd_scenarios(args) -> int:
    from .scenario import SCENARIO_DIR, shipped

    rows = shipped()
    w = max(map(len, rows), default=8)
    print(f"shipped scenarios ({SCENARIO_DIR}); run one with `stand run NAME`:")
    for name, desc in rows.items():
        print(f"  {name:<{w}}  {desc}")
    return 0


def cmd_bench(args) -> int:
    from .benches import BENCHES, print_rows, run_bench

    if args.name not in BENCHES:
        return fail(f"bench {args.name!r} is not known; available: {', '.join(BENCHES)}.")
    try:
        plot = str(Path(args.json).with_suffix(".png")) if args.json else None
        rows = run_bench(args.name, quick=args.quick, plot_path=plot)
    except ScenarioError as exc:
        return fail(str(exc))
    print_rows(rows)
    if args.json:
        Path(args.json).write_text(json.dumps({"bench": args.name, "rows": rows}, indent=2, default=float) + "\n")
    return 0 if all(r.get("pass", True) for r in rows) else 1


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stand", description="Hardware-in-the-loop test stand for spacecraft ADCS.",
                                epilog=EXIT_CODES, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    r = sub.add_parser("run", help="run a scenario (default: the detumble on emulated CAN devices)")
    r.add_argument("scenario", nargs="?",
                   help="scenario file, or a shipped name (`stand scenarios`; default: detumble)")
    r.add_argument("--out", help="output directory (default: runs/NAME-TIME)")
    r.add_argument("--speed", default=None, help="afap, realtime, or a factor such as 10 (default: afap; realtime "
                   "when a device is on a hardware or served link)")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario value, e.g. --set devices.mtq.channel=can1 (repeatable)")
    r.add_argument("--duration", type=float, help="simulated seconds (default: the scenario's)")
    r.add_argument("--seed", type=int, help="random seed (default: the scenario's)")
    r.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="show a progress bar (default: when stderr is a terminal)")
    # A short run spends most of its wall time drawing (about 2 s of matplotlib whatever the run's length): a
    # pipeline that reads only summary.json and the telemetry leaves the drawing out.
    r.add_argument("--plots", action=argparse.BooleanOptionalAction, default=True,
                   help="draw the PNG plots and report.md after the run (default); --no-plots leaves them out (the "
                   "summary, telemetry, events and log are the same)")
    r.add_argument("--view", nargs="?", const="", metavar="HOST:PORT",
                   help="serve the operator page live while the run goes (default 127.0.0.1 and a free port, "
                   "printed); another address needs --view-token")
    r.add_argument("--view-token", default=os.environ.get("STAND_VIEW_TOKEN"),
                   help="token the page must give to pause, resume or stop the run (default: $STAND_VIEW_TOKEN)")
    r.add_argument("--view-linger-s", type=_linger_seconds, default=None, metavar="SECONDS",
                   help="with --view: keep serving the finished run's page this long (default: until Ctrl-C when "
                   "run from a terminal, else not at all; inf: until Ctrl-C or SIGTERM)")
    r.add_argument("--allow-remote", action="append", default=[], metavar="HOST",
                   help="let devices reach this host or multicast group beyond this machine (repeatable; default: "
                        "loopback and link-local multicast only)")
    r.add_argument("--campaign", metavar="DIR", help="re-run one case of this campaign (with --case)")
    r.add_argument("--case", type=int, metavar="K", help="the case index to re-run (with --campaign)")
    r.set_defaults(func=cmd_run)

    c = sub.add_parser("check", help="validate a scenario; list the models built and left out, and why")
    c.add_argument("scenario")
    c.add_argument("--json", action="store_true", help="print JSON")
    c.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a scenario value")
    c.set_defaults(func=cmd_check)

    s = sub.add_parser("scenarios", help="list the shipped scenarios with their descriptions")
    s.set_defaults(func=cmd_scenarios)

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
    _verbosity_flags(p, 0)
    for command in sub.choices.values():  # `stand run -v ...` as well as `stand -v run ...`
        _verbosity_flags(command, argparse.SUPPRESS)
    return p


def _verbosity_flags(p: argparse.ArgumentParser, default) -> None:
    """-v/-q: what the stand's loggers print on the console (stand.logs.console); every run logs to RUN/stand.log."""
    p.add_argument("-v", "--verbose", action="count", default=default,
                   help="say more on the console: -v notable events (INFO), -vv debugging (DEBUG)")
    p.add_argument("-q", "--quiet", action="store_true", default=False if default == 0 else default,
                   help="print only errors from the stand's loggers (the verdict is still printed)")


def main(argv=None) -> int:
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        from .logs import Console

        console = Console(-1 if args.quiet else args.verbose)
        try:
            return args.func(args)
        finally:
            console.close()
    except KeyboardInterrupt:
        print("stand: interrupted", file=sys.stderr)
        return EXIT_STOPPED
    except BrokenPipeError:  # the reader of our output went away (stand ... | head): nothing left to say
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
