"""``stand bench shadow``: error of the obscuration interval ends against step size and run time.

The shipped approach (``fixtures/scenarios/rendezvous_shadow.toml``) is sampled at a range of
steps, with each interval end reported at the first sample past it (unrefined) or bisected between
its two samples to 1 ms (refined); at an 8 s step the bisection tolerance is swept too. The
reference is the same computation at a 0.5 s step bisected to 10 us. An unrefined end is late by
less than one step by construction; the rows show how far, and what the refinement costs. Ends at
the run's own start or end are left out (they are not events).
"""

from __future__ import annotations

import time

import numpy as np

STEPS_S = (16.0, 8.0, 4.0, 2.0, 1.0)
QUICK_STEPS_S = (8.0, 2.0)
REFINE_TOL_S = 1e-3
#: Tolerances swept at an 8 s step: the cost of each further digit of the ends.
TOLS_S = (1e-1, 1e-2, 1e-3, 1e-4)
QUICK_TOLS_S = (1e-2,)


def _ends(res) -> np.ndarray:
    out = []
    for iv in res.intervals:
        if not iv.start_open:
            out.append(iv.start_s)
        if not iv.end_open:
            out.append(iv.end_s)
    return np.array(out)


def _errors(res, ref_ends: np.ndarray) -> tuple[float, int]:
    ends = _ends(res)
    if len(ends) != len(ref_ends):
        return float("nan"), len(ends)
    return float(np.max(np.abs(ends - ref_ends))) if len(ends) else 0.0, len(ends)


def bench_shadow(quick: bool = False, plot_path: str | None = None) -> list[dict]:
    from stand.rendezvous import Approach, compute
    from stand.scenario import load

    sc = load("rendezvous_shadow")
    approach = Approach(sc)
    t0 = time.perf_counter()
    ref = compute(approach, step_s=1.0 if quick else 0.5, refine=True, tol_s=1e-5, per_occluder=False)
    ref_wall = time.perf_counter() - t0
    ref_ends = _ends(ref)
    rows = [{"name": "shadow.reference.ends", "value": len(ref_ends), "unit": "",
             "note": f"{ref.step_s:g} s step bisected to 1e-5 s in {ref_wall:.2f} s: "
             + ", ".join(f"{e:.3f}" for e in ref_ends)}]
    curves: dict[str, list[tuple[float, float]]] = {"unrefined": [], "refined": [], "refined, 8 s step": []}
    for h in QUICK_STEPS_S if quick else STEPS_S:
        for refine in (False, True):
            t0 = time.perf_counter()
            res = compute(approach, step_s=h, refine=refine, tol_s=REFINE_TOL_S, per_occluder=False)
            wall = time.perf_counter() - t0
            err, n = _errors(res, ref_ends)
            kind = "refined" if refine else "unrefined"
            limit = REFINE_TOL_S if refine else h
            curves[kind].append((wall, err))
            rows.append({"name": f"shadow.{kind}.step_{h:g}s.max_end_error", "value": err, "unit": "s",
                         "limit": f"<= {limit:g} s", "pass": bool(np.isfinite(err) and err <= limit),
                         "note": f"{res.evaluations} evaluations in {wall:.3f} s, {n} ends found"})
    for tol in QUICK_TOLS_S if quick else TOLS_S:
        t0 = time.perf_counter()
        res = compute(approach, step_s=8.0, refine=True, tol_s=tol, per_occluder=False)
        wall = time.perf_counter() - t0
        err, n = _errors(res, ref_ends)
        curves["refined, 8 s step"].append((wall, err))
        rows.append({"name": f"shadow.refined.step_8s.tol_{tol:g}s.max_end_error", "value": err, "unit": "s",
                     "limit": f"<= {tol:g} s", "pass": bool(np.isfinite(err) and err <= tol),
                     "note": f"{res.evaluations} evaluations in {wall:.3f} s, {n} ends found"})
    per_eval = ref_wall / max(ref.evaluations, 1) * 1e3
    rows.append({"name": "shadow.cost_per_time_sample", "value": round(per_eval, 3), "unit": "ms",
                 "note": f"{approach.mark_pts.shape[0] * approach.mark_pts.shape[1]} mark points x "
                 f"{len(approach.spec.sun_disk().offsets()[2])} Sun directions x {len(approach.occluders)} "
                 "occluders (culled where out of reach)"})
    if plot_path:
        _plot(curves, plot_path)
    return rows


def _plot(curves, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for kind, pts in curves.items():
        pts = [(w, e) for w, e in pts if np.isfinite(e) and e > 0]
        if pts:
            w, e = zip(*pts, strict=True)
            ax.loglog(w, e, "o-", label=kind)
    ax.set_xlabel("run time (s)")
    ax.set_ylabel("largest error of an interval end (s)")
    ax.set_title("stand bench shadow: interval ends, error against cost")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
