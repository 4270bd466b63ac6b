"""``stand fault``: inject, clear or list faults in a run that is going on with ``stand run --view``.

    stand fault RUN_DIR inject --device rw2 --type wheel_seized [--param K=V ...] [--duration-s X] [--name N]
    stand fault RUN_DIR inject --device st1 --type frame_drop --param probability=0.5 --param direction=to_host
    stand fault RUN_DIR clear NAME
    stand fault RUN_DIR list [--json]

The command finds the live page's address and token in ``RUN_DIR/view_url.json`` (written when the page starts,
readable by the user only, removed when the run ends) and calls its ``/api/faults`` endpoint, under the same
rules as the page's own controls. A ``--param`` value is read as a TOML value (``0.5``, ``[0.1, 0, 0]``,
``true``, ``"text"``), else taken as text. The fault acts from the run's next tick; the event log records it
(``fault_injected``, ``fault_cleared``). Exit codes: 0 done, 2 a usage error or a fault the run refused (one
sentence naming the field and what is allowed), 3 the run's page could not be reached or did not answer.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tomllib
import urllib.error
import urllib.request
from pathlib import Path

EXIT_OK, EXIT_USAGE, EXIT_UNREACHABLE = 0, 2, 3
#: Longest wait for the page's answer: it waits up to 10 s for the run's (stand.view.state.FAULT_ANSWER_S).
TIMEOUT_S = 15.0


class FaultCommandError(Exception):
    """One sentence for the user, with the exit code."""

    def __init__(self, message: str, code: int = EXIT_USAGE):
        super().__init__(message)
        self.code = code


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("fault", help="inject, clear or list faults in a run going on with --view",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("run_dir", help="the folder of a run started with `stand run --view`")
    p.add_argument("--token", default=None,
                   help="the page's token (default: the one in RUN_DIR/view_url.json, else $STAND_VIEW_TOKEN)")
    sub = p.add_subparsers(dest="action", required=True, metavar="inject|clear|list")
    inj = sub.add_parser("inject", help="inject a fault now")
    inj.add_argument("--device", required=True, help="the device the fault acts on (a protocol fault: its line or "
                     "bus)")
    inj.add_argument("--type", required=True, help="the fault type (`stand fault RUN_DIR list` shows them)")
    inj.add_argument("--param", action="append", default=[], metavar="K=V",
                     help="a parameter of the fault type, e.g. --param bias_deg_s=[0.5,0,0] (repeatable)")
    inj.add_argument("--duration-s", type=float, help="clear the fault after this many simulated seconds "
                     "(default: until cleared or the end)")
    inj.add_argument("--name", help="the fault's name (default: DEVICE_TYPE)")
    clr = sub.add_parser("clear", help="clear an injected fault")
    clr.add_argument("name", help="the fault's name (as `inject` printed it)")
    lst = sub.add_parser("list", help="the faults injected so far and the fault types")
    lst.add_argument("--json", action="store_true", help="print the endpoint's JSON")
    p.set_defaults(func=run)
    return p


def _value(text: str):
    """A --param value as TOML reads it (numbers, arrays, booleans, quoted strings), else the text itself."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def fault_table(args) -> dict:
    """The [[faults]] table that ``inject``'s options describe."""
    table: dict = {"device": args.device, "type": args.type}
    for item in args.param:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise FaultCommandError(f"--param {item!r} is not allowed: KEY=VALUE, e.g. --param rate=0.5.")
        if key in ("device", "type", "name", "duration_s"):
            raise FaultCommandError(f"--param {item!r} is not allowed: {key} has its own option "
                                    f"(--{key.replace('_', '-')}).")
        table[key] = _value(text.strip())
    if args.duration_s is not None:
        table["duration_s"] = args.duration_s
    if args.name is not None:
        table["name"] = args.name
    return table


def locate(run_dir, token: str | None = None) -> tuple[str, str | None]:
    """(base URL to call, token) of the live page serving ``run_dir``."""
    path = Path(run_dir) / "view_url.json"
    try:
        info = json.loads(path.read_text())
        url = info.get("connect") or info["url"]
    except FileNotFoundError:
        if not Path(run_dir).is_dir():
            raise FaultCommandError(f"run folder {run_dir} does not exist.") from None
        raise FaultCommandError(f"{run_dir} has no live page ({path.name} is missing): start the run with "
                                "`stand run ... --view`, or the run has already ended.") from None
    except (OSError, ValueError, KeyError, AttributeError) as exc:
        raise FaultCommandError(f"{path} cannot be used ({type(exc).__name__}: {exc}); it is written by "
                                "`stand run --view` while the run goes on.") from None
    return url.rstrip("/"), token or info.get("token") or os.environ.get("STAND_VIEW_TOKEN")


def call(base: str, token: str | None, body: dict | None = None, timeout_s: float = TIMEOUT_S) -> dict:
    """GET (no body) or POST ``/api/faults``; the JSON answer, or FaultCommandError with the page's sentence."""
    headers = {"Content-Type": "application/json"} if body is not None else {}
    if token:
        headers["X-Stand-Token"] = token
    data = json.dumps(body).encode() if body is not None else None
    req = urllib.request.Request(base + "/api/faults", data=data, headers=headers,
                                 method="POST" if body is not None else "GET")
    try:
        with urllib.request.urlopen(req, timeout=timeout_s) as resp:
            return json.loads(resp.read())
    except urllib.error.HTTPError as exc:
        try:
            why = json.loads(exc.read()).get("error")
        except (ValueError, AttributeError, OSError):
            why = None
        code = EXIT_USAGE if exc.code in (400, 403, 404, 409) else EXIT_UNREACHABLE
        raise FaultCommandError(f"the run refused: {why or exc.reason} (HTTP {exc.code}).", code) from None
    except (urllib.error.URLError, OSError, ValueError) as exc:
        reason = getattr(exc, "reason", exc)
        raise FaultCommandError(f"the run's page at {base} cannot be reached ({reason}); has the run ended?",
                                EXIT_UNREACHABLE) from None


def _print_list(answer: dict) -> None:
    faults = answer.get("faults", [])
    if not faults:
        print("no fault injected so far")
    for f in faults:
        when = f"from t = {f['injected_s']:.3f} s" if isinstance(f.get("injected_s"), int | float) else ""
        until = ("active" if f.get("active") else
                 f"cleared at t = {f['cleared_s']:.3f} s" if isinstance(f.get("cleared_s"), int | float) else "cleared")
        params = ", ".join(f"{k}={v}" for k, v in (f.get("params") or {}).items())
        print(f"{f.get('name')}: {f.get('type')} on {f.get('device')} {when}, {until}" + (f" ({params})" if params
                                                                                          else ""))
    for f in answer.get("scheduled", []):
        print(f"scheduled by the scenario: {f.get('when')}")
    types = answer.get("types", [])
    if types:
        print("fault types: " + ", ".join(t["name"] for t in types))


def run(args) -> int:
    try:
        if args.action == "inject":
            body = {"action": "inject", "fault": fault_table(args)}
        elif args.action == "clear":
            body = {"action": "clear", "name": args.name}
        else:
            body = None
        base, token = locate(args.run_dir, args.token)
        answer = call(base, token, body)
    except FaultCommandError as exc:
        print(f"stand: error: {exc}", file=sys.stderr)
        return exc.code
    if body is None:
        if args.json:
            print(json.dumps(answer, indent=1))
        else:
            _print_list(answer)
    else:
        print(f"{'injected' if body['action'] == 'inject' else 'cleared'} {answer.get('name')}")
    return EXIT_OK
