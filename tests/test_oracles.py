"""tests/oracles.py: a missing oracle or compiled path skips on a developer's machine and fails under CI."""

import shutil

import pytest

from tests.oracles import require, require_compiled

ABSENT = "no_such_oracle_module_for_this_test"


def test_a_missing_oracle_skips_locally_and_fails_in_ci(monkeypatch):
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match=ABSENT):
        require(ABSENT)
    for value in ("true", "1", "TRUE"):
        monkeypatch.setenv("CI", value)
        with pytest.raises(pytest.fail.Exception, match=f"CI: {ABSENT} does not import"):
            require(ABSENT)
    monkeypatch.setenv("CI", "false")
    with pytest.raises(pytest.skip.Exception):
        require(ABSENT)


def test_a_present_oracle_is_returned(monkeypatch):
    monkeypatch.setenv("CI", "true")
    assert require("json").dumps([1]) == "[1]"


def test_a_compiled_path_that_did_not_build_fails_wherever_a_compiler_is(monkeypatch):
    import compiled_paths

    monkeypatch.setattr(compiled_paths, "twin", lambda name: "sim._no_such_twin_compiled")
    monkeypatch.delenv("CI", raising=False)
    monkeypatch.setattr(shutil, "which", lambda name: "/usr/bin/cc" if name == "cc" else None)
    with pytest.raises(pytest.fail.Exception, match="sim._no_such_twin_compiled was not built"):
        require_compiled("sim.body_step")
    monkeypatch.setattr(shutil, "which", lambda name: None)
    with pytest.raises(pytest.skip.Exception, match="was not built"):  # no C compiler: nothing could have been built
        require_compiled("sim.body_step")


def test_a_built_twin_is_returned_even_under_stand_native_0(monkeypatch):
    import compiled_paths

    monkeypatch.setenv("STAND_NATIVE", "0")
    monkeypatch.setattr(compiled_paths, "twin", lambda name: "json")  # any importable module stands for a twin
    assert require_compiled("sim.body_step").dumps([1]) == "[1]"
