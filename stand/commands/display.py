"""``stand display-node``: a screen PC that receives attitude state over UDP and renders locally.

The library (the node, the one state sender, the shared key) is :mod:`stand.display`; this is its command.
The node refuses and counts what it cannot accept (see :mod:`stand.display.node`). The shared key
(HMAC-SHA256, at least 16 bytes) comes from ``--key-file PATH`` (a file only its owner can read) or the
environment variable ``STAND_DISPLAY_KEY``, never from the command line, where other users can read it in the
process list.

    stand display-node --bind 127.0.0.1:PORT [--window [--display N] [--windowed] | --out DIR]
                       [--screen WxH] [--max-frames N] [--timeout S] [--aberration on|off]
                       [--allow ADDR[/PREFIX] | --allow any ...] [--key-file PATH]
                       [--collimator-focal-m F] [--collimator-distortion K1,K2,P1,P2,K3] [--axis-px X,Y]

The collimator and axis options pre-distort the frames for the bench's calibration
(``star_screen.calibration.calibrate_screen``); without them the nominal bench is drawn.

Exit codes: 0 after a normal stop (max frames, idle timeout, window closed), 2 for a usage error.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import asdict

from stand.display import KEY_ENV, LOOPBACK, DirectoryOutput, DisplayNode, load_key, parse_hostport

__all__ = ["register", "run"]


def _fail(message: str) -> int:
    print(f"stand: error: {message}", file=sys.stderr)
    return 2


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "display-node",
        help="receive attitude state over UDP and render the star screen locally (window, PNG or memory)",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("--bind", required=True, help="HOST:PORT to listen on, e.g. 127.0.0.1:5600")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--window", action="store_true", help="show frames in a fullscreen window (display extra)")
    where.add_argument("--out", help="write every frame as PNG + truth.json into this directory (slow)")
    p.add_argument("--display", type=int, default=0, help="monitor index for --window (default 0)")
    p.add_argument("--windowed", action="store_true", help="with --window: a plain window, not fullscreen")
    p.add_argument("--no-corner-code", action="store_true", help="with --window: do not draw the frame counter")
    p.add_argument("--screen", default="1920x1080", help="screen resolution WxH (default 1920x1080)")
    p.add_argument("--aberration", choices=("on", "off"), default="on", help="apparent places (default) or not")
    cal = p.add_argument_group("pre-distortion: the bench's ChArUco calibration (star_screen.calibration)")
    cal.add_argument("--collimator-focal-m", type=float, default=None, help="calibrated collimator focal length, m")
    cal.add_argument("--collimator-distortion", default=None, metavar="K1,K2,P1,P2,K3",
                     help="calibrated collimator distortion (OpenCV's 5 terms)")
    cal.add_argument("--axis-px", default=None, metavar="X,Y", help="screen pixel on the collimator axis")
    p.add_argument("--max-frames", type=int, default=None, help="stop after N rendered frames")
    p.add_argument("--timeout", type=float, default=None,
                   help="stop after S seconds without a new state (default: run until stopped)")
    p.add_argument("--allow", action="append", default=None, metavar="ADDR[/PREFIX]",
                   help="accept state from this address or network (repeatable; 'any' for every sender; "
                        "default: loopback only)")
    p.add_argument("--key-file", default=None,
                   help=f"accept only state signed with the key in this file (owner-readable only); "
                        f"or set {KEY_ENV}")
    p.set_defaults(func=run)
    return p


def _numbers(text, flag: str, n: int) -> list[float]:
    try:
        values = [float(v) for v in str(text).split(",")]
    except ValueError:
        values = []
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{flag} {text!r} is not {n} numbers separated by commas.")
    return values


def _calibrated(bench, args):
    """The bench with the calibration the command line gives (collimator and axis), so frames are pre-distorted."""
    import dataclasses

    from star_screen.geometry import BrownConrady, Collimator

    focal = getattr(args, "collimator_focal_m", None)
    dist = getattr(args, "collimator_distortion", None)
    axis = getattr(args, "axis_px", None)
    if focal is not None and not (math.isfinite(focal) and 0.05 <= focal <= 20.0):
        raise ValueError(f"--collimator-focal-m {focal!r} is not allowed; give 0.05 to 20 m.")
    col = bench.collimator
    if focal is not None or dist is not None:
        k = BrownConrady(*_numbers(dist, "--collimator-distortion", 5)) if dist is not None else col.distortion
        col = Collimator(col.focal_length_m if focal is None else focal, k)
    sx0, sy0 = (bench.sx0, bench.sy0) if axis is None else _numbers(axis, "--axis-px", 2)
    return dataclasses.replace(bench, collimator=col, sx0=sx0, sy0=sy0)


def run(args) -> int:
    try:
        host, port = parse_hostport(args.bind)
        w_txt, _, h_txt = str(args.screen).lower().partition("x")
        try:
            width, height = int(w_txt), int(h_txt)
        except ValueError:
            raise ValueError(f"--screen {args.screen!r} is not a resolution; write it as WIDTHxHEIGHT, "
                             "e.g. 1920x1080.") from None
        if args.max_frames is not None and args.max_frames < 1:
            raise ValueError(f"--max-frames {args.max_frames}; give a whole number >= 1.")
        if args.timeout is not None and not args.timeout > 0:
            raise ValueError(f"--timeout {args.timeout}; give a positive number of seconds.")
        from star_screen.geometry import default_bench
        from star_screen.outputs import FrameQueue
        from star_screen.render import Renderer

        bench = _calibrated(default_bench(width, height), args)
        problems = bench.check_fits()
        if problems:
            raise ValueError(f"--screen {args.screen}: the default tracker field does not fit: " + "; ".join(problems))
        renderer = Renderer(bench, aberration=(args.aberration == "on"))
        if args.window:
            from star_screen.window import ScreenWindow

            output = ScreenWindow((width, height), display=args.display, fullscreen=not args.windowed,
                                  corner_code=not args.no_corner_code, clock=time.monotonic_ns)
        elif args.out:
            output = DirectoryOutput(args.out, renderer)
        else:
            output = FrameQueue(1)
        key = load_key(getattr(args, "key_file", None))
        allow = getattr(args, "allow", None) or LOOPBACK
        node = DisplayNode((host, port), renderer, output, copy=not args.window, allow=allow, key=key)
    except (ValueError, RuntimeError) as exc:
        return _fail(str(exc))
    print(f"display node listening on {node.address[0]}:{node.address[1]} (UDP)", file=sys.stderr)
    try:
        with node:
            stats = node.serve(max_frames=args.max_frames, timeout_s=args.timeout)
    except KeyboardInterrupt:
        stats = node.stats
        stats.stop_reason = "interrupted"
    finally:
        close = getattr(output, "close", None)
        if close is not None:
            close()
    counts = {k: v for k, v in asdict(stats).items() if k not in ("last_error", "errors")}
    errors = " ".join(f"{k}={v}" for k, v in sorted(stats.errors.items())) or "none"
    print("display node stopped: " + ", ".join(f"{k} {v}" for k, v in counts.items()) + f"; refused: {errors}")
    if stats.last_error:
        print(f"last refused datagram: {stats.last_error}", file=sys.stderr)
    return 0
