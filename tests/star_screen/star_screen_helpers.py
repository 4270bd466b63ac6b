"""Helpers shared by the star_screen tests (units, synthetic catalogs)."""

import numpy as np

from star_screen.catalog import Catalog

EPOCH_ISO = "2026-01-01T00:00:00Z"
ARCSEC = np.pi / (180 * 3600)
MAS = ARCSEC / 1000


def synthetic_catalog(ra_deg, dec_deg, mag, hip=None) -> Catalog:
    """A catalog of given stars (no proper motion, no parallax), sorted by magnitude."""
    ra = np.radians(np.atleast_1d(np.asarray(ra_deg, float)))
    dec = np.radians(np.atleast_1d(np.asarray(dec_deg, float)))
    mag = np.broadcast_to(np.asarray(mag, np.float32), ra.shape).copy()
    hip = np.arange(1, ra.size + 1, dtype=np.int32) if hip is None else np.asarray(hip, np.int32)
    o = np.argsort(mag, kind="stable")
    z32 = np.zeros(ra.size, np.float32)
    return Catalog(hip[o], ra[o], dec[o], z32, z32, z32, mag[o], z32, 9.0)


def separation(u, v) -> np.ndarray:
    """Angle (rad) between unit vectors, accurate at small angles."""
    u = np.asarray(u, float)
    v = np.asarray(v, float)
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1))
