"""A reference external flight program: B-dot detumbling on its own, closing the loop through the stand's
served magnetorquer board, in a process of its own (as a flight computer would, over a real CAN adapter).

    python examples/external_bdot.py --interface serial --channel /dev/pts/7 --duration 3600

It uses only the project's host driver (``drivers.magnetorquer.host.MagnetorquerBoard``) and the reference
B-dot law (``stand.adcs.BDot``): every magnetometer sample it reads and every dipole it commands crosses the CAN
codec. Time is the board's: sample counter times the sample period, so the law is the same whatever the stand's
pacing. It stops after ``--duration`` seconds of board time, after ``--idle-s`` wall seconds without a sample,
or on Ctrl-C / SIGTERM, and prints its counters as one JSON line.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--interface", required=True, help="python-can interface (socketcan, serial, udp_multicast...)")
    p.add_argument("--channel", required=True, help="python-can channel (can0, a pty, a multicast group...)")
    p.add_argument("--sample-period-s", type=float, default=0.1, help="the board's magnetometer period (0.1 s)")
    p.add_argument("--gain", type=float, default=5.0e4, help="B-dot gain, A m^2 s / T")
    p.add_argument("--max-dipole", type=float, default=0.2, help="per-axis dipole limit, A m^2")
    p.add_argument("--duration", type=float, default=None, help="stop after this much board time, s")
    p.add_argument("--idle-s", type=float, default=10.0, help="stop after this many wall seconds without a sample")
    args = p.parse_args(argv)

    from drivers.can_bus import open_bus
    from drivers.errors import DeviceTimeoutError, DriverError
    from drivers.magnetorquer.host import MagnetorquerBoard
    from stand.adcs import BDot

    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    try:
        # python-can's serial-line interfaces block each read for the port's timeout (0.1 s by default).
        extra = {"timeout": 1e-3} if args.interface in ("serial", "slcan") else {}
        bus = open_bus(args.interface, args.channel, **extra)
    except DriverError as exc:
        print(f"external_bdot: {exc}", file=sys.stderr)
        return 2
    board = MagnetorquerBoard(bus, name="mtq", owns_bus=True)
    bdot = BDot(board, args.sample_period_s, args.gain, args.max_dipole)
    samples, status, seq = 0, "completed", None
    with board:
        print(f"external_bdot: B-dot on CAN {args.interface}:{args.channel}", flush=True)
        last_wall = time.monotonic()
        try:
            while args.duration is None or samples * args.sample_period_s < args.duration:
                try:
                    sample = board.read_sample(timeout_s=0.5)
                except DeviceTimeoutError:
                    if time.monotonic() - last_wall > args.idle_s:
                        status = "idle"
                        break
                    continue
                last_wall = time.monotonic()
                # Board time from the sample counter (8 bits, wrapping): a sample missed still counts.
                samples += 1 if seq is None else (sample.seq - seq) % 256
                seq = sample.seq
                bdot.command_for(sample, samples * args.sample_period_s)
        except KeyboardInterrupt:
            status = "stopped"
        print(json.dumps({"status": status, "samples": samples, "used": bdot.samples_used,
                          "skipped": bdot.samples_skipped, "counters": board.counters}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
