"""What an emulated or served star tracker measures: the sky seen from the tracker (true attitude, rate, Sun,
Moon and Earth in tracker axes) and, for ``source = "image"``, the detector image the star screen renders,
noised and solved (:class:`ImageSolver`). The kind and its devices are in :mod:`stand.devices.star_tracker`."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from sim.constants import R_EARTH
from sim.environment import R_SUN
from sim.rotations import hamilton_floats
from sim.truth import compose_floats, rotate_to_body

ARCSEC = math.pi / 180.0 / 3600.0
R_MOON = 1.7374e6
#: The Earth's disk as a tracker sees it includes the bright atmosphere.
ATMOSPHERE_M = 100e3


def measure_source(spec, ctx, dev):
    """The emulator's measurement source for tracker ``spec`` built in ``ctx``: the truth (or the image solver's
    solution) at an exposure; the true attitudes go to ``dev.truth_at`` and the image solver to ``dev.image``."""
    sky = sky_truth(spec, ctx.truth, ctx.tracks, dev)
    if spec.source != "image":
        return sky
    # The camera's own stream, spawned from the tracker's seed, so the emulator's draws are unchanged.
    dev.image = solver = ImageSolver(spec.optics, spec.camera, ctx.epoch, ctx.rng.spawn(1)[0])
    truth = ctx.truth

    def measure(t_s: float):
        out = sky(t_s)
        out = dataclasses.replace(out, **solver.solve(t_s, out.q_TN, out.omega_TN_T, truth.v_N))
        take = solver.on_frame  # set when the operator page asked for this exposure's image (stand.view.frames)
        if take is not None:
            take(t_s, dataclasses.asdict(out))
        return out

    return measure


class ImageSolver:
    """The image source of one tracker: render its detector image, add camera noise, solve it.

    Built once at compose time (renderer, catalog places, pattern database), so the first exposure
    costs what every other does. ``solve`` renders at the TRUE tracker attitude with orbital and
    annual aberration (``v_N``: the spacecraft's velocity) and the rate smear of the exposure, adds
    shot, background and read noise from its own seeded Generator, and solves the image against
    apparent places: tracking from the previous exposure's solution (propagated by the rotation
    between the two solutions before it, as a tracker's own rate estimate) when that one was valid,
    lost in space otherwise (and when tracking finds no match).
    """

    def __init__(self, optics, camera: dict, epoch, rng: np.random.Generator):
        from star_screen.geometry import default_bench
        from star_screen.render import Renderer
        from star_screen.tracking import StarTracker

        self.optics = optics
        self.camera = dict(camera)
        self.epoch = epoch
        self.rng = rng
        self.renderer = Renderer(default_bench(tracker=optics), aberration=True)
        self.tracker = StarTracker(catalog=self.renderer.catalog, mag_limit=optics.mag_limit, epoch=epoch)
        self.tracker.database(optics)  # the pattern database (about 1 s), now rather than on the first tick
        self.tracker.places(epoch, parallax=True)  # apparent places at the scenario epoch, cached
        self.exposure = self.tracker.sparse_exposure(optics, **self.camera)  # noise drawn where extraction looks
        self._last: tuple[float, np.ndarray] | None = None  # (t_s, q) of the previous exposure if valid
        self._before: tuple[float, np.ndarray] | None = None  # the valid one before it
        self.counts = {"frames": 0, "lis": 0, "tracking": 0, "failed": 0}
        self.frame_ms: list[float] = []
        #: Set by the live page's feed when it wants the next exposure's image, ``on_frame(t_s, fields)``, called
        #: from the loop after the solve (it unsets itself): None, and so free, when no page watches.
        self.on_frame = None

    def _prior(self, t_s: float):
        if self._last is None:
            return None
        t1, q1 = self._last
        if self._before is None:
            return np.array(q1)
        t0, q0 = self._before
        # The rotation of the tracker axes from t0 to t1 (w >= 0), its angle scaled to t_s - t1, then after q1.
        w0, x0, y0, z0 = q0
        w, x, y, z = hamilton_floats((w0, -x0, -y0, -z0), q1)
        if w < 0.0:
            w, x, y, z = -w, -x, -y, -z
        s = math.sqrt(x * x + y * y + z * z)
        if s == 0.0:
            return np.array(q1)
        half = math.atan2(s, w) * (t_s - t1) / (t1 - t0)
        k = math.sin(half) / s
        q = hamilton_floats(q1, (math.cos(half), k * x, k * y, k * z))
        return np.array(q if q[0] >= 0.0 else tuple(-c for c in q))

    def solve(self, t_s: float, q_TN, omega_TN_T, v_N) -> dict:
        """TrackerTruth fields measured from the exposure at ``t_s``: the solved q_TN, stars centroided
        and matched, 1-sigma errors (rad); an identity attitude and 0 stars matched when the solve fails."""
        from star_screen.render import SmearTooLong

        w0 = time.perf_counter()
        epoch = self.epoch + t_s
        v = np.asarray(v_N, dtype=float)
        try:
            _, lit, signal_e = self.renderer.detector_signal(q_TN, epoch, v_sc_gcrs_m_s=v, omega_SN_S=omega_TN_T)
        except SmearTooLong:  # stars trailed past the renderer's cap: no tracker solves such an image
            self.counts["frames"] += 1
            self.counts["failed"] += 1
            self.frame_ms.append((time.perf_counter() - w0) * 1e3)
            self._last = self._before = None
            return {"q_TN": (1.0, 0.0, 0.0, 0.0), "stars_matched": 0, "stars_in_field": 0}
        sol = self.tracker.solve_stars(self.exposure.stars(lit, signal_e, self.rng), self.optics, self._prior(t_s),
                                       observer_velocity_m_s=self.renderer.observer_velocity(epoch, v))
        self.counts["frames"] += 1
        self.frame_ms.append((time.perf_counter() - w0) * 1e3)
        seen = {"stars_in_field": int(sol.stars_centroided)}
        if not sol.valid:
            self.counts["failed"] += 1
            self._last = self._before = None
            return {"q_TN": (1.0, 0.0, 0.0, 0.0), "stars_matched": 0, **seen}
        self.counts[sol.mode] += 1
        self._before, self._last = self._last, (t_s, tuple(sol.q_SN.tolist()))
        return {"q_TN": tuple(float(x) for x in sol.q_SN), "stars_matched": int(sol.stars_matched),
                "sigma_cross_rad": float(sol.sigma_cross_arcsec) * ARCSEC,
                "sigma_roll_rad": float(sol.sigma_roll_arcsec) * ARCSEC, **seen}

    def summary(self) -> dict:
        ms = np.asarray(self.frame_ms)
        out = dict(self.counts)
        if len(ms):
            out["frame_ms"] = {"median": round(float(np.median(ms)), 2), "p95": round(float(np.percentile(ms, 95)), 2),
                               "max": round(float(ms.max()), 2)}
        return out



def sky_truth(spec, truth, tracks: dict, link):
    """``sky(t_s)``: the :class:`~drivers.star_tracker.measurement.TrackerTruth` at an exposure (true q_TN, rate,
    Sun, Moon and Earth in tracker axes), logging the true attitude in ``link.truth_at``; shared by every source.
    Built at once from its fields (no dict between), as the emulator takes one per exposure."""
    from drivers.frozen_build import keyword_maker
    from drivers.star_tracker.emulator import TrackerTruth

    q_SB = link.q_SB
    truth_at = link.truth_at
    has_sun, has_moon = "sun" in tracks, "moon" in tracks
    # Sun and Moon positions of the whole second (from LEO they move < 5 arcsec/s): [second, sun, moon].
    bodies: list = [None, None, None]
    # A body the stand left out is None, its radius the TrackerTruth default (never in the field either way).
    absent = TrackerTruth(q_TN=(1.0, 0.0, 0.0, 0.0))
    make_truth = keyword_maker(TrackerTruth)

    def toward(q_TN, body, r_N, radius: float):
        """(direction in T, angular radius) of ``body`` (its GCRS position, floats) seen from ``r_N``."""
        bx, by, bz = body
        rx, ry, rz = r_N
        d = (bx - rx, by - ry, bz - rz)
        return rotate_to_body(q_TN, d), math.asin(radius / math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2))

    def sky(t_s: float):
        if abs(t_s - truth.t_s) > 1e-6:
            raise ValueError(f"{spec.name}: exposure at t = {t_s:.6f} s but the truth is at {truth.t_s:.6f} s; "
                             "the output interval and boot time must be whole dynamics steps.")
        q_TN = compose_floats(q_SB, truth.q)
        truth_at[round(t_s * 1e6)] = q_TN
        r_N = truth.r_N
        rx, ry, rz = r_N
        rn = math.sqrt(rx * rx + ry * ry + rz * rz)
        sin_earth = (R_EARTH + ATMOSPHERE_M) / rn
        if not sin_earth < 1.0:  # min(1.0, ...) without its call (a NaN to 1.0 as min gives)
            sin_earth = 1.0
        second = int(t_s)
        if bodies[0] != second:  # floats: the same values, float arithmetic each exposure
            bodies[0] = second
            bodies[1] = tracks["sun"].position_gcrs_floats(float(second)) if has_sun else None
            bodies[2] = tracks["moon"].position_gcrs_floats(float(second)) if has_moon else None
        sun_T, sun_r = absent.sun_T, absent.sun_radius_rad
        if bodies[1] is not None:
            sun_T, sun_r = toward(q_TN, bodies[1], r_N, R_SUN)
        moon_T, moon_r = absent.moon_T, absent.moon_radius_rad
        if bodies[2] is not None:
            moon_T, moon_r = toward(q_TN, bodies[2], r_N, R_MOON)
        return make_truth({  # TrackerTruth(**these), with fewer calls
            "q_TN": q_TN, "omega_TN_T": rotate_to_body(q_SB, truth.w), "sun_T": sun_T, "moon_T": moon_T,
            "earth_T": rotate_to_body(q_TN, (-rx, -ry, -rz)), "sun_radius_rad": sun_r, "moon_radius_rad": moon_r,
            "earth_radius_rad": math.asin(sin_earth), "stars_in_field": None,
            "stars_matched": None, "sigma_cross_rad": None, "sigma_roll_rad": None})

    return sky
