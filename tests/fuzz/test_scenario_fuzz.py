"""Nothing a scenario file holds can crash, hang or fill the machine, or make the stand lie (issue 11).

Every field of every shipped scenario is replaced by values of other types, non-finite, huge, negative, empty
and nested values; files are fed random bytes, byte-order marks, UTF-16, deep nesting and unknown keys. The only
exception allowed out of ``stand.scenario.load`` is ``ScenarioError``, and the command line answers exit 2 with
one line. Accepted mutants are built and run briefly: building raises nothing but the stand's own errors, and a
run never passes with nothing simulated.

The mutation tables are exhaustive and deterministic; the Hypothesis tests are bounded (``max_examples``) and run
derandomised under CI (tests/conftest.py).
"""

from __future__ import annotations

import copy
import datetime as dt
import json
import math
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.errors import DriverError
from stand import compose, scenario
from stand.adcs import PluginError
from stand.errors import ScenarioError

ROOT = Path(__file__).resolve().parents[2]
# The shipped scenarios (the folder also holds a campaign's dispersion file, which is not a scenario).
SHIPPED = sorted(scenario.SCENARIO_DIR / f"{name}.toml" for name in scenario.shipped())
#: Scenarios that run on emulated devices only (the others open real ports: they may fail, with a DriverError).
EMULATED = ("detumble", "detumble_duty_cycled", "detumble_igrf", "detumble_star_tracker")

#: Values of every TOML type, and the edges of each: what replaces a field.
REPLACEMENTS = [
    "", "x", "x" * 5000, "é\u202e\U0001f680", "a\x00b", "../../etc/passwd", "nan",
    0, 1, -1, 2**63 - 1, -(2**63), 2**200,
    0.0, -0.0, 0.5, -1.5, 1e-320, 1e308, -1e308, math.nan, math.inf, -math.inf,
    True, False,
    [], [1], [1.0, 2.0, 3.0], [1.0, 0.0, 0.0, 0.0, 0.0], ["a", "b", "c"], [[1.0, 0.0], [0.0, 1.0]], [[[[]]]],
    [math.nan, 0.0, 0.0], [1e308, 1e308, 1e308], [True, False, True],
    {}, {"a": 1}, {"x": {"y": [1, 2]}},
    dt.datetime(2026, 3, 20, 12, 0, tzinfo=dt.UTC), dt.datetime(2026, 3, 20, 12, 0), dt.date(2026, 3, 20),
    dt.time(12, 0),
]


def shipped_data(path: Path) -> dict:
    return tomllib.loads(path.read_text(encoding="utf-8"))


def leaf_paths(node, prefix=()) -> list[tuple]:
    """Every value and every table of a scenario, as a path of keys and list indices."""
    out = [prefix] if prefix else []
    if isinstance(node, dict):
        for k, v in node.items():
            out += leaf_paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += leaf_paths(v, (*prefix, i))
    return out


def replaced(data: dict, path: tuple, value) -> dict:
    out = copy.deepcopy(data)
    node = out
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = copy.deepcopy(value)
    return out


def parse_or_refuse(data: dict, source: str = "fuzz.toml"):
    """The parsed scenario, or None when refused with a ScenarioError (one line, naming the file)."""
    try:
        return scenario.parse(data, source)
    except ScenarioError as exc:
        text = str(exc)
        assert "\n" not in text and source in text and len(text) < 2000, text
        return None


def same_as_shipped(shipped: dict, data: dict) -> bool:
    """``data`` equals the shipped file's ``shipped`` (read once by the caller, never mutated: ``replaced`` copies)."""
    return data == shipped


# --- types, ranges and sizes: every field of every shipped scenario ------------------------------------------------

@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_every_field_replaced_by_every_kind_of_value(path):
    data = shipped_data(path)
    accepted = []
    for where in leaf_paths(data):
        for value in REPLACEMENTS:
            mutant = replaced(data, where, value)
            if parse_or_refuse(mutant) is not None and not same_as_shipped(data, mutant):
                accepted.append((where, value))
    # Non-finite numbers are never accepted anywhere, and neither are NUL bytes.
    for where, value in accepted:
        assert not (isinstance(value, float) and not math.isfinite(value)), (where, value)
        assert value != "a\x00b", where


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_fields_removed_and_unknown_keys_added(path):
    data = shipped_data(path)
    for where in leaf_paths(data):
        mutant = copy.deepcopy(data)
        node = mutant
        for key in where[:-1]:
            node = node[key]
        if isinstance(node, dict):
            del node[where[-1]]
            parse_or_refuse(mutant)
    for where in [()] + [p for p in leaf_paths(data) if isinstance(_at(data, p), dict)]:
        mutant = copy.deepcopy(data)
        _at(mutant, where)["no_such_key_s"] = 1.0
        with pytest.raises(ScenarioError, match="not known here"):
            scenario.parse(mutant, "fuzz.toml")


def _at(data, path):
    for key in path:
        data = data[key]
    return data


# --- the same mutations written as files, through stand.scenario.load ---------------------------------------------

def toml_value(v) -> str:
    """A value in TOML syntax (inline tables and arrays): enough to write any mutant as a file."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(v, dt.datetime | dt.date | dt.time):
        return v.isoformat()
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return "{" + ", ".join(f"{json.dumps(k)} = {toml_value(x)}" for k, x in v.items()) + "}"


def toml_text(data: dict) -> str:
    return "".join(f"{json.dumps(k)} = {toml_value(v)}\n" for k, v in data.items())


def test_toml_writer_round_trips_the_shipped_scenarios():
    for path in SHIPPED:
        data = shipped_data(path)
        assert tomllib.loads(toml_text(data)) == data


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_mutated_files_through_load(path, tmp_path):
    data = shipped_data(path)
    target = tmp_path / "fuzz.toml"
    for i, where in enumerate(leaf_paths(data)):
        for value in REPLACEMENTS[i % 4::4]:  # a quarter of the table per field, a different quarter each time
            target.write_text(toml_text(replaced(data, where, value)), encoding="utf-8")
            try:
                scenario.load(target)
            except ScenarioError as exc:
                assert "\n" not in str(exc) and "fuzz.toml" in str(exc)


# --- random structure (Hypothesis) ---------------------------------------------------------------------------------

toml_scalars = st.one_of(
    st.text(max_size=40), st.integers(min_value=-(2**80), max_value=2**80), st.floats(allow_nan=True),
    st.booleans(), st.datetimes(timezones=st.just(dt.UTC)), st.dates(), st.times(),
)
toml_values = st.recursive(toml_scalars, lambda inner: st.lists(inner, max_size=5)
                           | st.dictionaries(st.text(max_size=12), inner, max_size=4), max_leaves=20)
#: Examples per Hypothesis test; STAND_FUZZ_EXAMPLES raises it for a longer local hunt.
FUZZ = settings(max_examples=int(os.environ.get("STAND_FUZZ_EXAMPLES", "150")), deadline=None,
                suppress_health_check=[HealthCheck.too_slow])


@FUZZ
@given(which=st.sampled_from(SHIPPED), data=st.data(), value=toml_values)
def test_random_value_at_a_random_field(which, data, value):
    base = shipped_data(which)
    where = data.draw(st.sampled_from(leaf_paths(base)))
    parse_or_refuse(replaced(base, where, value))


@FUZZ
@given(which=st.sampled_from(SHIPPED), data=st.data(), n=st.integers(1, 4))
def test_several_fields_swapped_between_scenarios(which, data, n):
    """Values that are valid somewhere, moved to other fields (right type, wrong place or range)."""
    base = shipped_data(which)
    donor = shipped_data(data.draw(st.sampled_from(SHIPPED)))
    mutant = base
    for _ in range(n):
        where = data.draw(st.sampled_from(leaf_paths(mutant)))
        value = _at(donor, data.draw(st.sampled_from(leaf_paths(donor))))
        mutant = replaced(mutant, where, value)
    parse_or_refuse(mutant)


@FUZZ
@given(doc=st.dictionaries(st.text(max_size=10), toml_values, max_size=6))
def test_random_documents(doc):
    parse_or_refuse(doc)


# --- encodings, sizes and nesting, through files -------------------------------------------------------------------

def load_file(tmp_path: Path, content: bytes):
    p = tmp_path / "fuzz.toml"
    p.write_bytes(content)
    try:
        return scenario.load(p)
    except ScenarioError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 2000
        return None


@settings(max_examples=200, deadline=None)
@given(content=st.binary(max_size=2000))
def test_random_bytes(tmp_path_factory, content):
    assert load_file(tmp_path_factory.mktemp("b"), content) is None


def test_encodings_and_byte_order_marks(tmp_path):
    text = (scenario.SCENARIO_DIR / "detumble.toml").read_text(encoding="utf-8")
    assert load_file(tmp_path, text.encode("utf-8")) is not None
    for content in (b"\xef\xbb\xbf" + text.encode("utf-8"), text.encode("utf-16"), text.encode("utf-16-le"),
                    text.encode("utf-32"), text.encode("latin-1", "replace") + b"\xff", b"\x00" * 1000,
                    text.encode("utf-8").replace(b"detumble", b"d\xc3\x28", 1)):
        assert load_file(tmp_path, content) is None


@pytest.mark.parametrize("depth", [10, 100, 1000, 100_000])
def test_deep_nesting(tmp_path, depth):
    base = (scenario.SCENARIO_DIR / "detumble.toml").read_text(encoding="utf-8")
    for nested in ("[" * depth + "]" * depth, "{a = " * depth + "1" + "}" * depth):
        content = base.replace("q_BN = [1.0, 0.0, 0.0, 0.0]", "q_BN = " + nested)
        if len(content) < scenario.MAX_FILE_BYTES:
            assert load_file(tmp_path, content.encode()) is None
        deep_tables = "\n".join(f"[{'.'.join(['t'] * k)}]" for k in range(1, min(depth, 300)))
        assert load_file(tmp_path, (base + deep_tables).encode()) is None


def test_sizes(tmp_path):
    base = (scenario.SCENARIO_DIR / "detumble.toml").read_text(encoding="utf-8")
    big_list = "[" + ", ".join(["1.0"] * 100_000) + "]"
    assert load_file(tmp_path, base.replace("[1.0, 0.0, 0.0, 0.0]", big_list, 1).encode()) is None
    long_text = base.replace('name = "detumble"', 'name = "' + "n" * 500_000 + '"', 1)
    assert load_file(tmp_path, long_text.encode()) is None
    assert load_file(tmp_path, (base + "#" * scenario.MAX_FILE_BYTES).encode()) is None
    many_devices = base + "\n".join(f'[[devices]]\nname = "d{k}"\nkind = "sun_sensor"\ntype = "coarse"\n'
                                    for k in range(2000))
    load_file(tmp_path, many_devices.encode())


# --- the command line: exit 2 with one line, never a traceback -----------------------------------------------------

CLI_CASES = {
    "random_bytes": bytes(range(256)) * 4,
    "utf16": (scenario.SCENARIO_DIR / "detumble.toml").read_text().encode("utf-16"),
    "deep": (scenario.SCENARIO_DIR / "detumble.toml").read_text().replace(
        "q_BN = [1.0, 0.0, 0.0, 0.0]", "q_BN = " + "[" * 50_000 + "]" * 50_000).encode(),
    "nan": (scenario.SCENARIO_DIR / "detumble.toml").read_text().replace("mass_kg = 4.0", "mass_kg = nan").encode(),
    "nul_name": (scenario.SCENARIO_DIR / "detumble.toml").read_text().replace(
        'name = "detumble"', 'name = "a\\u0000b"').encode(),
    "tiny_step": (scenario.SCENARIO_DIR / "detumble.toml").read_text().replace(
        "duration_s = 5677.0", "duration_s = 2592000.0").replace("step_s = 0.1\n", "step_s = 1e-6\n", 1).replace(
        "[recording]\nrate_hz = 10.0", "[recording]\nrate_hz = 0.1").encode(),
}


@pytest.mark.parametrize("case", sorted(CLI_CASES))
def test_cli_check_exits_2_with_one_line(tmp_path, case):
    p = tmp_path / f"{case}.toml"
    p.write_bytes(CLI_CASES[case])
    done = subprocess.run([sys.executable, "-m", "stand.cli", "check", str(p)], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 2, (done.stdout, done.stderr)
    assert "Traceback" not in done.stderr and done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith("stand: error: ")
    assert CLI_NAMED[case] in done.stderr, done.stderr


#: What each command-line case's sentence names.
CLI_NAMED = {"random_bytes": "UTF-8", "utf16": "UTF-8", "deep": "nested", "nan": "spacecraft.mass_kg = nan",
             "nul_name": "scenario.name", "tiny_step": "dynamics.step_s = 1e-06"}


# --- accepted mutants build and run, and never pass with nothing simulated -----------------------------------------

NUMERIC_NUDGES = (0.5, 2.0, 10.0, 1e-3)


def accepted_mutants(limit: int) -> list[tuple[str, tuple, object, object]]:
    """A deterministic sample of accepted mutants of the emulated scenarios: numbers scaled, lists and
    booleans from the replacement table."""
    out = []
    for name in EMULATED:
        path = scenario.SCENARIO_DIR / f"{name}.toml"
        data = shipped_data(path)
        for where in leaf_paths(data):
            value = _at(data, where)
            if isinstance(value, bool):
                candidates = [not value]
            elif isinstance(value, int | float):
                candidates = [type(value)(value * f) if isinstance(value, float) else value * 2 for f in
                              NUMERIC_NUDGES] + [0, -value]
            else:
                candidates = [v for v in REPLACEMENTS if isinstance(v, list) and v]
            for v in candidates:
                mutant = replaced(data, where, v)
                if same_as_shipped(data, mutant):
                    continue
                sc = parse_or_refuse(mutant)
                if sc is not None:
                    out.append((name, where, v, sc))
    step = max(1, len(out) // limit)
    return out[::step][:limit]


def test_accepted_mutants_build_and_run(tmp_path):
    from stand.loop import run
    from stand.report import write_summary

    sample = accepted_mutants(12)
    assert len(sample) == 12
    for k, (name, where, value, sc) in enumerate(sample):
        duration = min(sc.duration_s, max(10 * sc.step_s, 1.0))
        try:
            compose.check_budget(sc, duration, tmp_path)
            scene = compose.build(sc, None, scenario.SCENARIO_DIR)
        except (ScenarioError, PluginError, DriverError) as exc:
            assert "\n" not in str(exc), (name, where, value, exc)
            continue
        with scene:
            out = tmp_path / f"run{k}"
            result = run(scene, out, duration_s=duration)
            summary = write_summary(scene, result, out, plots=False)  # the plots have tests of their own
        assert result.ticks >= 1 and result.sim_duration_s > 0, (name, where, value, result)
        if summary["pass"]:
            assert result.status == "completed" and summary["sim_duration_s"] > 0, (name, where, value)


# --- overrides from the command line (--set KEY=VALUE) -------------------------------------------------------------

set_keys = st.lists(st.sampled_from(["scenario", "dynamics", "orbit", "devices", "mtq", "controller", "criteria",
                                     "name", "step_s", "rate_hz", "", "0", "x"]) | st.text(max_size=6),
                    min_size=1, max_size=4).map(".".join)
set_values = st.text(max_size=30) | st.sampled_from(["nan", "inf", "-inf", "1e999", "[1, [2]]", "{a = 1}", "true",
                                                     '"\\u0000"', "1979-05-27T07:32:00Z", "[[[[[[]]]]]]"])


@FUZZ
@given(items=st.lists(st.tuples(set_keys, set_values), min_size=1, max_size=3))
def test_random_overrides(items):
    data = shipped_data(scenario.DEFAULT_SCENARIO)
    try:
        for key, value in items:
            scenario.set_value(data, f"{key}={value}")
    except ScenarioError as exc:
        assert "\n" not in str(exc)
        return
    parse_or_refuse(data)


# --- --set paths of every shipped scenario, nested wrongly, and odd numbers at every rate and time (issue 22) --------

def set_paths(node, prefix=()) -> list[str]:
    """Every dotted --set key of a scenario, list entries by their name (by index where they have none)."""
    out = [".".join(prefix)] if prefix else []
    if isinstance(node, dict):
        for k, v in node.items():
            out += set_paths(v, (*prefix, str(k)))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += set_paths(v, (*prefix, str(v.get("name", i)) if isinstance(v, dict) else str(i)))
    return out


#: Numbers no rate or time may take: subnormal (whose inverse is infinite), infinite, not a number.
ODD_NUMBERS = ["5e-324", "1e-310", "-1e-310", "2.2e-308", "inf", "-inf", "nan"]
ODD_VALUES = [*ODD_NUMBERS, "", "0", "-0.0", "1e308", "9223372036854775807", "[]", "{}", "{a = 1}", "[1e-310, 0, 0]",
              "[[1]]", "x", "true", "2026-01-01T00:00:00Z"]


def check_or_refuse(name: str, items: list[str]):
    """What ``stand check`` does (load with the overrides, then the plan), or None when refused in one sentence."""
    try:
        return compose.plan(scenario.load(name, items))
    except (ScenarioError, PluginError) as exc:
        assert "\n" not in str(exc) and "Traceback" not in str(exc), str(exc)
        return None


@pytest.mark.parametrize("item", ["devices.mtq=3", "devices.mtq.link.x=1", "devices.mtq.q_SB.x=1", "a..b=1", ".x=1",
                                  "x.=1", "orbit=", "devices=3", "devices.nope=1", "devices.0.name=1",
                                  "scenario.name.x=1", "controller.rate_hz=1e-310", "controller.rate_hz=5e-324",
                                  "recording.rate_hz=5e-324", "devices.mtq.sample_rate_hz=5e-324",
                                  "controller.rate_hz=inf", "controller.rate_hz=nan", "scenario.duration_s=5e-324"])
def test_set_items_of_the_issue_exit_2_with_one_sentence(item, capsys):
    from stand.cli import main

    assert main(["check", "detumble", "--set", item]) == 2
    err = capsys.readouterr().err
    assert err.startswith("stand: error: ") and err.count("\n") == 1 and "Traceback" not in err, err


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_odd_numbers_at_every_rate_and_time_are_refused(path):
    for key in set_paths(shipped_data(path)):
        if key.rsplit(".", 1)[-1].endswith(("_hz", "_s")):
            for value in ODD_NUMBERS:
                if value == "2.2e-308":  # the smallest normal double is a number like any other
                    continue
                assert check_or_refuse(path.stem, [f"{key}={value}"]) is None, (key, value)


def test_a_rate_too_small_to_invert_names_the_field():
    with pytest.raises(ScenarioError, match=r"devices\[1\]\.rate_hz = 5e-324 .*subnormal"):
        scenario.load("acquisition", ["devices.css.rate_hz=5e-324"])
    with pytest.raises(ScenarioError, match=r"controller\.rate_hz = 1e-300 .*a rate whose period is at most"):
        scenario.load("detumble", ["controller.rate_hz=1e-300"])


@FUZZ
@given(which=st.sampled_from(SHIPPED), data=st.data(),
       suffix=st.lists(st.sampled_from(["", "x", "0", "name", "mtq", "rate_hz", "duration"]), max_size=2),
       value=st.sampled_from(ODD_VALUES) | st.text(max_size=12))
def test_random_set_paths_of_every_shipped_scenario(which, data, suffix, value):
    key = ".".join([data.draw(st.sampled_from(set_paths(shipped_data(which)))), *suffix])
    check_or_refuse(which.stem, [f"{key}={value}"])
