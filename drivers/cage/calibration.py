"""Cage calibration: the coil constants and the lab's residual field, by least squares from
magnetometer readings at commanded currents, stored per bench as JSON.

Model: ``b_T = K i_A + b_lab_T`` with ``K`` a full 3x3 matrix (T/A; rows field axes, columns coils),
so cross-coupling and a magnetometer mounted slightly askew are calibrated too. Twelve unknowns,
three equations per point: at least four current vectors that are not coplanar in the affine sense
(e.g. zero and one per axis); :func:`default_points` gives fifteen (zero, +-1 level per axis, and
eight half-level corners) so the residual shows noise and non-linearity.

Inverse: ``command_field(b_T)`` needs ``i_A = K^-1 (b_T - b_lab_T)`` (:meth:`CageCalibration.currents_for`).
"""

from __future__ import annotations

import datetime
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["CageCalibration", "default_points", "fit_calibration", "run_calibration"]

#: Largest condition number of the 4-column design matrix [i, 1] a fit accepts.
MAX_DESIGN_CONDITION = 1e6


@dataclass(frozen=True)
class CageCalibration:
    """Result of a calibration on one bench.

    Attributes:
        coil_T_per_A: K, 3x3 (T/A), field at the test position per coil ampere.
        lab_field_T: residual lab field at the test position, cage axes (T).
        residual_rms_T: RMS of the fit's residuals over all points and axes (T).
        n_points: current vectors used.
        bench: the bench's name.
        created: ISO 8601 UTC time of the fit.
    """

    coil_T_per_A: tuple[tuple[float, float, float], ...]
    lab_field_T: tuple[float, float, float]
    residual_rms_T: float = 0.0
    n_points: int = 0
    bench: str = ""
    created: str = ""

    def __post_init__(self) -> None:
        k = np.asarray(self.coil_T_per_A, dtype=float)
        b = np.asarray(self.lab_field_T, dtype=float)
        if k.shape != (3, 3) or not np.all(np.isfinite(k)):
            raise ValueError(f"coil_T_per_A = {self.coil_T_per_A!r} is not allowed; give a 3x3 matrix in T/A.")
        if b.shape != (3,) or not np.all(np.isfinite(b)):
            raise ValueError(f"lab_field_T = {self.lab_field_T!r} is not allowed; give three numbers in T.")
        cond = np.linalg.cond(k)
        if not math.isfinite(cond) or cond > 1e6:
            raise ValueError(f"coil_T_per_A has condition number {cond:.3g}; a cage whose coils are this close to "
                             "parallel cannot be inverted accurately (allowed: below 1e6).")
        object.__setattr__(self, "coil_T_per_A", tuple(tuple(float(v) for v in row) for row in k))
        object.__setattr__(self, "lab_field_T", tuple(float(v) for v in b))
        object.__setattr__(self, "_K_inv", np.linalg.inv(k))
        object.__setattr__(self, "_K", k)
        object.__setattr__(self, "_b", b)

    def field_for(self, currents_A: Sequence[float]) -> np.ndarray:
        """Predicted field (T, cage axes) for coil currents ``currents_A`` (A)."""
        return self._K @ np.asarray(currents_A, dtype=float) + self._b  # type: ignore[attr-defined]

    def currents_for(self, b_T: Sequence[float]) -> np.ndarray:
        """Coil currents (A, signed) that make ``b_T`` (T, cage axes) at the test position."""
        b = np.asarray(b_T, dtype=float)
        if b.shape != (3,) or not np.all(np.isfinite(b)):
            raise ValueError(f"b_T = {b_T!r} is not allowed; give three finite numbers in T (cage axes).")
        return self._K_inv @ (b - self._b)  # type: ignore[attr-defined]

    # -- storage ---------------------------------------------------------------------------------

    def to_json(self) -> dict[str, Any]:
        return {"kind": "cage-calibration", "version": 1, "bench": self.bench, "created": self.created,
                "coil_T_per_A": [list(r) for r in self.coil_T_per_A], "lab_field_T": list(self.lab_field_T),
                "residual_rms_T": self.residual_rms_T, "n_points": self.n_points}

    def save(self, path: str | Path) -> Path:
        """Write the calibration as JSON to ``path`` (parents created); returns the path."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(json.dumps(self.to_json(), indent=2) + "\n")
        return p

    @classmethod
    def load(cls, path: str | Path) -> CageCalibration:
        """Read a calibration written by :meth:`save`; ValueError names the file and the problem."""
        p = Path(path)
        try:
            data = json.loads(p.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"cage calibration {p}: cannot be read as JSON ({exc}).") from None
        if not isinstance(data, dict) or data.get("kind") != "cage-calibration":
            raise ValueError(f"cage calibration {p}: not a cage calibration (expected \"kind\": \"cage-calibration\").")
        try:
            return cls(tuple(tuple(r) for r in data["coil_T_per_A"]), tuple(data["lab_field_T"]),
                       float(data.get("residual_rms_T", 0.0)), int(data.get("n_points", 0)),
                       str(data.get("bench", "")), str(data.get("created", "")))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"cage calibration {p}: missing or malformed field {exc}.") from None

    @classmethod
    def from_config(cls, config, bench: str = "emulated") -> CageCalibration:
        """The exact calibration of an emulated cage (its :class:`~drivers.cage.model.CageConfig`):
        for runs that do not want to spend sim time calibrating. A bench calibrates instead."""
        return cls(config.coil_T_per_A, config.lab_field_T, 0.0, 0, bench, "")

    @staticmethod
    def path_for(bench: str, root: str | Path) -> Path:
        """Where the calibration of ``bench`` is kept under ``root``: ``root/<bench>/cage_calibration.json``."""
        if not bench or any(c in bench for c in "/\\") or bench in {".", ".."}:
            raise ValueError(f"bench = {bench!r} is not allowed; give a plain name (no slashes).")
        return Path(root) / bench / "cage_calibration.json"


def fit_calibration(currents_A: Sequence[Sequence[float]], fields_T: Sequence[Sequence[float]], *,
                    bench: str = "") -> CageCalibration:
    """Least-squares ``K`` and ``b_lab`` from currents (N, 3) and the fields measured there (N, 3).

    Refuses fewer than 4 points, mismatched shapes, non-finite values, and point sets that do not
    determine every coil's constant (design matrix condition above ``MAX_DESIGN_CONDITION``).
    """
    i = np.asarray(currents_A, dtype=float)
    b = np.asarray(fields_T, dtype=float)
    if i.ndim != 2 or i.shape[1] != 3 or b.shape != i.shape:
        raise ValueError(f"currents_A {i.shape} and fields_T {b.shape} must both be (N, 3) with the same N.")
    if len(i) < 4:
        raise ValueError(f"{len(i)} calibration points are not enough; K (9) and the lab field (3) need at least 4 "
                         "current vectors.")
    if not (np.all(np.isfinite(i)) and np.all(np.isfinite(b))):
        raise ValueError("currents_A and fields_T must be finite.")
    design = np.hstack([i, np.ones((len(i), 1))])
    scale = np.maximum(np.abs(design).max(axis=0), 1e-300)  # condition of the shape, not of the units
    cond = np.linalg.cond(design / scale)
    if not math.isfinite(cond) or cond > MAX_DESIGN_CONDITION:
        raise ValueError(f"the calibration currents do not determine every coil constant (condition number "
                         f"{cond:.3g}, allowed below {MAX_DESIGN_CONDITION:g}); drive each axis on its own at "
                         "two or more levels.")
    x, *_ = np.linalg.lstsq(design, b, rcond=None)  # x: (4, 3); b = i @ x[:3] + x[3]
    residual = b - design @ x
    rms = float(np.sqrt(np.mean(residual**2)))
    created = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    return CageCalibration(tuple(map(tuple, x[:3].T)), tuple(x[3]), rms, len(i), bench, created)


def default_points(level_A: float = 1.0) -> np.ndarray:
    """Fifteen current vectors: zero, +-level on each axis alone, and the eight corners level x (+-1, +-1, +-1) / 2."""
    if not (math.isfinite(level_A) and level_A > 0):
        raise ValueError(f"level_A = {level_A!r} is not allowed; give a positive current in A.")
    pts = [np.zeros(3)]
    for a in range(3):
        for s in (1.0, -1.0):
            e = np.zeros(3)
            e[a] = s * level_A
            pts.append(e)
    for sx in (1, -1):
        for sy in (1, -1):
            for sz in (1, -1):
                pts.append(0.5 * level_A * np.array([sx, sy, sz], dtype=float))
    return np.array(pts)


def run_calibration(host, points: Sequence[Sequence[float]] | None = None, *, wait: Callable[[float], None],
                    settle_s: float = 1.0, samples: int = 10, sample_period_s: float = 0.02,
                    bench: str = "") -> CageCalibration:
    """Drive the cage through ``points`` (A; default :func:`default_points`), wait ``settle_s`` at
    each, average ``samples`` magnetometer readings ``sample_period_s`` apart (with the currents
    measured in the same reads), and fit.

    ``host`` is a :class:`~drivers.cage.host.CageHost` with the outputs enabled; ``wait(seconds)``
    lets time pass (``time.sleep`` on a bench, stepping the emulator in sim time in tests); the
    heartbeat is refreshed by every command. Readings flagged invalid are skipped; a point with no
    valid reading raises ValueError. The cage is left at zero current.
    """
    pts = default_points() if points is None else np.asarray(points, dtype=float)
    fields, currents = [], []
    for p in pts:
        host.command_currents(p)
        remaining = settle_s
        while remaining > 0:  # keep the heartbeat alive through long settling times
            dt = min(remaining, 0.1)
            wait(dt)
            host.heartbeat()
            remaining -= dt
        got_b, got_i = [], []
        for _ in range(samples):
            wait(sample_period_s)
            host.heartbeat()
            s = host.take_field()
            if s.valid:
                got_b.append(s.b_T)
                got_i.append(s.currents_A)
        if not got_b:
            raise ValueError(f"no valid magnetometer reading at currents {list(p)} A; is the field within range?")
        fields.append(np.mean(got_b, axis=0))
        currents.append(np.mean(got_i, axis=0))  # what flowed, not what was asked
    host.command_currents((0.0, 0.0, 0.0))
    return fit_calibration(np.array(currents), np.array(fields), bench=bench)
