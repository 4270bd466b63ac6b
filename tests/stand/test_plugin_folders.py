"""Plug-ins loaded from a scenario's folder: the same module name in two folders gives each scenario its own."""

from __future__ import annotations

import pytest

from stand.adcs import PluginError, load_plugin

PLUGIN = """
class Flight:
    SOURCE = {source!r}
"""


def test_the_same_module_name_in_two_folders_loads_each_folders_own(tmp_path):
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "fsw_same_name.py").write_text(PLUGIN.format(source=name))
    first = load_plugin("fsw_same_name:Flight", "a", base=tmp_path)
    second = load_plugin("fsw_same_name:Flight", "b", base=tmp_path)
    again = load_plugin("fsw_same_name:Flight", "b", base=tmp_path)
    assert (first.SOURCE, second.SOURCE) == ("a", "b")
    assert again is second  # the same folder again: the module already imported


def test_a_plug_in_named_like_a_module_already_imported_is_refused_in_one_sentence(tmp_path):
    (tmp_path / "json.py").write_text(PLUGIN.format(source="mine"))
    with pytest.raises(PluginError, match="'json' is already imported from .*give the plug-in's module a name of its"):
        load_plugin("json:Flight", ".", base=tmp_path)


def test_installed_packages_are_scanned_once_and_again_only_for_a_name_not_yet_seen(monkeypatch):
    import stand.adcs as adcs

    scans = []

    def fake_scan():
        scans.append(1)
        return {"stand": ["adcs-stand"]} if len(scans) < 3 else {"stand": ["adcs-stand"], "late_pkg": ["late"]}

    monkeypatch.setattr(adcs, "packages_distributions", fake_scan)
    adcs._installed_top_levels.cache_clear()
    try:
        for _ in range(3):
            assert load_plugin("stand.adcs:PluginError") is PluginError
        assert len(scans) == 1  # one scan serves every later load
        with pytest.raises(PluginError, match="'late_pkg' is not an installed package"):
            load_plugin("late_pkg.mod:Cls")  # looked again (scan 2), still missing
        assert len(scans) == 2
        with pytest.raises(PluginError, match="'late_pkg.mod' cannot be imported"):
            load_plugin("late_pkg.mod:Cls")  # scan 3 finds it installed; importing it is the next check
        assert len(scans) == 3
    finally:
        adcs._installed_top_levels.cache_clear()
