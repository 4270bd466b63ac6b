"""``stand bench env``: per-call cost of the environment models against the anchors of docs/benchmarks.md.

Machines are noisy: the anchors are the table's figures from another run, quoted for scale, not
measured side by side; compare orders of magnitude. Nothing here is asserted in tests.
"""

from __future__ import annotations

import time

import numpy as np


def _per_call_us(fn, n: int) -> float:
    fn()  # warm caches (coefficient files, lru tables)
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t0) / n)
    return best * 1e6


def bench_env(quick: bool = False) -> list[dict]:
    from sim import environment, ephemeris, frames, gravity, igrf
    from sim.time import Epoch

    n = 50 if quick else 400
    rng = np.random.default_rng(0)
    epoch = Epoch.from_iso("2026-06-01T00:00:00Z")
    r1 = np.array([4.0e6, 1.0e6, 5.5e6])
    big = rng.normal(size=(10_000, 3))
    big *= (6.9e6 / np.linalg.norm(big, axis=1))[:, None]
    jd = epoch.jd_tt
    track = ephemeris.EphemerisTrack(epoch, "moon")
    t_big = np.linspace(0.0, 86400.0, 10_000)
    field = gravity.load_field("jgm3", 20)
    r_sun = ephemeris.sun_position_gcrs(epoch)
    rows = [
        ("igrf14_deg13_single_point", _per_call_us(lambda: igrf.field_itrs(epoch, r1), n), "us",
         "docs/benchmarks.md: pyIGRF14 154 us, brahe 8 us, ppigrf 16 ms", 20.0),
        ("igrf14_deg13_per_point_vectorised_10k", _per_call_us(lambda: igrf.field_itrs(2026.4, big), 3) / 1e4,
         "us", "10,000 points per call (truth.py evaluates chunks)", None),
        ("dipole_single_point", _per_call_us(lambda: environment.magnetic_field_itrs(epoch, r1, model="dipole"), n),
         "us", "", None),
        ("sun_erfa_epv00", _per_call_us(lambda: ephemeris.sun_position_gcrs(jd), n), "us",
         "docs/benchmarks.md: 75 us", None),
        ("moon_erfa_moon98", _per_call_us(lambda: ephemeris.moon_position_gcrs(jd), n), "us",
         "docs/benchmarks.md: 8.5 us", None),
        ("moon_track_per_point_vectorised_10k", _per_call_us(lambda: track.position_gcrs(t_big), 3) / 1e4, "us",
         "1 h grid, cubic Hermite, nodes cached", None),
        ("sun_analytic_single", _per_call_us(lambda: ephemeris.sun_position_gcrs_analytic(jd), n), "us",
         "42 arcsec worst vs DE421", None),
        ("gcrs_to_itrs_c2t06a", _per_call_us(lambda: frames.dcm_itrs_gcrs(epoch), n), "us",
         "docs/benchmarks.md: pyerfa c2t06a 57 us", None),
        ("gravity_jgm3_20x20_single_point", _per_call_us(lambda: field.accel_itrs(r1), n), "us",
         "docs/benchmarks.md: brahe 4.3 us, satkit 3.9 us at degree 20", None),
        ("gravity_jgm3_20x20_per_point_vectorised_10k", _per_call_us(lambda: field.accel_itrs(big), 3) / 1e4, "us",
         "", None),
        ("shadow_conical_per_point_vectorised_10k",
         _per_call_us(lambda: environment.shadow_fraction(big, r_sun), 3) / 1e4, "us", "", None),
    ]
    out = []
    for name, value, unit, note, limit in rows:
        row = {"name": name, "value": float(value), "unit": unit, "note": note}
        if limit is not None:
            row["limit"] = limit
            row["pass"] = bool(value <= limit)
        out.append(row)
    return out
