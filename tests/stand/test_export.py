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
    assert main(["run", "--no-plots", "detumble_star_tracker", "--duration", "20", "--out", str(run)]) in (0, 1)
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


# ------------------------------------------------------------------------- the generated column table
@pytest.fixture(scope="module")
def columns_table():
    from stand import telemetry_doc

    return telemetry_doc.collect()


def test_the_column_table_in_docs_is_the_generated_one(columns_table):
    from pathlib import Path

    from stand import telemetry_doc

    page = Path(__file__).resolve().parents[2] / "docs" / "telemetry_columns.md"
    assert page.read_text() == telemetry_doc.markdown(columns_table), (
        "docs/telemetry_columns.md differs from the code: python -m stand.telemetry_doc > docs/telemetry_columns.md")


def test_every_column_each_kind_writes_has_a_meaning_and_a_unit(columns_table):
    from stand import devices

    # every shipped kind and both reference controllers appear, built from the shipped scenarios
    groups = set(columns_table)
    assert {f"kind:{k}" for k in devices.KINDS} <= groups
    assert {"run", "controller:bdot", "controller:pointing"} <= groups
    missing = [f"{g}: {c}" for g, cols in columns_table.items() for c, e in cols.items() if not e["meaning"]]
    assert not missing, f"columns written without a meaning: {missing}"
    # the hardware tracker's and the screen tracker's own columns are in (built on loopback ports)
    assert {"clock_offset_s", "screen_t_lit_s", "screen_lead_s", "flags"} <= set(columns_table["kind:star_tracker"])
    assert columns_table["kind:sun_sensor"]["currents"]["widths"] == {6}


def test_a_tracker_flags_column_holds_the_icd_flags_byte(columns_table):
    """`st1.flags` bit i is the ICD's SOLUTION flags bit i (bit 0 valid, 1 Sun in field, ...)."""
    from drivers.star_tracker.codec import StarTrackerCodec
    from stand.devices.star_tracker_devices import FLAG_BITS, ICD_FLAG_BITS

    icd = next(f for f in StarTrackerCodec().messages["SOLUTION"].fields if f.name == "flags").bits
    assert icd[:2] == ("valid", "sun_in_field")  # what the issue names: bit 0 valid, not "Sun in field"
    assert columns_table["kind:star_tracker"]["flags"]["bits"] == icd
    assert ICD_FLAG_BITS == {name: 1 << i for i, name in enumerate(icd)}
    assert FLAG_BITS == {f: ICD_FLAG_BITS[f] for f in ("sun_in_field", "moon_in_field", "earth_in_field",
                                                       "rate_too_high")}


def test_a_recorded_tracker_flags_byte_agrees_with_its_valid_column(tmp_path):
    """In a run: the flags byte's bit 0 is the valid column, and a tumbling tracker's invalid solutions carry the
    ICD's rate bit (16), not the old 8."""
    run = tmp_path / "run"
    assert main(["run", "--no-plots", "detumble_star_tracker", "--duration", "20", "--out", str(run)]) in (0, 1)
    tel = telemetry.load(run)
    ok = np.isfinite(tel["st1.t_exposure_s"])
    flags, valid = tel["st1.flags"][ok].astype(int), tel["st1.valid"][ok]
    assert len(flags) and np.array_equal(flags & 1, valid.astype(int))
    assert np.all(flags & 16 == 16) and not np.any(flags & ~0b111111)


def test_the_view_and_the_plots_read_the_same_flag_bits():
    import re
    from pathlib import Path

    from stand.devices import star_tracker_plots
    from stand.devices.star_tracker_devices import FLAG_BITS
    from stand.view import export as view_export

    js = (Path(view_export.__file__).parent / "assets" / "view.js").read_text()
    table = re.search(r"const FLAG_BITS = \[(.*?)\];", js, re.S).group(1)
    js_bits = [(int(b), word) for b, word in re.findall(r"\[(\d+), \"(\w+)\"", table)]
    expected = [(FLAG_BITS[f], w) for f, w in (("sun_in_field", "Sun"), ("moon_in_field", "Moon"),
                                               ("earth_in_field", "Earth"), ("rate_too_high", "rate"))]
    assert js_bits == expected
    assert [(b, w) for b, w, _ in view_export.FLAG_BITS] == expected
    assert star_tracker_plots.TRACKER_FLAG_BITS == FLAG_BITS
