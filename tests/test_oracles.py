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


def test_a_build_that_did_not_compile_fails_in_ci_only_with_a_compiler(monkeypatch):
    monkeypatch.delenv("STAND_NATIVE", raising=False)
    monkeypatch.setenv("CI", "true")
    monkeypatch.setattr(shutil, "which", lambda name: "/usr/bin/cc" if name == "cc" else None)
    with pytest.raises(pytest.fail.Exception, match="sim._native was not built"):
        require_compiled("python", "sim._native")
    require_compiled("compiled", "sim._native")  # built: goes on
    monkeypatch.setattr(shutil, "which", lambda name: None)
    with pytest.raises(pytest.skip.Exception):  # no C compiler: nothing could have been built
        require_compiled("python", "sim._native")
    monkeypatch.delenv("CI")
    monkeypatch.setattr(shutil, "which", lambda name: "/usr/bin/cc")
    with pytest.raises(pytest.skip.Exception):  # a developer's machine
        require_compiled("python", "sim._native")


def test_stand_native_0_is_a_deliberate_choice_and_skips_even_in_ci(monkeypatch):
    monkeypatch.setenv("CI", "true")
    monkeypatch.setenv("STAND_NATIVE", "0")
    with pytest.raises(pytest.skip.Exception, match="STAND_NATIVE=0"):
        require_compiled("python", "drivers._bitpack")
