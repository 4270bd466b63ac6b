"""``stand shadow``'s outputs (:func:`run_shadow`): ``obscuration.csv``, ``summary.json``, ``obscured.png``,
``tracks.png``, ``report.md`` and one ``camera_<t>s.png`` per requested time."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np

from sim.obscuration import (
    project_to_plate,
)

from .approach import Approach, Interval, ShadowResult, compute, render_camera


def write_png(path: Path, image: np.ndarray) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.imsave(path, image, cmap="gray", vmin=0.0, vmax=1.0)


# ------------------------------------------------------------------------------------------------
# Outputs


def _interval_json(iv: Interval) -> dict:
    return {"start_s": iv.start_s, "end_s": iv.end_s, "duration_s": iv.duration_s, "start_open": iv.start_open,
            "end_open": iv.end_open, "max_percent": iv.max_percent, "causes": list(iv.causes)}


def _write_csv(path: Path, approach: Approach, res: ShadowResult) -> None:
    st = res.samples
    names = [o.name for o in approach.occluders]
    n_marks = st["mark_shadow"].shape[1]
    rng = np.linalg.norm(st["r_CP_P"], axis=1)
    elev = np.degrees(np.arcsin(np.clip(st["sun_P"][:, 2], -1, 1)))
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "obscured_percent", "earth_lit_fraction", "sun_elevation_on_plate_deg", "range_m",
                    "x_L_m", "y_L_m", "z_L_m"] + [f"mark{k}_shadow" for k in range(n_marks)]
                   + [f"percent[{n}]" for n in names if "occluder_percent" in st])
        for i, t in enumerate(res.t_s):
            row = [f"{t:.6f}", f"{st['obscured_percent'][i]:.6f}", f"{st['earth_lit'][i]:.6f}", f"{elev[i]:.5f}",
                   f"{rng[i]:.4f}", *(f"{x:.4f}" for x in st["r_CL_L"][i]),
                   *(f"{x:.6f}" for x in st["mark_shadow"][i])]
            if "occluder_percent" in st:
                row += [f"{x:.6f}" for x in st["occluder_percent"][:, i]]
            w.writerow(row)


def _plots(out: Path, approach: Approach, res: ShadowResult) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Polygon
    from scipy.spatial import ConvexHull, QhullError

    st, t = res.samples, res.t_s
    fig, ax = plt.subplots(figsize=(9, 4.5))
    ax.plot(t, st["obscured_percent"], "k-", lw=1.6, label="marks in shadow (all)")
    for name, row in zip([o.name for o in approach.occluders], st.get("occluder_percent", []), strict=False):
        if np.any(row > 0):
            ax.plot(t, row, lw=0.9, label=name)
    for iv in res.intervals:
        ax.axvspan(iv.start_s, iv.end_s, color="tab:red", alpha=0.08)
    for iv in res.eclipses:
        ax.axvspan(iv.start_s, iv.end_s, color="tab:blue", alpha=0.12)
    ax.set_xlabel("time since epoch (s)")
    ax.set_ylabel("marks' area in shadow (%)")
    ax.set_title(f"{approach.sc.name}: obscuration (red: intervals, blue: Earth shadow)")
    ax.legend(fontsize=7, loc="upper right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "obscured.png", dpi=110)
    plt.close(fig)

    plate = approach.spec.plate
    fig, ax = plt.subplots(figsize=(6.5, 6.5))
    ax.add_patch(Circle((0, 0), plate.radius_m, fc="0.85", ec="k"))
    for c in plate.marks_m:
        ax.add_patch(Circle(tuple(c), plate.mark_radius_m, fc="w", ec="k", lw=0.8))
    bodies = [(o, p) for o, p in zip(approach.occluders, approach.poses(st), strict=True) if hasattr(o.shape,
                                                                                                     "outline_m")]
    cmap = plt.get_cmap("viridis")
    k_show = np.unique(np.linspace(0, len(t) - 1, approach.spec.track_times).round().astype(int))
    lim = 1.3 * plate.radius_m
    for j, (occ, (r, C)) in enumerate(bodies):
        pts_V = occ.shape.outline_m()
        r_all = np.broadcast_to(r, (len(t), 3))
        C_all = np.broadcast_to(C, (len(t), 3, 3))
        centre_P = r_all + np.einsum("tji,j->ti", C_all, pts_V.mean(axis=0))
        track = project_to_plate(centre_P, st["sun_P"])
        near = np.linalg.norm(track[:, :2], axis=1) < 3 * plate.radius_m
        if np.any(near):
            xy = np.where(near[:, None], track[:, :2], np.nan)
            ax.plot(xy[:, 0], xy[:, 1], "-", lw=0.8, color=f"C{j % 10}", label=f"track: {occ.name}")
        for n_k, k in enumerate(k_show):
            pts_P = r_all[k] + pts_V @ C_all[k]
            proj = project_to_plate(pts_P, st["sun_P"][k])[:, :2]
            if not np.all(np.isfinite(proj)):
                continue
            try:
                hull = proj[ConvexHull(proj).vertices]
            except (QhullError, ValueError):
                continue
            if np.all(hull.min(axis=0) < lim) and np.all(hull.max(axis=0) > -lim):
                ax.add_patch(Polygon(hull, closed=True, fc=cmap(n_k / max(len(k_show) - 1, 1)), alpha=0.25,
                                     ec=f"C{j % 10}", lw=0.6))
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_aspect("equal")
    ax.set_xlabel("x_P (m)")
    ax.set_ylabel("y_P (m)")
    ax.set_title("shadows on the plate at " + ", ".join(f"{t[k]:.0f}" for k in k_show) + " s\n(purple to yellow: "
                 "earlier to later) and the tracks of the bodies' centres")
    ax.legend(fontsize=6, loc="lower left")
    fig.tight_layout()
    fig.savefig(out / "tracks.png", dpi=110)
    plt.close(fig)
    return ["obscured.png", "tracks.png"]


def _report(out: Path, approach: Approach, res: ShadowResult, images: list[str], summary: dict) -> None:
    spec = approach.spec
    lines = [f"# Shadows on the docking target: {approach.sc.name}", "",
             approach.sc.description or "", "",
             f"- epoch {approach.sc.epoch.iso}, {approach.sc.duration_s:g} s sampled every {res.step_s:g} s "
             f"({len(res.t_s)} samples), interval ends "
             + (f"bisected to {spec.refine_tol_s:g} s" if res.refined else "to one sample (not refined)"),
             f"- chaser trajectory: {spec.trajectory}, r0 = {spec.r0_L_m.tolist()} m, v0 = {spec.v0_L_m_s.tolist()}"
             " m/s (LVLH)",
             f"- Sun: {'point (umbra only)' if spec.sun == 'point' else f'disk sampled with {spec.sun_rings} rings'}"
             f"; Earth shadow {'conical' if spec.earth_shadow else 'off'}",
             f"- {len(spec.plate.marks_m)} marks of radius {spec.plate.mark_radius_m:g} m, each sampled at "
             f"{approach.mark_pts.shape[1]} points; obscured when above {spec.threshold_percent:g} %",
             f"- computed in {res.wall_time_s:.2f} s ({res.evaluations} evaluations)", "",
             "## Obscuration intervals", "",
             "| # | start (s) | end (s) | duration (s) | peak (%) | cast by |", "|---|---|---|---|---|---|"]
    for k, iv in enumerate(res.intervals):
        s = f"{iv.start_s:.3f}" + (" (run start)" if iv.start_open else "")
        e = f"{iv.end_s:.3f}" + (" (run end)" if iv.end_open else "")
        lines.append(f"| {k + 1} | {s} | {e} | {iv.duration_s:.3f} | {iv.max_percent:.1f} | "
                     f"{', '.join(iv.causes)} |")
    if not res.intervals:
        lines.append("| - | none | | | | |")
    lines += ["", "## Earth shadow", ""]
    lines += [f"- {iv.start_s:.1f} s to {iv.end_s:.1f} s (darkest {iv.max_percent:.0f} % of the Sun hidden)"
              for iv in res.eclipses] or ["- none: the target is in sunlight throughout"]
    lines += ["", "## Figures", "", "![obscured](obscured.png)", "", "![tracks](tracks.png)", ""]
    lines += [f"![camera]({name})" for name in images]
    lines += ["", f"Peak obscuration {summary['max_obscured_percent']:.1f} %, obscured "
              f"{summary['obscured_time_s']:.1f} s of {approach.sc.duration_s:g} s.", ""]
    (out / "report.md").write_text("\n".join(lines))


def run_shadow(sc, out: Path, step_s: float | None = None, refine: bool | None = None,
               camera_times_s: tuple[float, ...] | None = None) -> dict:
    """``stand shadow``: compute, then write every output into ``out``; returns the summary."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    approach = Approach(sc)
    res = compute(approach, step_s, refine)
    _write_csv(out / "obscuration.csv", approach, res)
    plots = _plots(out, approach, res)
    images = []
    cam = approach.spec.camera
    times = camera_times_s if camera_times_s is not None else (cam.times_s if cam else ())
    for tc in times:
        name = f"camera_{tc:08.1f}s.png".replace(" ", "0")
        write_png(out / name, render_camera(approach, tc, cam))
        images.append(name)
    op = res.samples["obscured_percent"]
    dt = np.diff(res.t_s)
    summary: dict[str, Any] = {
        "scenario": sc.name,
        "sim_duration_s": sc.duration_s,
        "wall_time_s": res.wall_time_s,
        "step_s": res.step_s,
        "refined": res.refined,
        "refine_tol_s": approach.spec.refine_tol_s if res.refined else None,
        "threshold_percent": approach.spec.threshold_percent,
        "samples": len(res.t_s),
        "evaluations": res.evaluations,
        "max_obscured_percent": float(op.max()),
        "obscured_time_s": float(np.sum(dt * (op[:-1] > approach.spec.threshold_percent))),
        "intervals": [_interval_json(iv) for iv in res.intervals],
        "eclipses": [_interval_json(iv) for iv in res.eclipses],
        "occluders": [o.name for o in approach.occluders],
        "outputs": ["obscuration.csv", "summary.json", "report.md", *plots, *images],
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    _report(out, approach, res, images, summary)
    return summary

