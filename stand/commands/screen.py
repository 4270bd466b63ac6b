"""``stand screen``: render one star-screen frame to PNG files with its truth as JSON.

    stand screen --ra DEG --dec DEG --roll DEG --out DIR [--epoch ISO] [--aberration on|off]
                 [--screen WxH] [--scenario S --tracker NAME]

Writes ``DIR/screen.png`` (what the panel shows, 8-bit drive codes), ``DIR/detector_raw.png`` (what
an ideal tracker records through the collimator, 16-bit counts: the file to measure or to solve
with ``stand solve``), ``DIR/detector.png`` (the same image stretched to 8 bits for looking at) and
``DIR/truth.json`` (q_SN, optics, every star drawn with its Hipparcos number, magnitude and detector
pixel position).

Pointing: the boresight (+z of the tracker frame) points to (ra, dec); roll 0 puts celestial north
up in the image (-y) and east to the left; positive roll turns the sky counter-clockwise on the
image (see ``star_screen.attitude``). Without a scenario the default tracker is used: 20 x 15 deg
on 1024 x 768 pixels, limiting magnitude Hp 8, behind a 1.1 m collimator and a 1920 x 1080 screen.
With ``--scenario S --tracker NAME`` the optics of that image-source tracker (``source = "image"``:
fov_deg, resolution_px, mag_limit, psf_sigma_px) and the scenario epoch are used instead (an explicit
``--epoch`` still wins); ``--tracker`` may be left out when the scenario has one image-source tracker.
``--aberration off`` draws catalog places (proper motion only, no parallax or aberration).
Exit codes: 0 written, 2 usage error (message names the option, the value and what is allowed).
"""

from __future__ import annotations

import argparse
import sys

DEFAULT_EPOCH = "2026-01-01T00:00:00Z"


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "screen",
        help="render one star-screen frame (screen.png, detector_raw.png, detector.png, truth.json)",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("--ra", type=float, required=True, help="boresight right ascension, deg")
    p.add_argument("--dec", type=float, required=True, help="boresight declination, deg in [-90, 90]")
    p.add_argument(
        "--roll",
        type=float,
        default=0.0,
        help="roll about the boresight, deg (0: north up, east left; + turns the sky CCW)",
    )
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    p.add_argument("--epoch", default=None,
                   help=f"UTC epoch, ISO 8601 (default: the scenario's, else {DEFAULT_EPOCH})")
    p.add_argument(
        "--aberration",
        choices=("on", "off"),
        default="on",
        help="apparent places (on, default) or catalog places with proper motion only (off)",
    )
    p.add_argument("--screen", default="1920x1080", help="screen resolution WxH (default 1920x1080)")
    p.add_argument("--scenario", default=None, help="scenario file or name: use its tracker optics and epoch")
    p.add_argument("--tracker", default=None,
                   help="image-source star tracker of the scenario (default: its only one)")
    p.set_defaults(func=run)
    return p


def _fail(msg: str) -> int:
    print(f"stand screen: {msg}", file=sys.stderr)
    return 2


def _scenario_tracker(scenario: str, tracker: str | None):
    """(optics, epoch, name) of an image-source tracker of a scenario, or an error message."""
    from stand.errors import ScenarioError
    from stand.scenario import load

    try:
        sc = load(scenario)
    except ScenarioError as exc:
        return f"--scenario {scenario!r}: {exc}"
    trackers = [d for d in sc.devices if d.kind == "star_tracker"]
    listed = ", ".join(f"{d.name} (source = {d.source!r})" for d in trackers) or "none"
    if tracker is None:
        image = [d for d in trackers if d.optics is not None]
        if len(image) != 1:
            return (f"--tracker is required: scenario {sc.source} has {len(image) or 'no'} image-source star "
                    f"trackers; its star trackers: {listed}.")
        return image[0].optics, sc.epoch, image[0].name
    spec = next((d for d in trackers if d.name == tracker), None)
    if spec is None:
        return f"--tracker {tracker!r} is not a star tracker of scenario {sc.source}; available: {listed}."
    if spec.optics is None:
        return (f"--tracker {tracker!r} has source = {spec.source!r} in scenario {sc.source} and so no optics; "
                f"choose a tracker with source = 'image' (fov_deg, resolution_px, ...); star trackers: {listed}.")
    return spec.optics, sc.epoch, spec.name


def run(args) -> int:
    if args.tracker is not None and args.scenario is None:
        return _fail(f"--tracker {args.tracker!r} needs --scenario: the tracker's optics are read from a scenario.")
    try:
        w_txt, h_txt = str(args.screen).lower().split("x")
        width, height = int(w_txt), int(h_txt)
    except ValueError:
        return _fail(
            f"--screen {args.screen!r} is not a resolution; write it as WIDTHxHEIGHT, e.g. 1920x1080."
        )
    from sim.time import Epoch
    from star_screen.attitude import q_SN_from_radec_roll
    from star_screen.geometry import default_bench
    from star_screen.outputs import write_frame
    from star_screen.render import Renderer

    optics, epoch, which = None, None, "the default tracker"
    if args.scenario is not None:
        found = _scenario_tracker(args.scenario, args.tracker)
        if isinstance(found, str):
            return _fail(found)
        optics, epoch, name = found
        which = f"tracker {name}"
    try:
        if args.epoch is not None or epoch is None:
            epoch = Epoch.from_iso(args.epoch if args.epoch is not None else DEFAULT_EPOCH)
        q_SN = q_SN_from_radec_roll(args.ra, args.dec, args.roll)
        bench = default_bench(width, height, **({"tracker": optics} if optics is not None else {}))
    except ValueError as exc:
        return _fail(str(exc))
    problems = bench.check_fits()
    if problems:
        return _fail(
            f"--screen {args.screen}: the field of {which} does not fit: " + "; ".join(problems)
        )
    renderer = Renderer(bench, aberration=(args.aberration == "on"))
    frame = renderer.render(q_SN, epoch, time_tag_ns=0)
    try:
        truth = write_frame(args.out, frame, renderer)
    except OSError as exc:
        return _fail(f"--out {args.out!r}: {exc}")
    except RuntimeError as exc:  # an optional dependency (OpenCV for PNG) is not installed
        return _fail(str(exc))
    print(
        f"wrote {args.out}/screen.png, detector_raw.png, detector.png, truth.json: {truth['n_stars']} stars, "
        f"q_SN = {[round(v, 9) for v in truth['q_SN']]}"
    )
    return 0

