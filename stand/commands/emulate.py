"""``stand emulate KIND --port PORT``: run one device emulator alone, so a flight computer or a terminal can be
wired to it.

    stand emulate KIND --port PORT [--duration S] [KIND'S OPTIONS]
    stand emulate KIND --port PORT --scenario S [--name NAME] [--speed F] [--out DIR] [--duration S]
    stand emulate KIND --help        (the kind's own options)

Every kind that declares how it is served (``DeviceKind.serving``, :mod:`stand.devices.serving`) can be served,
the shipped ones and those of the ``adcs_stand.devices`` entry point alike: KIND is the kind's name with ``-`` for
``_`` (``star-tracker``, ``sun-sensor``, ``reaction-wheel``, ``gyro``, ``magnetorquer``, ``cage``). The kind says
what ``--port`` is (a serial URL or path, a CAN ``INTERFACE:CHANNEL``, a Modbus endpoint) and which fixed values
it serves open loop. With ``--scenario`` the device is fed by that scenario's truth instead: the scenario runs
paced with the device on a ``served`` link and the flight computer outside. When the scenario's own controller
uses that device (``detumble``'s B-dot and its magnetorquer), the flight computer takes its place
(``controller.kind = "external"``), and the console says so.

Sim time is wall time since start. It stops on Ctrl-C (or SIGTERM) or after ``--duration`` seconds and prints its
counters as one JSON line. Exit codes: 0 stopped normally, 1 a device error (port lost), 2 usage error (a port
another stand or emulator holds is refused as in use: serial ports and serial-line CAN adapters are opened
exclusively). What a flight computer sends that the device cannot decode is counted and dropped, never an error
(``rejected_*`` in the counters printed at the end).
"""

from __future__ import annotations

import argparse
import importlib
import math
import sys

from stand import devices

COMMON = ("--port", "--duration", "--scenario", "--name", "--speed", "--out")


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "emulate",
        help="run one device emulator on a port (every kind that declares how it is served; "
             "`stand emulate KIND --help` for its options)",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("device", help="device kind to emulate, e.g. star-tracker, gyro, sun-sensor, reaction-wheel, "
                                  "magnetorquer, cage")
    p.add_argument("options", nargs=argparse.REMAINDER,
                   help="--port PORT and the kind's options (`stand emulate KIND --help` lists them)")
    p.set_defaults(func=run)
    return p


def _fail(msg: str) -> int:
    print(f"stand emulate: error: {msg}", file=sys.stderr)
    return 2


def servable() -> dict[str, str]:
    """``stand emulate`` names -> kind names, for every kind that declares how it is served."""
    out = {}
    for name in devices.kind_names():
        try:
            kind = devices.get(name)
        except Exception:  # noqa: BLE001 - a broken plug-in kind is not listed; `stand emulate` of it says why
            continue
        if getattr(kind, "serving", None) is not None:
            out[name.replace("_", "-")] = name
    return out


class UsageError(Exception):
    pass


class _KindParser(argparse.ArgumentParser):
    """A usage error becomes one sentence and exit status 2 through ``_fail`` (the caller may be a test in the
    same process, not a shell)."""

    def error(self, message):
        raise UsageError(message)


def kind_parser(command: str, serving) -> argparse.ArgumentParser:
    """The options of ``stand emulate COMMAND``: the common ones, then the kind's declared ones."""
    p = _KindParser(prog=f"stand emulate {command}", description=serving.summary)
    p.add_argument("--port", required=True, help=serving.port_help)
    p.add_argument("--duration", type=float, default=None, help="stop after S seconds (default: until Ctrl-C)")
    closed = p.add_argument_group("closed loop (fed by a scenario's truth)")
    closed.add_argument("--scenario", default=None,
                        help="the stand runs this scenario paced with this device served on --port and the flight "
                             "computer outside; without it the emulator runs open loop")
    closed.add_argument("--name", default=None, help="which device of that kind (default: the first)")
    closed.add_argument("--speed", default=None, help="realtime (default) or a factor")
    closed.add_argument("--out", default=None, help="the run's output directory")
    groups = {}
    for opt in serving.options:
        where = p if opt.group is None else groups.setdefault(opt.group, p.add_argument_group(opt.group))
        kw = {"help": opt.help, "default": opt.default, "type": opt.type}
        if opt.choices is not None:
            kw["choices"] = opt.choices
        where.add_argument(opt.flag, **kw)
    return p


def _resolve(serve):
    if isinstance(serve, str):  # "module:function", imported on use
        module, _, attr = serve.partition(":")
        return getattr(importlib.import_module(module), attr)
    return serve


def run_served(args, kind, serving) -> int:
    """The closed-loop path: the scenario runs paced with this device served on --port (link = "served"), the
    rest of the scenario as it is; the same path as ``stand run`` of a scenario with a served device."""
    from stand import scenario as scenario_mod
    from stand.cli import main as stand_main
    from stand.errors import ScenarioError

    if serving.port_fields is None:
        return _fail(f"--scenario is not available for {args.device!r}: it serves open loop only.")
    try:
        fields = serving.port_fields(args.port, args)
    except ValueError as exc:
        return _fail(str(exc))
    try:
        sc = scenario_mod.load(args.scenario)
    except ScenarioError as exc:
        return _fail(str(exc))
    names = [d.name for d in sc.devices if d.kind == kind and (args.name is None or d.name == args.name)]
    if not names:
        return _fail(f"--scenario {args.scenario!r} has no {kind} device" + (f" named {args.name!r}" if args.name
                                                                              else "") + ".")
    name = names[0]
    sets = [f"devices.{name}.link=served"] + [f"devices.{name}.{key}={value}" for key, value in fields.items()]
    try:
        takes_over = _flight_computer_takes_over(args.scenario, sc, sets)
    except ScenarioError as exc:
        return _fail(str(exc))
    print(f"stand emulate: {args.device} {name!r} of scenario {sc.name}, served on {args.port} and fed by the "
          "scenario's truth (closed loop with the flight computer on the other end)", flush=True)
    if takes_over:
        sets.append(EXTERNAL_CONTROLLER)
        print(f"stand emulate: the scenario's controller ({sc.controller.kind}) uses {name}; the flight computer on "
              "the other end takes its place (controller.kind = 'external'): the stand commands nothing, its other "
              "devices run as the scenario has them", flush=True)
    argv = ["run", args.scenario, "--speed", args.speed or "realtime"]
    for item in sets:
        argv += ["--set", item]
    if args.duration is not None:
        argv += ["--duration", str(args.duration)]
    if args.out:
        argv += ["--out", args.out]
    return stand_main(argv)


#: The override that hands the loop to the flight computer outside (an inline table replaces the whole table).
EXTERNAL_CONTROLLER = 'controller={kind = "external"}'


def _flight_computer_takes_over(scenario: str, sc, sets: list[str]) -> bool:
    """Whether the scenario's own controller uses the device about to be served: it then cannot run (its device
    belongs to the flight computer outside), so the flight computer takes its place. Any other refusal of the served
    scenario is the scenario's (ScenarioError)."""
    from stand import controllers
    from stand import scenario as scenario_mod
    from stand.errors import ScenarioError

    try:
        scenario_mod.load(scenario, sets)
        return False
    except ScenarioError as exc:
        if not (exc.field.startswith("controller.") and controllers.get(sc.controller.kind).in_stand):
            raise
    scenario_mod.load(scenario, [*sets, EXTERNAL_CONTROLLER])  # what remains wrong is the scenario's: said as is
    return True


def _unknown_options(command: str, kind: str, unknown: list[str], kinds: dict[str, str]) -> str:
    """One sentence for options the kind does not take, naming the kinds that do."""
    flag = next((u.partition("=")[0] for u in unknown if u.startswith("-")), unknown[0])
    owners = [k.replace("_", " ") for k in kinds.values()
              if any(o.flag == flag for o in devices.get(k).serving.options)]
    where = f"; it is for the {' and the '.join(owners)} only" if owners else ""
    return (f"{flag} is not an option of the {kind.replace('_', ' ')}{where} (`stand emulate {command} --help` "
            "lists its options).")


def run(args) -> int:
    kind = args.device.replace("-", "_")
    serving = None
    if kind in devices.kind_names():
        try:
            serving = getattr(devices.get(kind), "serving", None)
        except Exception as exc:  # noqa: BLE001 - an installed kind that does not import: say so, in one sentence
            return _fail(f"device kind {kind!r} cannot be loaded: {type(exc).__name__}: {exc}.")
    kinds = servable()
    if serving is None:
        why = "declares no way to be served" if kind in devices.kind_names() else "is not known"
        return _fail(f"device {args.device!r} {why}; available: {', '.join(kinds)}.")
    parser = kind_parser(args.device, serving)
    try:
        opts, unknown = parser.parse_known_args(args.options)
        if unknown:
            return _fail(_unknown_options(args.device, kind, unknown, kinds))
    except UsageError as exc:
        return _fail(f"{exc} (`stand emulate {args.device} --help` lists its options).")
    opts.device = args.device
    if opts.scenario is not None:
        return run_served(opts, kind, serving)
    if opts.duration is not None and not (math.isfinite(opts.duration) and opts.duration > 0):
        return _fail(f"--duration {opts.duration!r} is not allowed; give a positive number of seconds.")
    return _resolve(serving.serve)(opts, _fail)
