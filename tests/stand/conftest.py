import contextlib
import itertools
import subprocess
import time
import tomllib
from pathlib import Path

import pytest

from stand.scenario import DEFAULT_SCENARIO
from tests.oracles import require_tool

_channels = itertools.count()


@pytest.fixture
def scenario_dict():
    """The default scenario as a dict, on a CAN channel of its own (tests share one process)."""
    data = tomllib.loads(Path(DEFAULT_SCENARIO).read_text())
    for d in data.get("devices", []):
        d["channel"] = f"test-{d['name']}-{next(_channels)}"
    return data


def to_toml(data: dict) -> str:
    """Enough TOML writing for scenario dicts (tables, arrays of tables, scalars, lists)."""

    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + "}"
        return repr(v)

    lines = []
    for name, table in data.items():
        if isinstance(table, list):
            for item in table:
                lines.append(f"[[{name}]]")
                lines += [f"{k} = {value(v)}" for k, v in item.items()]
        else:
            lines.append(f"[{name}]")
            lines += [f"{k} = {value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


@pytest.fixture
def write_scenario(tmp_path):
    def write(data: dict, name: str = "scenario.toml") -> Path:
        p = tmp_path / name
        p.write_text(to_toml(data))
        return p

    return write


@contextlib.contextmanager
def socat_pty_pair(where: Path, prefix: str = ""):
    """A socat pty pair (the stand's end, the peer's end) linked in ``where``; socat stops on leaving."""
    require_tool("socat", "socat")
    a, b = where / f"{prefix}stand", where / f"{prefix}peer"
    proc = subprocess.Popen(["socat", f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 5
        while not (a.exists() and b.exists()) and time.monotonic() < deadline:
            time.sleep(0.02)
        yield str(a), str(b)
    finally:
        proc.terminate()
        proc.wait(timeout=5)


@pytest.fixture
def pty_pair(tmp_path):
    """A socat pty pair (the stand's end, the peer's end) for cross-process serial tests; skipped without socat."""
    with socat_pty_pair(tmp_path) as pair:
        yield pair


def run_shipped_without_plots(name: str, duration_s: float, out: Path) -> dict:
    """``stand run NAME --duration DURATION_S --out OUT`` without the PNG plots and report.md; returns the summary.

    For a reference run whose telemetry and summary a test compares against and whose plots it never looks at: on
    3,600 s of detumble_igrf the plots took 19 s against the loop's 30 s (one loaded sitting). The same build and
    loop as the command (``stand.cli._prepare``), so the telemetry is the command's, bit for bit (compared column by
    column on detumble and detumble_igrf), and the same summary.json."""
    from stand import scenario
    from stand.compose import build
    from stand.loop import run
    from stand.report import write_summary

    path = scenario.find(name)
    with build(scenario.load(path), None, path.parent, duration_s=duration_s, out_dir=out) as scene:
        result = run(scene, out, duration_s=duration_s)
        return write_summary(scene, result, out, plots=False, duration_s=duration_s)
