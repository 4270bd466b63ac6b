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
#: The map's outline and the margin (pixels of the panorama) left around it.
OUTLINE = (0.6, 0.66, 0.75)
MARGIN_PX = 14
#: A coarse sun sensor head's field: lit (a current flows) or dark.
HEAD_LIT, HEAD_DARK = (1.0, 0.82, 0.3), (0.5, 0.5, 0.5)
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
    # a kind that does not say why is drawn "no solution", never in a colour the legend gives a meaning
    key, text = (dev.get("state") or {}).get("invalid") or ("none", "invalid")
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



#: Points to panorama pixels at the export's scale (100 dpi, the 1200-pixel map drawn about 1130 pixels wide).
_PT = 100 / 72 * 1200 / 1130


class _Labels:
    """Places the panorama's point labels so that none covers another or runs off the map: each tries the
    offsets right of its point, then above and below, then left, and takes the first free one."""

    def __init__(self, ax, width: float, height: float):
        self.ax, self.W, self.H, self.boxes = ax, width, height, []

    def _box(self, p, w, h, dx, dy, left: bool):
        x0 = p[0] - dx * _PT - w if left else p[0] + dx * _PT
        yc = p[1] - dy * _PT
        return (x0, yc - h / 2, x0 + w, yc + h / 2)

    def _free(self, b) -> bool:
        inside = b[0] >= 0 and b[2] <= self.W and b[1] >= 0 and b[3] <= self.H
        return inside and not any(b[0] < o[2] and o[0] < b[2] and b[1] < o[3] and o[1] < b[3] for o in self.boxes)

    def add(self, text: str, p, colour, fontsize: float, dx: float, dy: float) -> None:
        if not np.all(np.isfinite(p)):
            return
        w, h = 0.6 * fontsize * len(text) * _PT, 1.25 * fontsize * _PT
        tries = [(dx, dy + k * 1.2 * fontsize, left) for left in (False, True) for k in (0, -1, 1, -2, 2, -3, 3)]
        pick = next((c for c in tries if self._free(self._box(p, w, h, *c))), tries[0])
        self.boxes.append(self._box(p, w, h, *pick))
        off_x = -pick[0] if pick[2] else pick[0]
        self.ax.annotate(text, p, xytext=(off_x, pick[1]), textcoords="offset points", color=colour,
                         fontsize=fontsize, ha="right" if pick[2] else "left", va="center", zorder=6)


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
    # a margin around the map, so the Hammer outline's top and bottom and a marker on the edge are not cut
    pad = MARGIN_PX
    ax.set_xlim(-pad, W + pad)
    ax.set_ylim(H + pad, -pad)
    ax.set_aspect("equal")
    ax.axis("off")
    from matplotlib.patches import Ellipse, Rectangle

    if kind == "hammer":
        ax.add_patch(Ellipse((W / 2, H / 2), W, H, facecolor="#03050a", edgecolor=OUTLINE, lw=1.0, zorder=0))
    else:
        ax.add_patch(Rectangle((0, 0), W, H, facecolor="#03050a", edgecolor=OUTLINE, lw=1.0, zorder=0))
    where = {}
    labels = _Labels(ax, W, H)

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
        labels.add("Sun" if body == "sun" else "Moon", pb, COLORS[body], 8, 9, -6)
        where[body] = pb
    C_BN = dcm(samples["q_BN"][i])
    for a in range(3):
        for sgn in (1, -1):
            pa = at(sgn * C_BN[a])
            name = ("+" if sgn > 0 else "-") + "XYZ"[a]
            ax.plot(*pa, "s", ms=6, mfc=AXIS_COLORS[a] if sgn > 0 else "none", mec=AXIS_COLORS[a], zorder=5)
            labels.add(name, pa, AXIS_COLORS[a], 7, 6, 5)
            where[name] = pa
    v = np.asarray(samples["v_BN_N"][i], dtype=float)
    marks = [("+v", v / np.linalg.norm(v), "white"), ("nadir", -r / rn, "#78c8ff")]
    if "b_true_B" in samples and np.linalg.norm(samples["b_true_B"][i]) > 0:
        bN = C_BN.T @ np.asarray(samples["b_true_B"][i], dtype=float)
        marks.append(("B", bN / np.linalg.norm(bN), "#e678ff"))
    for name, u_m, col in marks:
        pm = at(u_m)
        ax.plot(*pm, "+", ms=10, color=col, mew=1.2, zorder=5)
        labels.add(name, pm, col, 7, 6, -9)
        where[name] = pm
    for dev in meta["devices"]:
        key, text = device_state(samples, dev, i)
        C_SB = dcm(dev["q_SB"])
        for k, fov in enumerate(dev["fovs"]):
            col = COLORS[key]
            if fov.get("head"):
                cur = samples.get(f"{dev['name']}.currents")
                col = HEAD_LIT if cur is not None and cur[i][k] > 1e-6 else HEAD_DARK
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
                labels.add(f"{dev['name']}: {text}", pb, col, 8, 6, 6)
                where[fov["label"]] = pb
    return where


def _degree_ticks(ax, kind: str, W: int, H: int) -> None:
    """Azimuth (the frame's longitude, about +Z from +X, increasing to the left) on x every 30 deg, where each
    meridian crosses the equator, and elevation (latitude from the X-Y plane) on y every 30 deg, where each
    parallel meets the map's left edge: the map's own degree labels on both axes."""
    lons = np.arange(180, -181, -30)
    px = state.project(np.column_stack((np.cos(np.radians(lons)), np.sin(np.radians(lons)), np.zeros(len(lons)))),
                       kind, W, H)[:, 0]
    px[0], px[-1] = 0.0, float(W)  # +-180 deg: the left and right edge (the projection's wrap)
    lats = np.arange(-90, 91, 30)
    la = np.radians(lats)
    edge = np.column_stack((-np.cos(la), np.full(len(la), 1e-9), np.sin(la)))  # azimuth just under 180 deg
    py = state.project(edge, kind, W, H)[:, 1]
    ax.axis("on")
    for side in ax.spines.values():
        side.set_visible(False)
    ax.set_xticks(px, [f"{v:d}°" for v in lons])
    ax.set_yticks(py, [f"{v:+d}°" if v else "0°" for v in lats])
    ax.tick_params(colors="#c9d1d9", labelsize=8, length=3, pad=2)
    ax.set_xlabel("azimuth in the frame: about +Z from +X, increasing to the left (deg)", color="#c9d1d9",
                  fontsize=9)
    ax.set_ylabel("elevation from the X-Y plane (deg)", color="#c9d1d9", fontsize=9)


def _legend_handles(meta: dict, field: bool = True) -> list:
    """What each mark and colour means, for what this run draws (a kind's states only when it has that device)."""
    from matplotlib.lines import Line2D

    def mark(label, marker, colour, filled=True, ms=8, mew=1.0):
        return Line2D([], [], ls="none", marker=marker, ms=ms, mec=colour, mew=mew, mfc=colour if filled else "none",
                      label=label)

    def line(label, colour, ls="-", lw=1.8):
        return Line2D([], [], color=colour, ls=ls, lw=lw, label=label)

    h = [mark("Sun", "o", COLORS["sun"]), mark("Sun behind the Earth", "o", COLORS["sun"], False),
         mark("Moon (hollow: behind the Earth)", "o", COLORS["moon"], ms=7),
         *(mark(f"body +{a} (hollow: -{a})", "s", c, ms=6) for a, c in zip("XYZ", AXIS_COLORS, strict=True)),
         mark("velocity +v", "+", "white", ms=9, mew=1.2), mark("nadir", "+", "#78c8ff", ms=9, mew=1.2)]
    if field:
        h.append(mark("magnetic field B", "+", "#e678ff", ms=9, mew=1.2))
    devs = meta.get("devices", [])
    keys = {"valid"}
    flags = False
    for d in devs:
        st = d.get("state")
        if st:
            keys |= {device_state({}, d, 0)[0]}
            keys.add(st["invalid"][0])
            flags = flags or bool(st.get("flags"))
    if flags:
        keys |= {"sun_flag", "moon_flag", "earth_flag", "rate"}
    words = {"valid": "field of view: valid", "sun_flag": "field: Sun in field", "moon_flag": "field: Moon in field",
             "earth_flag": "field: Earth in field", "rate": "field: rate too high", "acquiring": "field: acquiring",
             "none": "field: no solution / no Sun"}
    h += [line(words[k], COLORS[k]) for k in words if k in keys]
    if any(f.get("head") for d in devs for f in d.get("fovs", [])):
        h += [line("sun sensor head: lit", HEAD_LIT, "--", 1.0), line("sun sensor head: dark", HEAD_DARK, "--", 1.0)]
    if any(d.get("exclusion_deg") for d in devs):
        h.append(line("exclusion cone (Sun, Moon, Earth colour)", (0.8, 0.8, 0.8), ":", 1.0))
    return h


def panorama_figure(samples: dict, meta: dict, i: int, *, frame: str = "body", kind: str = "equirectangular",
                    mag_limit: float = 6.0, stars=None):
    """The export's figure of sample ``i``: title, the map with degree labels on both axes, and a legend below."""
    from matplotlib.figure import Figure

    t = float(samples["t_s"][i])
    fig = Figure(figsize=(12, 7.8), dpi=100, facecolor="#0d1117")
    ax = fig.add_axes((0.06, 0.2, 0.92, 0.74), facecolor=fig.get_facecolor())
    draw_panorama(ax, samples, meta, i, frame=FRAMES[frame], kind=kind, stars=stars, mag_limit=mag_limit)
    _degree_ticks(ax, kind, 1200, 600)
    epoch = Epoch.from_iso(meta["epoch"])
    fig.text(0.01, 0.975, f"{meta['scenario']}: panorama in the {frame} frame ({kind}), t = {t:.1f} s, "
             f"{(epoch + t).iso[:19]} UTC, stars to Hp {mag_limit:g}", color="#d8dee6", fontsize=10, va="top")
    handles = _legend_handles(meta, "b_true_B" in samples)
    fig.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.5, 0.005), ncol=5, fontsize=8,
               frameon=False, labelcolor="#d8dee6", handlelength=2.2, columnspacing=1.5)
    return fig


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
    for ts in times_s:
        i = int(np.argmin(np.where(t <= ts + 1e-9, ts - t, np.inf)))  # the sample at or before ts
        fig = panorama_figure(samples, meta, i, frame=frame, kind=kind, mag_limit=mag_limit, stars=stars)
        path = out_dir / f"panorama_{t[i]:g}s.png"
        fig.savefig(path, facecolor=fig.get_facecolor())
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
