"""``stand export``: a run's telemetry as one Parquet or CSV file, for pandas, polars, pyarrow or a spreadsheet.

    stand export RUN --format parquet|csv [--out FILE]

One float64 column per float of a telemetry row, named as :func:`stand.telemetry.flat_columns` names them: a
scalar column keeps its name (``t_s``, ``st1.flags``), a vector column ``NAME`` of width w becomes ``NAME[0]`` ...
``NAME[w-1]`` (``q_BN[0]`` is the quaternion's scalar part). The values are those of ``stand.telemetry.load``
bit for bit: Parquet stores the float64s themselves (with each column's unit and meaning in its field metadata,
and the run's ``schema.json`` in the file's metadata); CSV writes each number with 17 significant digits, which
reads back to the same float64 (``nan`` for a missing value). A run still going or killed exports the whole rows
on disk. Parquet needs pyarrow (``pip install 'adcs-stand[export]'``); CSV needs nothing more.

Exit codes: 0 written, 2 a usage error (no telemetry in RUN, pyarrow missing, an output that cannot be written).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from stand import telemetry

FORMATS = ("parquet", "csv")
#: Rows written per chunk of a CSV (bounded memory for the text of a long run).
CSV_CHUNK_ROWS = 20_000
#: printf format of a CSV number: 17 significant digits round-trip every float64 (IEEE 754 binary64).
CSV_FLOAT = "%.17g"


class ExportError(ValueError):
    """One sentence for the operator: what is wrong and what to do."""


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("export", help="write a run's telemetry as a Parquet or CSV file (pandas, polars, ...)",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("run", metavar="RUN", help="the run's folder (what `stand run --out` named)")
    p.add_argument("--format", required=True, choices=FORMATS, help="parquet (needs pyarrow) or csv")
    p.add_argument("--out", metavar="FILE", help="the file to write (default: RUN/telemetry.parquet or .csv)")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    try:
        out = export(args.run, args.format, args.out)
    except ExportError as exc:
        print(f"stand: error: {exc}", file=sys.stderr)
        return 2
    print(f"stand: wrote {out}")
    return 0


def export(run_dir: str | Path, fmt: str, out: str | Path | None = None) -> Path:
    """Write the run's telemetry to ``out`` (default ``RUN/telemetry.FORMAT``) in ``fmt``; returns the path.
    The file appears whole or not at all (written beside it, then renamed)."""
    if fmt not in FORMATS:
        raise ExportError(f"--format {fmt!r} is not known; use one of {', '.join(FORMATS)}")
    try:
        schema = telemetry.schema(run_dir)
        data = telemetry.rows(run_dir)
        cols = telemetry.flat_columns(run_dir)
    except FileNotFoundError as exc:
        raise ExportError(f"RUN {str(run_dir)!r} holds no telemetry ({exc}); give the folder of a run") from None
    except (OSError, ValueError, KeyError) as exc:
        raise ExportError(f"RUN {str(run_dir)!r}: its telemetry cannot be read ({exc})") from None
    out = Path(out) if out is not None else Path(run_dir) / f"telemetry.{fmt}"
    tmp = out.with_name(f".{out.name}.part")
    try:
        if fmt == "parquet":
            _parquet(tmp, data, cols, schema)
        else:
            _csv(tmp, data, cols)
        os.replace(tmp, out)
    except OSError as exc:
        if tmp.parent.is_dir():
            tmp.unlink(missing_ok=True)
        raise ExportError(f"--out {str(out)!r} cannot be written ({exc.strerror or exc}); name a file in a folder "
                          "the stand can write in") from None
    return out


def _parquet(path: Path, data, cols: list[dict], schema: dict) -> None:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise ExportError("--format parquet needs pyarrow, which is not installed: pip install "
                          "'adcs-stand[export]' (or use --format csv)") from None
    fields = [pa.field(c["name"], pa.float64(), metadata={"unit": c["unit"], "meaning": c["meaning"],
                                                          "column": c["column"]}) for c in cols]
    arrow_schema = pa.schema(fields, metadata={"adcs_stand.schema": json.dumps(schema)})
    table = pa.Table.from_arrays([pa.array(data[:, i]) for i in range(len(cols))], schema=arrow_schema)
    pq.write_table(table, path)


def _csv(path: Path, data, cols: list[dict]) -> None:
    import numpy as np

    with open(path, "w", newline="") as f:
        f.write(",".join(c["name"] for c in cols) + "\n")
        for start in range(0, len(data), CSV_CHUNK_ROWS):
            np.savetxt(f, data[start:start + CSV_CHUNK_ROWS], fmt=CSV_FLOAT, delimiter=",")
