"""The telemetry log: written off the hot path, readable after a crash or a SIGKILL.

Layout of ``RUN_DIR/telemetry/``:

* ``schema.json``: written once before the first row: column names, their widths, units and, where the kind or
  the stand declares one, a one-line meaning.
* ``rows.f64``: little-endian float64 rows appended by a writer thread. A row is never split
  across a write that is not flushed as a whole, and ``load`` ignores a trailing partial row, so
  a log cut by SIGKILL reads back up to the last flush (at most ``FLUSH_S`` old).
* ``RUN_DIR/events.jsonl``: one JSON object per line for what happened (start, warnings, device
  errors, the end), flushed at once.

The loop hands rows as flat tuples of floats to ``Recorder.record``; batching and the numpy
conversion happen on the writer thread.

Other tools read a run through :func:`load` (columns as numpy arrays), :func:`load_frame` (a pandas DataFrame,
the ``export`` extra) or ``stand export RUN --format parquet|csv`` (:func:`flat_columns` names the flat
columns: a vector column ``NAME`` of width w becomes ``NAME[0]`` ... ``NAME[w-1]``, in the order it is recorded,
so ``q_BN[0]`` is the scalar part).
"""

from __future__ import annotations

import json
import queue
import sys
import threading
import time
from pathlib import Path

import numpy as np

from .logs import log_event

#: Longest time (wall clock) a recorded row waits before it is on disk.
FLUSH_S = 0.5
BATCH_ROWS = 2048
SCHEMA = "schema.json"
ROWS = "rows.f64"


class TelemetryError(OSError):
    """The log could not be written (a full disk, a lost mount): the run must end, keeping what is on disk."""


class Recorder:
    """Append rows of floats to the log from the loop; a thread writes them."""

    def __init__(self, run_dir: str | Path, columns: list[tuple[str, int, str]], meanings: dict | None = None,
                 clock=time.monotonic):
        self.dir = Path(run_dir) / "telemetry"
        self.dir.mkdir(parents=True, exist_ok=True)
        self.columns = columns
        self.width = sum(w for _, w, _ in columns)
        meanings = meanings or {}
        schema = {
            "format": "rows of little-endian float64, one row per record",
            "row_floats": self.width,
            "columns": [{"name": n, "width": w, "unit": u, **({"meaning": meanings[n]} if n in meanings else {})}
                        for n, w, u in columns],
        }
        try:
            (self.dir / SCHEMA).write_text(json.dumps(schema, indent=1))
        except OSError as exc:
            raise TelemetryError(f"cannot write the telemetry schema in {self.dir}: {exc.strerror or exc}.") from None
        self._file = open(self.dir / ROWS, "wb")  # noqa: SIM115 - closed by close()
        self._clock = clock
        self._buffer: list[tuple] = []
        self._last_handoff = clock()
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self.error: str | None = None  # set by the writer thread when a write fails
        self._thread = threading.Thread(target=self._writer, name="telemetry-writer", daemon=True)
        self._thread.start()
        self.rows = 0
        self.closed = False

    def record(self, row: tuple) -> None:
        if self.error is not None:
            raise TelemetryError(self.error)
        if len(row) != self.width:  # refused here, where the loop can say when; the rows before are still written
            raise TelemetryError(self.width_error(len(row)))
        self._buffer.append(row)
        if len(self._buffer) >= BATCH_ROWS or self._clock() - self._last_handoff >= FLUSH_S:
            self._handoff()

    def width_error(self, n: int) -> str:
        """The sentence for a row of ``n`` values: the declared columns, their count and widths."""
        declared = ", ".join(f"{name} {w}" for name, w, _ in self.columns)
        return (f"a telemetry row has {n} values but the {len(self.columns)} columns declared hold {self.width} "
                f"({declared}): each device's row() and the controller's telemetry() must return as many values as "
                "their columns declare; the rows before are kept")

    def _handoff(self) -> None:
        if self._buffer:
            self._queue.put(self._buffer)
            self.rows += len(self._buffer)
            self._buffer = []
        self._last_handoff = self._clock()

    def _writer(self) -> None:
        """The thread: writes batches until close(). Whatever stops it, of any exception type, is kept in ``error``,
        which record() and close() raise, so the loop ends the run as aborted instead of scoring a partial log."""
        try:
            while True:
                batch = self._queue.get()
                if batch is None:
                    return
                if self.error is None:  # after a failure the queue is drained; nothing more is written
                    self._write(batch)
        except BaseException as exc:  # noqa: BLE001 - reported through record() and close(), never lost
            self.error = self.error or (f"the telemetry writer stopped ({type(exc).__name__}: {exc}); the rows "
                                        "written before are kept")

    def _rows_array(self, batch: list) -> np.ndarray:
        """The batch as an (n, width) array; at a row that is not ``width`` numbers, the rows before it and the
        error (so they are written and the run ends)."""
        try:
            arr = np.asarray(batch, dtype="<f8")
            if arr.ndim == 2 and arr.shape[1] == self.width:
                return arr
        except (ValueError, TypeError):
            pass
        good = []
        for row in batch:  # only after a failure: find the first bad row
            try:
                one = np.asarray(row, dtype="<f8")
            except (ValueError, TypeError) as exc:
                self.error = (f"a telemetry row at t = {row[0]!r} s is not {self.width} numbers ({exc}); the rows "
                              "before are kept")
                break
            if one.shape != (self.width,):
                self.error = (f"a telemetry row at t = {row[0]!r} s has shape {one.shape}; the {len(self.columns)} "
                              f"columns declared hold {self.width} numbers; the rows before are kept")
                break
            good.append(one)
        return np.asarray(good, dtype="<f8").reshape(-1, self.width)

    def _write(self, batch: list) -> None:
        arr = self._rows_array(batch)
        if not len(arr):
            return
        start = self._file.tell()
        try:
            # Whole rows only: a short write (disk full) is cut back to the last whole row.
            self._file.write(arr.tobytes())
            self._file.flush()
        except OSError as exc:
            self.error = (f"writing the telemetry failed ({exc.strerror or exc}); the rows written before are "
                          "kept")
            try:
                self._file.truncate(start + ((self._file.tell() - start) // (8 * self.width)) * 8 * self.width)
            except OSError:
                pass

    def close(self) -> None:
        """Write what is buffered and stop the writer. Idempotent."""
        if self.closed:
            return
        self.closed = True
        self._handoff()
        self._queue.put(None)
        self._thread.join()
        try:
            self._file.close()
        except OSError as exc:
            self.error = self.error or f"closing the telemetry failed ({exc.strerror or exc})"
        if self.error is not None:
            raise TelemetryError(self.error)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class EventLog:
    """``events.jsonl``: one line per event, flushed immediately (it survives a kill). Each event is also a log
    record of the logger of the module that logged it (:func:`stand.logs.log_event`: ``stand.log`` and the
    console)."""

    def __init__(self, run_dir: str | Path):
        Path(run_dir).mkdir(parents=True, exist_ok=True)
        self.path = Path(run_dir) / "events.jsonl"
        self._file = open(self.path, "a", buffering=1)  # noqa: SIM115 - line-buffered, closed by close()
        self.lost = 0

    def log(self, kind: str, message: str, **fields) -> None:
        log_event(sys._getframe(1).f_globals.get("__name__", __name__), kind, message)
        if not self._file.closed:
            try:
                self._file.write(json.dumps({"kind": kind, "message": message, **fields}, default=str) + "\n")
            except OSError:
                self.lost += 1  # a full disk must not turn an event into a crash; the count goes in the summary

    def close(self) -> None:
        if not self._file.closed:
            try:
                self._file.close()
            except OSError:
                self.lost += 1


def schema(run_dir: str | Path) -> dict:
    """The run's ``schema.json`` (FileNotFoundError naming the run when it has none)."""
    d = Path(run_dir) / "telemetry"
    try:
        return json.loads((d / SCHEMA).read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{run_dir} holds no telemetry ({d / SCHEMA} is missing).") from None


def rows(run_dir: str | Path) -> np.ndarray:
    """The whole rows on disk as an (n, row_floats) float64 array (a trailing partial row is left out)."""
    return _whole_rows(np.fromfile(Path(run_dir) / "telemetry" / ROWS, dtype="<f8"), schema(run_dir))


def _whole_rows(raw: np.ndarray, schema_: dict) -> np.ndarray:
    width = int(schema_["row_floats"])
    n = raw.size // width
    return raw[: n * width].reshape(n, width)


def flat_columns(run_dir: str | Path) -> list[dict]:
    """One entry per float of a row, in row order: ``name`` (``NAME`` for a scalar column, ``NAME[i]`` for element
    i of a vector column), ``column`` (the recorded column's name), ``unit`` and ``meaning`` (empty when none)."""
    out = []
    for c in schema(run_dir)["columns"]:
        w = int(c["width"])
        for i in range(w):
            out.append({"name": c["name"] if w == 1 else f"{c['name']}[{i}]", "column": c["name"],
                        "unit": c.get("unit", ""), "meaning": c.get("meaning", "")})
    return out


def load_frame(run_dir: str | Path):
    """A run's telemetry as a pandas DataFrame: one float64 column per float of a row, named as
    :func:`flat_columns` names them (``t_s``, ``q_BN[0]`` ... ``q_BN[3]``, ``st1.flags``, ...), the values
    bit for bit those of :func:`load`. Needs pandas (``pip install 'adcs-stand[export]'``)."""
    try:
        import pandas as pd
    except ImportError:
        raise ImportError("a DataFrame needs pandas: pip install 'adcs-stand[export]' (or pandas itself)") from None
    data = rows(run_dir)
    names = [c["name"] for c in flat_columns(run_dir)]
    return pd.DataFrame({name: data[:, i].copy() for i, name in enumerate(names)})


def load(run_dir: str | Path, as_frame: bool = False):
    """A run's telemetry as columns: ``t_s`` (n,), ``q_BN`` (n, 4), ``omega_BN_B`` (n, 3), ...; with
    ``as_frame=True`` a pandas DataFrame instead (:func:`load_frame`).

    Reads whatever whole rows are on disk, so it works on a run that is still going or was killed.
    """
    if as_frame:
        return load_frame(run_dir)
    schema_ = schema(run_dir)
    return _columns(schema_, rows(run_dir))


def load_with_bytes(run_dir: str | Path) -> tuple[dict[str, np.ndarray], bytes]:
    """:func:`load`'s columns and the bytes of ``rows.f64`` they view, from one read of the file: a campaign's case
    fingerprints those bytes after its summary has judged the columns (reading the file twice cost each case a
    copy of its telemetry). The columns are read-only: they are the bytes fingerprinted."""
    schema_ = schema(run_dir)
    data = (Path(run_dir) / "telemetry" / ROWS).read_bytes()
    whole = len(data) - len(data) % 8  # what np.fromfile reads of a file cut inside a float: whole floats
    return _columns(schema_, _whole_rows(np.frombuffer(data, dtype="<f8", count=whole // 8), schema_)), data


def _columns(schema_: dict, rows_: np.ndarray) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    col = 0
    for c in schema_["columns"]:
        w = int(c["width"])
        out[c["name"]] = rows_[:, col] if w == 1 else rows_[:, col:col + w]
        col += w
    return out


def units(run_dir: str | Path) -> dict[str, str]:
    """Column name -> unit, from the schema."""
    return {c["name"]: c["unit"] for c in schema(run_dir)["columns"]}
