"""Static panoramas for reports: ``stand view RUN_DIR --export DIR`` and the run report's ``panorama.png``.

The same picture as the page's panorama (``assets/view.js``), drawn with matplotlib from the same samples and
the same projection (``state.project``): catalog stars sized by magnitude, the Earth with its day and night
sides, the Sun and the Moon, the body axes, the velocity, nadir and field directions, and every field of view
coloured by the device's state at that time.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sim.constants import R_EARTH
from sim.rotations import dcm
from sim.time import Epoch
from stand.telemetry import load

from . import state

FRAMES = {"body": "B", "gcrs": "N", "lvlh": "O", "itrs": "E"}
#: The page's colours (view.js COLORS), 0-255.
_RGB = {"sun": (255, 200, 0), "moon": (190, 196, 210), "valid": (60, 220, 90), "sun_flag": (255, 60, 60),
        "moon_flag": (255, 150, 40), "earth_flag": (80, 160, 255), "rate": (200, 110, 255), "none": (140, 140, 140),
        "acquiring": (230, 200, 60)}
COLORS = {k: tuple(c / 255 for c in v) for k, v in _RGB.items()}
AXIS_COLORS = ("#ff5555", "#55e678", "#5a96ff")
#: Bits of a tracker's NAME.flags (the ICD's flags byte) that say why a solution is not valid (view.js FLAG_BITS).
FLAG_BITS = ((2, "Sun", "sun_flag"), (4, "Moon", "moon_flag"), (8, "Earth", "earth_flag"), (16, "rate", "rate"))


def _lvlh(r, v):
    z = -r / np.linalg.norm(r)
    y = -np.cross(r, v)
    y /= np.linalg.norm(y)
    return np.stack((np.cross(y, z), y, z))


def frame_dcm(samples: dict, i: int, frame: str) -> np.ndarray:
    """dcm_FN of the panorama's frame at sample ``i`` (``B``, ``N``, ``O`` or ``E``)."""
    if frame == "N":
        return np.eye(3)
    if frame == "B":
        return dcm(samples["q_BN"][i])
    if frame == "E":
        return dcm(samples["q_EN"][i])
    if frame == "O":
        return _lvlh(np.asarray(samples["r_BN_N"][i]), np.asarray(samples["v_BN_N"][i]))
    raise ValueError(f"panorama frame {frame!r} is not one of B, N, O, E.")


def inverse(kind: str, x, y, width: float, height: float):
    """Directions (..., 3) under pixels, and a mask of pixels that are on the sky."""
    if kind == "equirectangular":
        lon = (width / 2 - x) / width * 2 * math.pi
        lat = (height / 2 - y) / height * math.pi
        ok = (np.abs(lat) <= math.pi / 2) & (np.abs(lon) <= math.pi)
    else:
        hx = (width / 2 - x) / (width / 2) * 2 * math.sqrt(2)
        hy = (height / 2 - y) / (height / 2) * math.sqrt(2)
        ok = hx * hx / 8 + hy * hy / 2 <= 1
        z = np.sqrt(np.clip(1 - (hx / 4) ** 2 - (hy / 2) ** 2, 0, 1))
        lon = 2 * np.arctan2(z * hx, 2 * (2 * z * z - 1))
        lat = np.arcsin(np.clip(z * hy, -1, 1))
    u = np.stack((np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)), axis=-1)
    return u, ok


def device_state(samples: dict, dev: dict, i: int) -> tuple[str, str]:
    """(colour key, text) of a device at sample ``i``, as the page colours its field of view."""
    n = dev["name"]
    valid = samples.get(f"{n}.valid")
    if valid is None or not np.isfinite(valid[i]):
        return "none", "no solution"
    if valid[i] >= 0.5:
        return "valid", "valid"
    flags = samples.get(f"{n}.flags")
    hit = [(name, key) for bit, name, key in FLAG_BITS if flags is not None and int(flags[i]) & bit]
    if hit:
        return hit[0][1], "invalid: " + ", ".join(h[0] for h in hit)
    key, text = (dev.get("state") or {}).get("invalid") or ("sun_flag", "invalid")
    return key, text


def _boundary(fov: dict, n: int = 96) -> np.ndarray:
    if fov["shape"] == "rect":
        tx, ty = (math.tan(math.radians(a) / 2) for a in fov["fov_deg"])
        corners = np.array([[-tx, -ty], [tx, -ty], [tx, ty], [-tx, ty], [-tx, -ty]])
        f = np.linspace(0, 1, n // 4, endpoint=False)[:, None]
        edges = [c0 + f * (c1 - c0) for c0, c1 in zip(corners[:-1], corners[1:], strict=True)]
        pts = np.concatenate([*edges, corners[:1]])
        u = np.column_stack((pts, np.ones(len(pts))))
    else:
        a = np.asarray(fov["axis_S"], dtype=float)
        ref = np.array([0.0, 0.0, 1.0]) if abs(a[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        e1 = np.cross(a, ref)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(a, e1)
        h = math.radians(fov["half_deg"])
        phi = np.linspace(0, 2 * math.pi, n + 1)[:, None]
        u = math.cos(h) * a + math.sin(h) * (np.cos(phi) * e1 + np.sin(phi) * e2)
    return u / np.linalg.norm(u, axis=-1, keepdims=True)


def _broken(pts: np.ndarray, width: float) -> np.ndarray:
    """The polyline with NaN rows where the projection wraps (one artist draws all its pieces)."""
    jumps = np.flatnonzero(np.hypot(*np.diff(pts, axis=0).T) > 0.25 * width) + 1
    return np.insert(pts, jumps, np.nan, axis=0)


def _polyline(ax, pts: np.ndarray, width: float, **kw) -> None:
    b = _broken(pts, width)
    ax.plot(b[:, 0], b[:, 1], **kw)


def _land() -> list[np.ndarray]:
    """The land outlines the page draws (assets/land-110m.json), as (n, 2) lon-lat arrays in degrees."""
    import json

    rings = json.loads((Path(__file__).with_name("assets") / "land-110m.json").read_text())["rings"]
    return [np.asarray(r, dtype=float).reshape(-1, 2) for r in rings]


def _earth_lines(ax, samples, i, M, r, kind, W, H) -> None:
    """Coastlines and the 30 deg net on the side of the Earth the spacecraft sees."""
    C_EN = dcm(samples["q_EN"][i])
    net = [np.column_stack((np.arange(-180, 181, 4.0), np.full(91, lat))) for lat in (-60, -30, 0, 30, 60)]
    net += [np.column_stack((np.full(45, lon), np.arange(-88, 89, 4.0))) for lon in range(-180, 180, 30)]
    for rings, colour in ((net, (0.78, 0.86, 1.0, 0.22)), (_land(), (0.55, 0.86, 0.59, 0.8))):
        pieces = []
        for ring in rings:
            lon, lat = np.radians(ring[:, 0]), np.radians(ring[:, 1])
            e = R_EARTH * np.column_stack((np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)))
            p_N = e @ C_EN  # ITRS -> GCRS, as row vectors
            d = p_N - r
            seen = np.sum(d * p_N, axis=1) < 0
            pts = state.project(d @ M.T, kind, W, H)
            pts[~seen] = np.nan
            pieces.append(_broken(pts, W))
            pieces.append(np.full((1, 2), np.nan))
        b = np.concatenate(pieces)
        ax.plot(b[:, 0], b[:, 1], color=colour, lw=0.7, zorder=3)



def _draw_graticule(ax, kind: str, W: int, H: int) -> None:
    """Lines of the panorama's own latitude every 30 deg (to +-60) and longitude every 30 deg."""
    for lat in range(-60, 61, 30):
        lon = np.radians(np.arange(-180, 181, 3))
        la = math.radians(lat)
        _polyline(ax, state.project(np.column_stack((np.cos(la) * np.cos(lon), np.cos(la) * np.sin(lon),
                                                     np.full_like(lon, math.sin(la)))), kind, W, H), W,
                  color=(0.47, 0.55, 0.67, 0.25), lw=0.6)
    for lon_d in range(-150, 181, 30):
        lat = np.radians(np.arange(-90, 91, 3))
        lo = math.radians(lon_d)
        _polyline(ax, state.project(np.column_stack((np.cos(lat) * math.cos(lo), np.cos(lat) * math.sin(lo),
                                                     np.sin(lat))), kind, W, H), W,
                  color=(0.47, 0.55, 0.67, 0.25), lw=0.6)

def draw_panorama(ax, samples: dict, meta: dict, i: int, *, frame: str = "B", kind: str = "equirectangular",
                  width: int = 1200, height: int = 600, mag_limit: float = 6.0, stars=None) -> dict:
    """Draw the panorama of sample ``i`` on a matplotlib axes in pixel coordinates; returns what was drawn
    where (name -> pixel) for tests."""
    M = frame_dcm(samples, i, frame)
    W, H = width, height
    ax.set_xlim(0, W)
    ax.set_ylim(H, 0)
    ax.set_aspect("equal")
    ax.axis("off")
    from matplotlib.patches import Rectangle

    ax.add_patch(Rectangle((0, 0), W, H, color="#03050a", zorder=0))
    where = {}

    def at(u_N):
        return state.project(np.asarray(u_N, dtype=float) @ M.T, kind, W, H)

    r = np.asarray(samples["r_BN_N"][i], dtype=float)
    rn = float(np.linalg.norm(r))
    _draw_graticule(ax, kind, W, H)
    if stars is not None:
        u_N, mag = stars
        sel = mag <= mag_limit
        p = at(u_N[sel])
        size = np.maximum(0.7, 3.2 - 0.42 * mag[sel])
        ax.scatter(p[:, 0], p[:, 1], s=size ** 2 * 0.35, c="white", marker="s", linewidths=0, alpha=0.9)
    # the Earth, per pixel at half resolution
    ys, xs = np.mgrid[0:H:2, 0:W:2] + 1.0  # half resolution, smoothed: the limb stays clean at report size
    u, ok = inverse(kind, xs, ys, W, H)
    u_N = u @ M  # frame F -> N
    b = u_N @ r
    disc = b * b - (rn * rn - R_EARTH * R_EARTH)
    hit = ok & (disc >= 0) & (b < 0)
    s = -b - np.sqrt(np.maximum(disc, 0))
    p = r + s[..., None] * u_N
    n = p / R_EARTH
    lit = n @ np.asarray(samples["sun_N"][i])
    day = np.clip((lit + 0.05) / 0.1, 0, 1)
    shade = 0.55 + 0.45 * np.clip(-np.sum(n * u_N, axis=-1), 0, 1)
    rgba = np.zeros(xs.shape + (4,))
    rgba[..., 0] = (12 + day * 40) * shade / 255
    rgba[..., 1] = (22 + day * 95) * shade / 255
    rgba[..., 2] = (45 + day * 170) * shade / 255
    rgba[..., 3] = np.where(hit, 1.0, 0.0)
    ax.imshow(rgba, extent=(0, W, H, 0), interpolation="bilinear", zorder=2)
    _earth_lines(ax, samples, i, M, r, kind, W, H)
    # Sun, Moon, body axes, velocity, nadir, field
    earth_half = math.asin(min(1.0, R_EARTH / rn))
    for body in ("sun", "moon"):
        u_b = np.asarray(samples[f"{body}_N"][i], dtype=float)
        pb = at(u_b)
        hidden = math.acos(float(np.clip(u_b @ (-r / rn), -1, 1))) < earth_half
        ax.plot(*pb, "o", ms=14 if body == "sun" else 11, mfc="none" if hidden else COLORS[body], mec=COLORS[body],
                zorder=5)
        ax.annotate("Sun" if body == "sun" else "Moon", pb, xytext=(9, -6), textcoords="offset points",
                    color=COLORS[body], fontsize=8, zorder=6)
        where[body] = pb
    C_BN = dcm(samples["q_BN"][i])
    for a in range(3):
        for sgn in (1, -1):
            pa = at(sgn * C_BN[a])
            name = ("+" if sgn > 0 else "-") + "XYZ"[a]
            ax.plot(*pa, "s", ms=6, mfc=AXIS_COLORS[a] if sgn > 0 else "none", mec=AXIS_COLORS[a], zorder=5)
            ax.annotate(name, pa, xytext=(6, 5), textcoords="offset points", color=AXIS_COLORS[a], fontsize=7, zorder=6)
            where[name] = pa
    v = np.asarray(samples["v_BN_N"][i], dtype=float)
    marks = [("+v", v / np.linalg.norm(v), "white"), ("nadir", -r / rn, "#78c8ff")]
    if "b_true_B" in samples and np.linalg.norm(samples["b_true_B"][i]) > 0:
        bN = C_BN.T @ np.asarray(samples["b_true_B"][i], dtype=float)
        marks.append(("B", bN / np.linalg.norm(bN), "#e678ff"))
    for name, u_m, col in marks:
        pm = at(u_m)
        ax.plot(*pm, "+", ms=10, color=col, mew=1.2, zorder=5)
        ax.annotate(name, pm, xytext=(6, -9), textcoords="offset points", color=col, fontsize=7, zorder=6)
        where[name] = pm
    for dev in meta["devices"]:
        key, text = device_state(samples, dev, i)
        C_SB = dcm(dev["q_SB"])
        for k, fov in enumerate(dev["fovs"]):
            col = COLORS[key]
            if fov.get("head"):
                cur = samples.get(f"{dev['name']}.currents")
                col = (1.0, 0.82, 0.3) if cur is not None and cur[i][k] > 1e-6 else (0.5, 0.5, 0.5)
            bound = _boundary(fov) @ C_SB @ C_BN  # sensor -> body -> N, as row vectors
            _polyline(ax, at(bound), W, color=col, lw=0.8 if fov.get("head") else 1.8,
                      ls="--" if fov.get("head") else "-", zorder=4)
            for body, colour_key in (("sun", "sun_flag"), ("moon", "moon_flag"), ("earth", "earth_flag")):
                half = dev.get("exclusion_deg", {}).get(body)
                if half and not fov.get("head"):
                    cone = _boundary({"shape": "cone", "axis_S": fov["axis_S"], "half_deg": half})
                    _polyline(ax, at(cone @ C_SB @ C_BN), W, color=(*COLORS[colour_key], 0.55), lw=0.8, ls=":",
                              zorder=4)
            if not fov.get("head"):
                pb = at(np.asarray(fov["axis_S"], dtype=float) @ C_SB @ C_BN)
                ax.annotate(f"{dev['name']}: {text}", pb, xytext=(6, 6), textcoords="offset points", color=col,
                            fontsize=8, zorder=6)
                where[fov["label"]] = pb
    return where


def star_places(meta: dict, mag_limit: float):
    from star_screen.catalog import Catalog

    cat = Catalog.load(mag_limit=mag_limit)
    places = cat.places(Epoch.from_iso(meta["epoch"]), parallax=False)
    return places.u_N, np.asarray(places.mag, dtype=float)


def _check_times(times_s, t) -> None:
    lo, hi = float(np.min(t)), float(np.max(t))
    bad = [x for x in times_s if not lo - 1e-9 <= x <= hi + 1e-9]
    if bad:
        raise ValueError(f"--times {', '.join(f'{x:g}' for x in bad)} is not allowed: times within the run, "
                         f"{lo:g} to {hi:g} s.")


def export(run_dir, out_dir, times_s=None, *, frame: str = "body", kind: str = "equirectangular",
           mag_limit: float = 6.0, samples: dict | None = None, meta: dict | None = None) -> list[Path]:
    """Write ``panorama_<t>s.png`` for each time (default: start, middle and end of the run)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if frame not in FRAMES:
        raise ValueError(f"--frame {frame!r} is not allowed: one of {', '.join(FRAMES)}.")
    if kind not in state.PROJECTIONS:
        raise ValueError(f"--projection {kind!r} is not allowed: one of {', '.join(state.PROJECTIONS)}.")
    if not -2.0 <= mag_limit <= 9.0:
        raise ValueError(f"--mag {mag_limit!r} is not allowed: a magnitude limit from -2 to 9 (the catalog's).")
    meta = meta or state.load_meta(run_dir)
    if samples is None:
        tel = load(run_dir)
        t_all = np.asarray(tel["t_s"])
        if len(t_all) == 0:
            raise ValueError(f"{run_dir} has no telemetry rows to draw.")
        if times_s is None:
            times_s = (float(t_all[0]), float(t_all[len(t_all) // 2]), float(t_all[-1]))
        _check_times(times_s, t_all)
        # Only the rows drawn, at full resolution: the row at or before each time.
        idx = np.clip(np.searchsorted(t_all, np.asarray(times_s) + 1e-9, side="right") - 1, 0, len(t_all) - 1)
        samples = state.Sky(meta).derive({k: np.asarray(v)[idx] for k, v in tel.items()})
    t = np.asarray(samples["t_s"])
    if len(t) == 0:
        raise ValueError(f"{run_dir} has no telemetry rows to draw.")
    if times_s is None:
        times_s = (float(t[0]), float(t[len(t) // 2]), float(t[-1]))
    _check_times(times_s, t)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stars = star_places(meta, mag_limit)
    written = []
    epoch = Epoch.from_iso(meta["epoch"])
    for ts in times_s:
        i = int(np.argmin(np.where(t <= ts + 1e-9, ts - t, np.inf)))  # the sample at or before ts
        fig = plt.figure(figsize=(12, 6.4), dpi=100, facecolor="#0d1117")
        ax = fig.add_axes((0, 0, 1, 0.94))
        draw_panorama(ax, samples, meta, i, frame=FRAMES[frame], kind=kind, stars=stars, mag_limit=mag_limit)
        fig.text(0.01, 0.965, f"{meta['scenario']}: panorama in the {frame} frame ({kind}), t = {t[i]:.1f} s, "
                 f"{(epoch + float(t[i])).iso[:19]} UTC, stars to Hp {mag_limit:g}", color="#d8dee6", fontsize=10)
        path = out_dir / f"panorama_{t[i]:g}s.png"
        fig.savefig(path, facecolor=fig.get_facecolor())
        plt.close(fig)
        written.append(path)
    return written


def report_panorama(run_dir, sc=None) -> str | None:
    """``panorama.png`` at the end of a run, for its report (None when the run recorded nothing).
    ``sc``: the run's scenario (else ``view.json`` or the scenario the summary names)."""
    t = load(run_dir)["t_s"]
    if len(t) == 0:
        return None
    meta = state.describe(sc) if sc is not None else state.load_meta(run_dir)
    path = export(run_dir, run_dir, (float(t[-1]),), meta=meta)[0]
    target = Path(run_dir) / "panorama.png"
    path.replace(target)
    return target.name
