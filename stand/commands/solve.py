"""``stand solve``: solve one detector image lost in space and print the attitude as JSON.

    stand solve IMAGE [--fov-deg 20x15] [--psf-sigma-px 1.0] [--epoch ISO] [--aberration on|off]
                      [--mag-limit 8]

IMAGE is a single-channel PNG (16-bit as ``stand screen`` writes ``detector_raw.png``, or 8-bit; a
colour image is converted to grey). The stretched 8-bit ``detector.png`` solves too, but its
centroids are less accurate: solve the raw file. The field of view is the full undistorted field
along the image's x and y (pinhole optics centred on the image). The JSON holds ``q_SN`` (tracker frame S
relative to GCRS, scalar first, w >= 0; S: +z boresight, +x image right, +y image down), the
boresight's ``ra_deg``, ``dec_deg`` and ``roll_deg`` in the convention of ``stand screen``
(``star_screen.attitude``), ``stars_centroided``, ``stars_matched``, ``sigma_cross_arcsec``,
``sigma_roll_arcsec`` and ``valid``.

``--aberration on`` (default, as ``stand screen`` renders) solves against apparent places for an
observer moving with the Earth at ``--epoch``; ``off`` against catalog places (proper motion only).
Exit codes: 0 solved, 1 no valid solution (the JSON says ``"valid": false``), 2 usage error.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

DEFAULT_EPOCH = "2026-01-01T00:00:00Z"


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "solve",
        help="solve one detector image lost in space; print q_SN, ra/dec/roll as JSON",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("image", help="detector image file (PNG, 16-bit or 8-bit, single channel)")
    p.add_argument("--fov-deg", default="20x15", help="full field of view along x and y, deg (default 20x15)")
    p.add_argument("--psf-sigma-px", type=float, default=1.0, help="star spot Gaussian sigma, px (default 1)")
    p.add_argument("--epoch", default=DEFAULT_EPOCH, help=f"UTC epoch, ISO 8601 (default {DEFAULT_EPOCH})")
    p.add_argument("--aberration", choices=("on", "off"), default="on",
                   help="solve against apparent places (on, default) or catalog places (off)")
    p.add_argument("--mag-limit", type=float, default=8.0, help="faintest catalog star used, Hp (default 8)")
    p.set_defaults(func=run)
    return p


def _fail(msg: str) -> int:
    print(f"stand: error: {msg}", file=sys.stderr)
    return 2


def _read_image(path: str):
    import pathlib

    import numpy as np

    if not pathlib.Path(path).is_file():
        raise ValueError(f"IMAGE {path!r} does not exist or is not a file; give a PNG written by 'stand screen'.")
    try:
        import cv2
    except ImportError:  # pragma: no cover - depends on the installation
        raise ValueError(
            "reading images needs OpenCV; it is part of the base install (pip install adcs-stand)."
        ) from None
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"IMAGE {path!r} could not be read as an image; give a PNG (8- or 16-bit).")
    if img.ndim == 3:
        img = cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2GRAY)
    if img.ndim != 2 or img.dtype.kind not in "uif":
        raise ValueError(f"IMAGE {path!r} has shape {img.shape} and type {img.dtype}; a 2-D grey image is needed.")
    return img.astype(np.float32)


def run(args) -> int:
    try:
        fx_txt, fy_txt = str(args.fov_deg).lower().split("x")
        fov_x, fov_y = float(fx_txt), float(fy_txt)
    except ValueError:
        return _fail(f"--fov-deg {args.fov_deg!r} is not a field of view; write it as XxY in degrees, e.g. 20x15.")
    if not (math.isfinite(args.psf_sigma_px) and 0.3 <= args.psf_sigma_px <= 10.0):
        return _fail(f"--psf-sigma-px {args.psf_sigma_px!r}; it must lie between 0.3 and 10 pixels.")
    from sim.ephemeris import earth_pv_bcrs
    from sim.time import Epoch
    from star_screen.attitude import radec_roll_from_q_SN
    from star_screen.geometry import TrackerOptics
    from star_screen.tracking import StarTracker

    try:
        image = _read_image(args.image)
        epoch = Epoch.from_iso(args.epoch)
        h, w = image.shape
        optics = TrackerOptics.from_fov(fov_x, fov_y, w, h, psf_sigma_px=args.psf_sigma_px,
                                        mag_limit=args.mag_limit)
        tracker = StarTracker(mag_limit=args.mag_limit, epoch=epoch)
    except (ValueError, FileNotFoundError) as exc:
        return _fail(str(exc))
    v_obs = earth_pv_bcrs(epoch)[1] if args.aberration == "on" else None
    sol = tracker.solve(image, optics, epoch=epoch, observer_velocity_m_s=v_obs)
    out = {
        "image": str(args.image),
        "valid": sol.valid,
        "mode": sol.mode,
        "q_SN": [float(v) for v in sol.q_SN] if sol.valid else None,
        "q_convention": "scalar-first [w, x, y, z]; v_S = dcm(q_SN) @ v_N; S: +z boresight, +x image right, "
        "+y image down; N: GCRS",
        "stars_centroided": sol.stars_centroided,
        "stars_matched": sol.stars_matched,
        "sigma_cross_arcsec": sol.sigma_cross_arcsec if sol.valid else None,
        "sigma_roll_arcsec": sol.sigma_roll_arcsec if sol.valid else None,
        "false_match_probability": sol.false_prob,
        "epoch_utc": epoch.iso,
        "aberration": args.aberration == "on",
        "fov_deg": [fov_x, fov_y],
    }
    if sol.valid:
        ra, dec, roll = radec_roll_from_q_SN(sol.q_SN)
        out.update(ra_deg=float(ra), dec_deg=float(dec), roll_deg=float(roll))
    print(json.dumps(out, indent=1))
    return 0 if sol.valid else 1

