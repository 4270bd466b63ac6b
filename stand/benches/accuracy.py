"""``stand bench accuracy``: error against run time for every attitude and orbit integrator.

Cases (docs/benchmarks.md and issue 6):

* ``separatrix``: torque-free body, inertia diag(10, 20, 30) kg m^2, omega0 = (0.01, 0.5, 0.01)
  rad/s, identity start, 600 s; reference: the closed form ``sim.torque_free`` (itself checked
  against DOP853 at rtol 1e-13, fixtures/reference/torque_free/).
* ``fastspin``: same body, |omega0| = 20 rad/s 4 deg off the major axis, 600 s; same reference.
  The 0.1 s step is shown refused and subdivided.
* ``kepler_e0.9`` and ``kepler_e0.99``: two-body, perigee radius 7000 km, one orbit from perigee;
  reference ``sim.orbit.propagate_kepler`` (universal variables, checked at 80 digits).
* ``leo_j2_1day``: 500 km, i = 97.4 deg, one day, point mass + J2; reference DOP853 rtol 1e-13.

For each method and step or tolerance: final error (deg for attitude, m for orbits), maximum
relative drift of the conserved quantities (energy; |H| for the body, orbital angular momentum for
orbits; J2 energy for the J2 case), wall time (``time.perf_counter``, median of repeats). Rows
carry the acceptance figures of issue 6 with ``pass``; a work-precision plot (error against run
time, log-log) is written to ``plot_path`` and named in a row.

Closed loop (issue 26, :mod:`stand.benches.closed_loop`): the pointing scenario and a three-wheel MRP pointing
case on the stand's truth at dynamics steps 0.2 ... 0.01 s with every integrator a scenario may choose, the
controller at its own rate (zero-order hold), against DOP853 of the same loop integrated piecewise between
control ticks; the largest attitude (arcsec) and wheel-speed (rpm) errors against wall time, and their figure
beside ``plot_path`` (``NAME_closed_loop.png``).
"""

from __future__ import annotations

import math
import statistics
import time
import warnings
from pathlib import Path

import numpy as np
import scipy.integrate  # noqa: F401  (imported before timing: the first solve_ivp call would pay for it)

from sim import attitude as att
from sim.integrators import UnstableMethodWarning
from sim.orbit import MU_EARTH, elements_to_state, j2_energy, propagate_j2, propagate_kepler
from sim.rotations import angle_between, dcm
from sim.torque_free import TorqueFreeBody

from . import closed_loop

INERTIA = [10.0, 20.0, 30.0]
Q0 = [1.0, 0.0, 0.0, 0.0]
W_SEPARATRIX = [0.01, 0.5, 0.01]
W_FASTSPIN = [20.0 * math.sin(math.radians(4.0)), 0.0, 20.0 * math.cos(math.radians(4.0))]
DURATION_S = 600.0

#: docs/benchmarks.md, near-separatrix case: Basilisk RK4 0.1 s (1.1e-4 deg) in 56-84 ms; RKF78 0.25 s
#: (1.6e-8 deg) in 124 ms. Measured on another machine of the same class.
BASILISK_1E4_MS = 84.0
BASILISK_1E4_DEG = 1.1e-4
BASILISK_16E9_MS = 124.0
BASILISK_16E9_DEG = 1.6e-8


def _median_time(fn, repeats: int):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def _attitude_row(case, w0, ref_q, method, step, repeats, **kw):
    grid = 10.0 if method == "dop853" else step
    rep: dict = {}

    def run():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UnstableMethodWarning)
            return att.propagate(INERTIA, Q0, w0, DURATION_S, grid, method, report=rep, **kw)

    wall, (t, q, w) = _median_time(run, repeats)
    err = float(np.degrees(angle_between(q[-1], ref_q)))
    T = att.kinetic_energy(INERTIA, w)
    H_N = np.einsum("nji,nj->ni", dcm(q), w * np.array(INERTIA))
    dT = float(np.max(np.abs(T / T[0] - 1.0)))
    dH = float(np.max(np.linalg.norm(H_N - H_N[0], axis=1)) / np.linalg.norm(H_N[0]))
    label = f"rtol {kw['rtol']:g}" if method == "dop853" else f"h {step:g} s"
    if rep.get("substeps", 1) and rep.get("substeps", 1) > 1:
        label += f" (subdivided x{rep['substeps']})"
    return {"name": f"accuracy.{case}.{method}.{label.split(' (')[0].replace(' ', '_')}", "value": err,
            "unit": "deg", "case": case, "method": method,
            "step_s": None if method == "dop853" else step, "rtol": kw.get("rtol"),
            "error": err, "error_unit": "deg", "wall_s": wall, "energy_drift": dT, "momentum_drift": dH,
            "rhs_evals": rep.get("rhs_evals"), "substeps": rep.get("substeps"),
            "note": f"{label}; {wall * 1e3:.1f} ms; dT/T {dT:.1e}; dH/H {dH:.1e}"}


def _orbit_rows(case, r0, v0, duration, reference, conserved, steps, rtols, repeats, mu_j2):
    rows = []
    r_ref = reference
    configs = [("rk4", s, None) for s in steps] + [("dop853", duration, tol) for tol in rtols]
    for method, step, tol in configs:
        kw = {"rtol": tol, "atol": 1e-6 * tol / 1e-12} if method == "dop853" else {}

        def run(method=method, step=step, kw=kw):
            return propagate_j2(r0, v0, duration, step, j2=mu_j2, method=method, **kw)

        try:
            wall, (t, r, v) = _median_time(run, repeats)
        except ValueError as exc:
            rows.append({"name": f"accuracy.{case}.{method}.h_{step:g}_s", "value": "refused", "unit": "",
                         "case": case, "method": method, "note": str(exc)[:160]})
            continue
        err = float(np.linalg.norm(r[-1] - r_ref))
        c = conserved(r, v)
        drift = [float(np.max(np.abs(x / x[0] - 1.0))) for x in c]
        label = f"rtol {tol:g}" if method == "dop853" else f"h {step:g} s"
        rows.append({"name": f"accuracy.{case}.{method}.{label.replace(' ', '_')}", "value": err, "unit": "m",
                     "case": case, "method": method, "step_s": None if tol else step, "rtol": tol,
                     "error": err, "error_unit": "m", "wall_s": wall, "energy_drift": drift[0],
                     "momentum_drift": drift[1],
                     "note": f"{label}; {wall * 1e3:.1f} ms; dE/E {drift[0]:.1e}; dh/h {drift[1]:.1e}"})
    return rows


def _two_body_conserved(r, v):
    rn = np.linalg.norm(r, axis=1)
    energy = 0.5 * np.sum(v * v, axis=1) - MU_EARTH / rn
    return energy, np.linalg.norm(np.cross(r, v), axis=1)


def _j2_conserved(r, v):
    return j2_energy(r, v), np.cross(r, v)[:, 2]  # J2 keeps energy and the polar component of h


def _plot(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = [c for c in dict.fromkeys(r.get("case") for r in rows) if c]
    fig, axes = plt.subplots(1, len(cases), figsize=(4.2 * len(cases), 4.0))
    for ax, case in zip(np.atleast_1d(axes), cases, strict=True):
        sel = [r for r in rows if r.get("case") == case and isinstance(r.get("error"), float)]
        for method in dict.fromkeys(r["method"] for r in sel):
            pts = sorted((r["wall_s"], max(r["error"], 1e-16)) for r in sel if r["method"] == method)
            ax.loglog([p[0] for p in pts], [p[1] for p in pts], "o-", label=method)
        if case == "separatrix":
            ax.loglog([BASILISK_1E4_MS / 1e3, BASILISK_16E9_MS / 1e3], [BASILISK_1E4_DEG, BASILISK_16E9_DEG],
                      "k*", ms=10, label="Basilisk (docs/benchmarks.md)")
        ax.set_title(case)
        ax.set_xlabel("wall time [s]")
        ax.set_ylabel(f"final error [{sel[0]['error_unit'] if sel else ''}]")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def bench_accuracy(quick: bool = False, plot_path: str | Path = "accuracy.png") -> list[dict]:
    """Work-precision rows for all cases; ``quick`` trims the grid and repeats (about 20 s)."""
    repeats = 1 if quick else 3
    rows: list[dict] = []

    # -- near-separatrix torque-free body ------------------------------------------------------
    ref = TorqueFreeBody(INERTIA, Q0, W_SEPARATRIX).attitude(DURATION_S)
    grid = [
        ("rk4", [0.16, 0.1, 0.08] if quick else [0.16, 0.1, 0.08, 0.05, 0.02, 0.01], {}),
        ("rkmk4", [0.1, 0.05] if quick else [0.16, 0.1, 0.05, 0.02], {}),
        ("dop853", [1e-8, 1e-11] if quick else [1e-8, 1e-10, 1e-11, 1e-12], {}),
        # 0.75 s is 0.375 rad per step here; the guard (0.5 rad) admits up to 0.9996 s.
        ("rk8", [0.75, 0.5, 0.25, 0.2] if quick else [0.75, 0.6, 0.5, 0.4, 0.25, 0.2, 0.1], {}),
        ("trapezoid", [0.1] if quick else [0.1, 0.01], {"max_angle_rad": 1.0}),
        ("implicit_midpoint", [0.1] if quick else [0.1, 0.01], {"max_angle_rad": 1.0}),
    ]
    sep = []
    for method, values, kw in grid:
        for v in values:
            if method == "dop853":
                sep.append(_attitude_row("separatrix", W_SEPARATRIX, ref, method, DURATION_S, repeats,
                                         rtol=v, atol=v * 1e-2))
            else:
                sep.append(_attitude_row("separatrix", W_SEPARATRIX, ref, method, v, repeats, **kw))
    rows += sep

    def find(method, step):
        return next(r for r in sep if r["method"] == method and r["step_s"] == step)

    rows.append({"name": "accuracy.acceptance.rk4_0.1s_separatrix", "value": find("rk4", 0.1)["error"],
                 "unit": "deg", "limit": "<= 2e-4", "pass": find("rk4", 0.1)["error"] <= 2e-4})
    rows.append({"name": "accuracy.acceptance.rkmk4_0.1s_separatrix", "value": find("rkmk4", 0.1)["error"],
                 "unit": "deg", "limit": "<= 1e-3", "pass": find("rkmk4", 0.1)["error"] <= 1e-3})
    for method, (h1, h2) in (("rk4", (0.16, 0.08)), ("rkmk4", (0.1, 0.05))):
        order = math.log(find(method, h1)["error"] / find(method, h2)["error"]) / math.log(h1 / h2)
        rows.append({"name": f"accuracy.acceptance.{method}_order", "value": round(order, 3), "unit": "",
                     "limit": "4 +- 0.5", "pass": abs(order - 4.0) <= 0.5, "note": f"h = {h1:g} and {h2:g} s"})
    order8 = math.log(find("rk8", 0.5)["error"] / find("rk8", 0.25)["error"]) / math.log(2.0)
    rows.append({"name": "accuracy.rk8_order", "value": round(order8, 3), "unit": "",
                 "note": "h = 0.5 and 0.25 s over 600 s: apparent order, above 8 before the asymptotic regime "
                         "(tests/sim measure 8 +- 0.7 over 60 s)"})
    for target, anchor_ms, anchor_deg in ((1e-4, BASILISK_1E4_MS, BASILISK_1E4_DEG),
                                          (1.6e-8, BASILISK_16E9_MS, BASILISK_16E9_DEG)):
        ok = [r for r in sep if r["error"] <= max(target, anchor_deg)]
        best = min(ok, key=lambda r: r["wall_s"]) if ok else None
        rows.append({"name": f"accuracy.acceptance.fastest_to_{target:g}deg",
                     "value": round(best["wall_s"] * 1e3, 2) if best else "not reached", "unit": "ms",
                     "anchor": f"Basilisk {anchor_ms:g} ms for {anchor_deg:g} deg (docs/benchmarks.md)",
                     "limit": f"<= {anchor_ms:g} ms", "pass": bool(best and best["wall_s"] * 1e3 <= anchor_ms),
                     "note": f"{best['method']} {best['note']}, error {best['error']:.2g} deg" if best else
                     "no configuration in the grid reached it"})

    # -- fast spin -------------------------------------------------------------------------------
    ref_fast = TorqueFreeBody(INERTIA, Q0, W_FASTSPIN).attitude(DURATION_S)
    fast = [_attitude_row("fastspin", W_FASTSPIN, ref_fast, "rk4", 1e-3, 1)]
    if not quick:
        fast.append(_attitude_row("fastspin", W_FASTSPIN, ref_fast, "rk4", 2e-3, 1))
        fast.append(_attitude_row("fastspin", W_FASTSPIN, ref_fast, "rkmk4", 1e-3, 1))
        fast.append(_attitude_row("fastspin", W_FASTSPIN, ref_fast, "rk8", 0.02, 1))
        fast.append(_attitude_row("fastspin", W_FASTSPIN, ref_fast, "rk8", 0.01, 1))
        fast.append(_attitude_row("fastspin", W_FASTSPIN, ref_fast, "dop853", DURATION_S, 1, rtol=1e-8,
                                  atol=1e-10))
    sub = _attitude_row("fastspin", W_FASTSPIN, ref_fast, "rk4", 0.1, 1, subdivide=True)
    fast.append(sub)
    rows += fast
    rows.append({"name": "accuracy.acceptance.fastspin_rk4_1ms", "value": fast[0]["error"], "unit": "deg",
                 "limit": "<= 1e-3", "pass": fast[0]["error"] <= 1e-3})
    try:
        att.propagate(INERTIA, Q0, W_FASTSPIN, DURATION_S, 0.1)
        refused, msg = False, "accepted (should have been refused)"
    except ValueError as exc:
        refused, msg = True, str(exc)
    rows.append({"name": "accuracy.acceptance.fastspin_0.1s_refused", "value": "refused" if refused else "ran",
                 "unit": "", "pass": refused, "note": msg[:200]})
    rows.append({"name": "accuracy.acceptance.fastspin_0.1s_subdivided", "value": sub["error"], "unit": "deg",
                 "pass": bool(np.isfinite(sub["error"])) and sub["substeps"] > 1,
                 "note": f"subdivide=True: {sub['substeps']} substeps of {0.1 / sub['substeps']:g} s, finite, "
                         "error reported (the 0.1 rad/step guard; use 1 ms for 1e-3 deg)"})

    # -- orbits ----------------------------------------------------------------------------------
    for e in (0.9, 0.99):
        rp = 7.0e6
        a = rp / (1.0 - e)
        period = 2.0 * math.pi * math.sqrt(a ** 3 / MU_EARTH)
        r0, v0 = elements_to_state(e=e, i=math.radians(30.0), raan=0.3, argp=0.5, a=a, nu=0.0)
        r_ref, _ = propagate_kepler(r0, v0, period)
        per_orbit = [1000, 5000] if quick else [1000, 5000, 20000]
        rows += _orbit_rows(f"kepler_e{e:g}", r0, v0, period, r_ref, _two_body_conserved,
                            [period / n for n in per_orbit], [1e-10] if quick else [1e-8, 1e-10, 1e-12],
                            repeats, 0.0)
    r0, v0 = elements_to_state(e=0.0, i=math.radians(97.4), raan=0.0, argp=0.0, a=6878137.0, nu=0.0)
    _, r_tight, _ = propagate_j2(r0, v0, 86400.0, 86400.0, method="dop853", rtol=1e-13, atol=1e-7)
    from sim.orbit import J2_EARTH

    rows += _orbit_rows("leo_j2_1day", r0, v0, 86400.0, r_tight[-1], _j2_conserved,
                        [60.0, 10.0] if quick else [60.0, 30.0, 10.0, 1.0], [1e-10] if quick else [1e-8, 1e-10, 1e-12],
                        repeats, J2_EARTH)

    path = Path(plot_path)
    _plot(rows, path)
    rows.append({"name": "accuracy.plot", "value": str(path.resolve()), "unit": "",
                 "note": f"work-precision plot (error vs wall time, log-log) written to {path.resolve()}"})

    # -- closed loop -----------------------------------------------------------------------------
    closed = closed_loop.bench_rows(quick)
    rows += closed
    closed_path = path.with_name(f"{path.stem}_closed_loop{path.suffix or '.png'}")
    closed_loop.plot(closed, closed_path)
    rows.append({"name": "accuracy.closed_loop.plot", "value": str(closed_path.resolve()), "unit": "",
                 "note": f"closed-loop work-precision plot written to {closed_path.resolve()}"})
    return rows
