"""`stand export` and `telemetry.load(as_frame=True)`: what pandas reads back is `telemetry.load` to the bit."""

from __future__ import annotations

import math
import sys

import numpy as np
import pandas as pd
import pytest

from stand import telemetry
from stand.cli import main

#: Values a float text format gets wrong first: NaN, infinities, signed zero, a subnormal, the extremes, one that
#: needs all 17 digits, a quaternion element that is not a short decimal.
AWKWARD = (math.nan, math.inf, -math.inf, -0.0, 5e-324, 1.7976931348623157e308, -2.2250738585072014e-308,
           0.1 + 0.2, 1.0 / 3.0, 6878137.000000001)


def _recorded_run(run_dir) -> None:
    """A run folder written by the stand's own Recorder: a scalar, a 4-vector, a flags column and a 3-vector."""
    cols = [("t_s", 1, "s"), ("q_BN", 4, "1"), ("st1.flags", 1, "1"), ("dev.vec_B", 3, "T")]
    rng = np.random.default_rng(7)
    with telemetry.Recorder(run_dir, cols, {"t_s": "time"}) as rec:
        for k in range(50):
            row = [float(k) * 0.1, *rng.normal(size=4), float(k % 64), *rng.normal(scale=1e-5, size=3)]
            row[1 + k % 8] = AWKWARD[k % len(AWKWARD)]
            rec.record(tuple(row))


def _flat(tel: dict) -> np.ndarray:
    """`telemetry.load`'s columns side by side, in row order (what each export column must hold)."""
    return np.column_stack([v.reshape(len(v), -1) for v in tel.values()])


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal to the bit, except that any NaN equals any NaN (a NaN's payload is not a value)."""
    a, b = np.asarray(a, dtype="<f8"), np.asarray(b, dtype="<f8")
    nan = np.isnan(a)
    return a.shape == b.shape and np.array_equal(nan, np.isnan(b)) and np.array_equal(
        a[~nan].view("<u8"), b[~nan].view("<u8"))


@pytest.fixture
def run_dir(tmp_path):
    _recorded_run(tmp_path / "run")
    return tmp_path / "run"


def test_frame_names_vector_elements_and_equals_load_to_the_bit(run_dir):
    tel = telemetry.load(run_dir)
    frame = telemetry.load(run_dir, as_frame=True)
    assert list(frame.columns) == ["t_s", "q_BN[0]", "q_BN[1]", "q_BN[2]", "q_BN[3]", "st1.flags",
                                   "dev.vec_B[0]", "dev.vec_B[1]", "dev.vec_B[2]"]
    assert all(frame.dtypes == np.float64) and len(frame) == 50
    assert _same_bits(frame.to_numpy(), _flat(tel))
    assert _same_bits(frame["q_BN[2]"].to_numpy(), tel["q_BN"][:, 2])
    # the awkward values are really in there, signed zero included
    assert np.signbit(tel["q_BN"][np.equal(tel["q_BN"], 0.0)]).any() and np.isinf(tel["q_BN"]).any()


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
def test_export_read_back_by_pandas_equals_load_to_the_bit(run_dir, tmp_path, fmt, capsys):
    out = tmp_path / f"x.{fmt}"
    assert main(["export", str(run_dir), "--format", fmt, "--out", str(out)]) == 0
    assert str(out) in capsys.readouterr().out
    back = pd.read_parquet(out) if fmt == "parquet" else pd.read_csv(out)
    assert list(back.columns) == [c["name"] for c in telemetry.flat_columns(run_dir)]
    assert all(back.dtypes == np.float64)
    assert _same_bits(back.to_numpy(), _flat(telemetry.load(run_dir)))


def test_parquet_carries_units_meanings_and_the_schema(run_dir):
    import json

    import pyarrow.parquet as pq

    out = run_dir / "telemetry.parquet"
    assert main(["export", str(run_dir), "--format", "parquet"]) == 0  # the default: beside the telemetry
    schema = pq.read_schema(out)
    field = schema.field("dev.vec_B[1]")
    assert field.metadata[b"unit"] == b"T" and field.metadata[b"column"] == b"dev.vec_B"
    assert schema.field("t_s").metadata[b"meaning"] == b"time"
    assert json.loads(schema.metadata[b"adcs_stand.schema"]) == telemetry.schema(run_dir)


def test_a_real_run_with_a_tracker_exports_to_the_bit(tmp_path):
    """A shipped scenario's telemetry (a tracker: NaN before its first solution, flags, quaternions)."""
    run = tmp_path / "run"
    assert main(["run", "detumble_star_tracker", "--duration", "20", "--out", str(run)]) in (0, 1)
    tel = telemetry.load(run)
    assert np.isnan(tel["st1.err_cross"]).any()
    for fmt in ("csv", "parquet"):
        assert main(["export", str(run), "--format", fmt]) == 0
    csv = pd.read_csv(run / "telemetry.csv")
    parquet = pd.read_parquet(run / "telemetry.parquet")
    assert _same_bits(csv.to_numpy(), _flat(tel)) and _same_bits(parquet.to_numpy(), _flat(tel))


def test_a_killed_run_exports_its_whole_rows(run_dir, tmp_path):
    with open(run_dir / "telemetry" / telemetry.ROWS, "ab") as f:
        f.write(b"\x00" * 20)  # a partial row, as a SIGKILL mid-write leaves
    assert main(["export", str(run_dir), "--format", "csv"]) == 0
    assert len(pd.read_csv(run_dir / "telemetry.csv")) == 50


def test_export_errors_are_one_sentence(tmp_path, capsys, monkeypatch):
    assert main(["export", str(tmp_path), "--format", "csv"]) == 2
    err = capsys.readouterr().err
    assert "holds no telemetry" in err and str(tmp_path) in err and "Traceback" not in err
    _recorded_run(tmp_path / "run")
    assert main(["export", str(tmp_path / "run"), "--format", "csv", "--out", str(tmp_path / "no" / "x.csv")]) == 2
    assert "--out" in capsys.readouterr().err
    assert not list((tmp_path / "run").glob("*.part")) and not (tmp_path / "no").exists()
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # as if pyarrow were not installed
    assert main(["export", str(tmp_path / "run"), "--format", "parquet"]) == 2
    assert "pip install 'adcs-stand[export]'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["export", str(tmp_path / "run"), "--format", "xlsx"])
    assert exc.value.code == 2
