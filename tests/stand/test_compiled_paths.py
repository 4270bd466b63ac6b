"""compiled_paths: the one list of the hot paths compiled by Cython, the choice of build each process makes, and the
record of it in every run's summary.json."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

import compiled_paths
from tests.oracles import require_compiled
from tests.stand.test_cli import run_cli

CHOICE = "import json, compiled_paths; print(json.dumps(compiled_paths.active()))"


def _active_in_a_new_process(**env: str) -> dict:
    out = subprocess.run([sys.executable, "-c", CHOICE], env={**os.environ, **env}, capture_output=True, text=True,
                         check=True, timeout=60)
    return json.loads(out.stdout)


def test_every_listed_module_is_a_plain_module_and_its_twin_is_the_same_source() -> None:
    for name in compiled_paths.MODULES:
        twin = require_compiled(name)
        assert twin.__name__ == compiled_paths.twin(name) and compiled_paths.is_compiled(twin)
        plain = __import__(name, fromlist=["_"])
        assert not compiled_paths.is_compiled(plain)
        # the classes and functions the module defines (not what it imports, nor C-only constants)
        public = {n for n, v in vars(plain).items() if not n.startswith("_") and getattr(v, "__module__", "") == name}
        assert public and public <= set(dir(twin)), (name, public - set(dir(twin)))


def test_stand_native_0_runs_the_plain_python_of_every_path() -> None:
    assert _active_in_a_new_process(STAND_NATIVE="0") == dict.fromkeys(compiled_paths.MODULES, "python")
    for name in compiled_paths.MODULES:
        require_compiled(name)
    assert _active_in_a_new_process(STAND_NATIVE="1") == dict.fromkeys(compiled_paths.MODULES, "compiled")


def test_only_listed_modules_load() -> None:
    with pytest.raises(ValueError, match="'sim.truth' is not a compiled path; compiled_paths.MODULES lists"):
        compiled_paths.load("sim.truth")
    assert compiled_paths.twin("drivers.can_node") == "drivers._can_node_compiled"


def test_the_summary_records_which_paths_ran_compiled(scenario_dict, write_scenario, capsys, tmp_path) -> None:
    scenario_dict["scenario"]["duration_s"] = 2.0
    code, _, _ = run_cli(["run", "--no-plots", str(write_scenario(scenario_dict)), "--out", str(tmp_path / "o")],
                         capsys)
    assert code in (0, 1)
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["compiled_paths"] == compiled_paths.active()
    assert set(summary["compiled_paths"]) == set(compiled_paths.MODULES)


def test_the_record_imports_no_path_the_run_did_not_load_and_says_what_loading_it_would_give() -> None:
    # A detumble never needs the star tracker's matching; its package took 0.3 s to import when the record loaded
    # every path, which every run and every campaign case paid.
    probe = ("import json, sys, compiled_paths; before = compiled_paths.active(); "
             "unloaded = [n for n in compiled_paths.MODULES if n.split('.')[0] not in sys.modules]; "
             "[compiled_paths.load(n) for n in compiled_paths.MODULES]; "
             "print(json.dumps([before, compiled_paths.active(), unloaded]))")
    for native in ("0", "1"):
        out = subprocess.run([sys.executable, "-c", probe], env={**os.environ, "STAND_NATIVE": native},
                             capture_output=True, text=True, check=True, timeout=60)
        before, after, unloaded = json.loads(out.stdout)
        assert unloaded == list(compiled_paths.MODULES)  # active() imported none of them
        assert before == after  # and said what load() then chose
