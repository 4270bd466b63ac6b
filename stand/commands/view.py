"""``stand view``: the operator page replaying a run folder, or its panorama exported as PNG.

    stand view RUN_DIR [--bind HOST:PORT] [--token T]
    stand view RUN_DIR --export DIR [--times T1,T2,...] [--frame body|gcrs|lvlh|itrs]
                       [--projection equirectangular|hammer] [--mag M]

Serving prints the page's URL and runs until Ctrl-C (the page has a time slider, play/pause and speed). The
export writes ``panorama_<t>s.png`` for each time (default: start, middle, end). ``stand run --view`` serves the
same page live. Exit codes: 0 served or written, 2 a usage error or a run folder whose ``view.json`` or
``summary.json`` cannot be used (one sentence naming the value or the file).
"""

from __future__ import annotations

import argparse
import os
import sys
import threading


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("view", help="the operator page replaying a run (or its panorama as PNG)",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("run_dir", help="a run folder written by `stand run`")
    p.add_argument("--bind", default="", metavar="HOST:PORT",
                   help="address to serve on (default 127.0.0.1 and a free port); another host needs --token")
    p.add_argument("--token", default=os.environ.get("STAND_VIEW_TOKEN"),
                   help="token of the page (default: $STAND_VIEW_TOKEN)")
    p.add_argument("--export", metavar="DIR", help="write the panorama as PNG into DIR instead of serving")
    p.add_argument("--times", help="comma-separated times (s) to export (default: start, middle and end)")
    p.add_argument("--frame", default="body", help="panorama frame: body, gcrs, lvlh or itrs (default body)")
    p.add_argument("--projection", default="equirectangular", help="equirectangular or hammer")
    p.add_argument("--mag", type=float, default=6.0, help="faintest stars drawn, Hp magnitude (default 6, up to 9)")
    p.set_defaults(func=run)
    return p


def _fail(msg: str) -> int:
    print(f"stand: error: {msg}", file=sys.stderr)
    return 2


def _times(text: str | None):
    if text is None:
        return None
    try:
        times = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        times = ()
    if not times:
        raise ValueError(f"--times {text!r} is not allowed: comma-separated times in seconds, e.g. 0,600,1800.")
    return times


def run(args) -> int:
    from stand.view import export, server

    try:
        if args.export:
            written = export.export(args.run_dir, args.export, _times(args.times), frame=args.frame,
                                    kind=args.projection, mag_limit=args.mag)
            for path in written:
                print(path)
            return 0
        host, port = server.parse_bind(args.bind)
        src = server.ReplaySource(args.run_dir)
        view = server.ViewServer(src, host, port, args.token, token_flag="--token")
        url = view.start()
    except ValueError as exc:  # a bad option, or a view.json / summary.json the page cannot use (named)
        return _fail(str(exc))
    except OSError as exc:
        if exc.filename is None:  # our own FileNotFoundError: the sentence is in the message
            return _fail(str(exc))
        return _fail(f"{exc.filename} cannot be read: {exc.strerror or exc}.")
    print(f"stand: replay of {args.run_dir} at {url} (Ctrl-C to stop serving)", flush=True)
    stop = threading.Event()
    try:
        while not stop.wait(3600.0):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        view.close()
    return 0
