"""``stand bench render``: star-screen accuracy and speed against the acceptance of the star-screen issue.

Rows (``bench_render(quick) -> list[dict]`` with ``name, value, unit`` and optional ``limit, pass, note``):

* geometry: emitted-light centroid of each isolated rendered star (decoded through the panel's
  gamma-2.2 response) against an independent TAN projection (astropy WCS when installed, else
  spherical-trigonometry gnomonic formulas) of the same catalog places, at random attitudes plus
  both celestial poles and the RA 0/360 wrap. RMS and max for stars whose peak is at least 8/255 of
  full-scale luminance (goal G2 of docs/benchmarks.md), and the same for all stars (info).
* brightness: emitted flux against the flux the photometry policy asked for, as magnitudes.
* detector: truth detector pixels against the independent projection.
* speed: screen frame time (wall clock, persistent sparse update, no copy) at 1920 x 1080,
  2560 x 1440 and 3840 x 2160 with stars to Hp 8, median and p95, and the 4K / 1080p ratio; the
  same as thread CPU time (what an idle core would take) beside each.
* display node: state sent over loopback UDP -> frame rendered and handed on, median and p95.
"""

from __future__ import annotations

import time

import numpy as np

from sim.time import Epoch
from star_screen.attitude import radec_roll_from_q_SN
from star_screen.catalog import unit_to_radec
from star_screen.geometry import default_bench
from star_screen.metrics import emitted_centroids, isolated, reference_tan_pixels
from star_screen.render import Renderer

EPOCH = "2026-01-01T00:00:00Z"
PEAK_MIN = 8.0 / 255.0


def _attitudes(n: int, seed: int = 20260101) -> np.ndarray:
    from star_screen.attitude import q_SN_from_radec_roll

    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    special = q_SN_from_radec_roll(
        np.array([0.0, 123.0, 0.0, 359.99, 0.01, 180.0, 359.9]),
        np.array([90.0, -90.0, 0.0, 30.0, -45.0, 89.5, -89.7]),
        np.array([0.0, 45.0, 10.0, -30.0, 170.0, 0.0, 90.0]),
    )
    return np.concatenate((special, q))


def _row(name, value, unit, limit=None, ok=None, note=None) -> dict:
    r = {"name": name, "value": float(value), "unit": unit}
    if limit is not None:
        r["limit"] = float(limit)
    if ok is not None:
        r["pass"] = bool(ok)
    if note:
        r["note"] = note
    return r


def geometry_rows(n_attitudes: int) -> list[dict]:
    epoch = Epoch.from_iso(EPOCH)
    r = Renderer(default_bench(1920, 1080), aberration=False)
    places = r._places_at(epoch)
    b = r.bench
    t = b.tracker
    lum = b.screen.response()
    errs, dmag, peaks, det_err = [], [], [], []
    method = ""
    hip_to_row = {int(h): i for i, h in enumerate(places.hip)}
    for q in _attitudes(n_attitudes):
        f = r.render(q, epoch, detector=False)
        s = f.stars
        if len(s) == 0:
            continue
        rows = np.array([hip_to_row[int(h)] for h in s.hip])
        sra, sdec = (np.degrees(a) for a in unit_to_radec(places.u_N[rows]))
        ra, dec, roll = (float(v) for v in radec_roll_from_q_SN(q))
        ref_scr, method = reference_tan_pixels(ra, dec, sra, sdec, roll, b.k_px, b.k_px, b.sx0, b.sy0)
        ref_det, _ = reference_tan_pixels(ra, dec, sra, sdec, roll, t.fx, t.fy, t.cx, t.cy)
        det_err.append(np.abs(s.detector_xy - ref_det).max())
        rad = np.ceil(r.photometry.truncate_sigmas * s.screen_sigma).astype(int) + 1
        iso = isolated(s.screen_xy, rad) & ~s.clipped
        c, flux = emitted_centroids(f.screen, lum, s.screen_xy[iso], rad[iso])
        ok = np.isfinite(flux)
        errs.append(np.linalg.norm(c[ok] - ref_scr[iso][ok], axis=1))
        dmag.append(-2.5 * np.log10(flux[ok] / s.screen_flux[iso][ok]))
        peaks.append(s.screen_peak[iso][ok])
    e, dm, pk = (np.concatenate(a) for a in (errs, dmag, peaks))
    sel = pk >= PEAK_MIN
    note = (
        f"{n_attitudes + 7} attitudes incl. poles and RA wrap; reference: {method}; "
        "catalog places (aberration off)"
    )
    return [
        _row(
            "geometry centroid RMS (peak >= 8/255)",
            np.sqrt(np.mean(e[sel] ** 2)),
            "screen px",
            0.01,
            np.sqrt(np.mean(e[sel] ** 2)) <= 0.01,
            f"{sel.sum()} isolated stars; " + note,
        ),
        _row("geometry centroid max (peak >= 8/255)", e[sel].max(), "screen px", 0.03, e[sel].max() <= 0.03),
        _row(
            "brightness error max (peak >= 8/255)",
            np.abs(dm[sel]).max(),
            "mag",
            0.05,
            np.abs(dm[sel]).max() <= 0.05,
        ),
        _row(
            "geometry centroid RMS (all stars, info)",
            np.sqrt(np.mean(e**2)),
            "screen px",
            note=f"{len(e)} isolated stars, faintest peak {pk.min():.2e} of full scale",
        ),
        _row("geometry centroid max (all stars, info)", e.max(), "screen px"),
        _row("brightness error max (all stars, info)", np.abs(dm).max(), "mag"),
        _row("detector truth vs reference max", max(det_err), "detector px", 1e-6, max(det_err) <= 1e-6),
    ]


def speed_rows(n_frames: int) -> list[dict]:
    epoch = Epoch.from_iso(EPOCH)
    qs = _attitudes(n_frames, seed=7)
    rows, medians = [], {}
    for w, h in ((1920, 1080), (2560, 1440), (3840, 2160)):
        r = Renderer(default_bench(w, h))
        for q in qs[:5]:  # warm up (places cache, allocations)
            r.render(q, epoch, detector=False, copy=False)
        ts, cpu, ns = [], [], []
        for q in qs:
            t0, c0 = time.perf_counter(), time.thread_time()
            f = r.render(q, epoch, detector=False, copy=False)
            ts.append(time.perf_counter() - t0)
            cpu.append(time.thread_time() - c0)
            ns.append(len(f.stars))
        ts = np.array(ts) * 1e3
        cpu = np.array(cpu) * 1e3
        med, p95 = np.median(ts), np.percentile(ts, 95)
        medians[w] = med
        note = f"{len(qs)} frames, stars per frame mean {np.mean(ns):.0f} max {max(ns)}, Hp <= 8, apparent"
        # Wall clock is what a display loop lives by (and what the limits apply to); thread CPU time
        # is what the frame costs on an idle core. On a shared machine wall - CPU is preemption.
        lim = w == 1920
        rows.append(_row(f"render {w}x{h} median", med, "ms", 3.0 if lim else None, med <= 3.0 if lim else None,
                         "wall clock; " + note))
        rows.append(_row(f"render {w}x{h} p95", p95, "ms", 5.0 if lim else None, p95 <= 5.0 if lim else None,
                         "wall clock"))
        rows.append(_row(f"render {w}x{h} CPU median (info)", np.median(cpu), "ms",
                         note="thread CPU time, immune to other load"))
        rows.append(_row(f"render {w}x{h} CPU p95 (info)", np.percentile(cpu, 95), "ms",
                         note=f"wall p95 - CPU p95 = {p95 - np.percentile(cpu, 95):.2f} ms (preemption)"))
    ratio = medians[3840] / medians[1920]
    rows.append(
        _row(
            "render time ratio 3840x2160 / 1920x1080",
            ratio,
            "",
            1.5,
            ratio <= 1.5,
            "sparse update: cost follows the stars, not the pixels",
        )
    )
    r = Renderer(default_bench(1920, 1080))
    ts = []
    for q in qs:
        t0 = time.perf_counter()
        r.render(q, epoch, screen=False, copy=False)
        ts.append(time.perf_counter() - t0)
    rows.append(_row("detector image 1024x768 median (info)", np.median(ts) * 1e3, "ms"))
    return rows


def display_node_rows(n_frames: int) -> list[dict]:
    """Round trip of the display node on loopback: state sent -> frame rendered and handed on.

    Sender and node run in one thread (send, then ``serve(max_frames=1)``), so the time is the
    node's own work: UDP send and receive, decode, render at 1920 x 1080, push to the output."""
    from stand.display import DisplayNode, StateSender
    from star_screen.outputs import FrameQueue

    epoch = Epoch.from_iso(EPOCH)
    qs = _attitudes(n_frames + 5, seed=11)[: n_frames + 5]
    renderer = Renderer(default_bench(1920, 1080))
    ts = []
    with DisplayNode(("127.0.0.1", 0), renderer, FrameQueue(1), copy=False) as node, StateSender(
        *node.address, scenario_epoch=epoch
    ) as sender:
        for i, q in enumerate(qs):
            t0 = time.perf_counter()
            sender.send(q, i * 100_000_000, v_sc_gcrs_m_s=(7000.0, 0.0, 0.0))
            node.serve(max_frames=1, timeout_s=2.0)
            if i >= 5:  # the first frames warm the caches
                ts.append(time.perf_counter() - t0)
        st = node.stats
    ts = np.array(ts) * 1e3
    note = (f"{len(ts)} frames, loopback UDP, send -> decode -> render 1920x1080 -> output, one thread, wall clock; "
            f"{st.rendered} rendered, {st.corrupt + st.duplicate + st.out_of_order + st.superseded} dropped; "
            "sim time advances 0.1 s per frame (catalog places are refreshed on an hourly grid, "
            "so moving time costs nothing extra)")
    return [
        _row("display node round trip 1920x1080 median", np.median(ts), "ms", note=note),
        _row("display node round trip 1920x1080 p95", np.percentile(ts, 95), "ms"),
    ]


def bench_render(quick: bool = False) -> list[dict]:
    """Measure the star-screen acceptance; ``quick`` uses fewer attitudes and frames."""
    return (geometry_rows(20 if quick else 120) + speed_rows(60 if quick else 300)
            + display_node_rows(30 if quick else 300))


if __name__ == "__main__":  # pragma: no cover
    import sys

    for row in bench_render(quick="--quick" in sys.argv):
        print(row)
