"""Magnetic hardware-in-the-loop: the B-dot closes through a Helmholtz cage (emulated, over Modbus TCP) that the
stand drives to the simulated field, with the board's magnetometer reading the cage instead of the truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stand import telemetry
from stand.cli import main

from .conftest import run_shipped_without_plots

CHECKPOINTS_S = (600, 1800, 3600)


def _rates(run_dir) -> dict[int, float]:
    tel = telemetry.load(run_dir)
    rate = np.degrees(np.linalg.norm(tel["omega_BN_B"], axis=1))
    return {t: float(rate[np.searchsorted(tel["t_s"], t - 1e-9)]) for t in CHECKPOINTS_S}


@pytest.mark.slow
def test_detumble_through_the_cage_lands_within_15_percent_of_detumble_igrf(tmp_path):
    # The reference: completed (passed or not), as `stand run` exiting 0 or 1; its plots are not compared.
    assert run_shipped_without_plots("detumble_igrf", 3600, tmp_path / "igrf")["status"] == "completed"
    code = main(["run", "detumble_cage", "--duration", "3600", "--out", str(tmp_path / "cage"), "--no-progress"])
    summary = json.loads((tmp_path / "cage" / "summary.json").read_text())
    assert summary["status"] == "completed", summary["error"]
    reference, through_cage = _rates(tmp_path / "igrf"), _rates(tmp_path / "cage")
    for t in CHECKPOINTS_S:
        assert abs(through_cage[t] - reference[t]) <= 0.15 * reference[t], (t, through_cage, reference)
    following = summary["device_counters"]["cage"]["following_error_nT"]
    assert 0 < following["rms"] < 500 and following["peak"] >= following["rms"] and 0 <= following["lag_s"] <= 1
    crit = {c["metric"]: c for c in summary["criteria"]}
    assert crit["cage_following_rms_nT"]["unit"] == "nT" and code in (0, 1)
    # The board read the cage: its magnetometer differs from the truth by the following error, not by zero.
    tel = telemetry.load(tmp_path / "cage")
    diff = np.linalg.norm(tel["mtq.mag_S"] - tel["b_true_B"], axis=1)[tel["t_s"] > 5]
    assert np.nanmedian(diff) > 5e-9
    assert (tmp_path / "cage" / "cage_cage.png").exists()


def test_a_magnetometer_can_only_read_a_device_that_makes_a_field(tmp_path, capsys):
    code = main(["check", "detumble_cage", "--set", "devices.mtq.field_source=mtq"])
    err = capsys.readouterr().err
    assert code == 2 and "devices[1].field_source = 'mtq'" in err and "cage" in err
