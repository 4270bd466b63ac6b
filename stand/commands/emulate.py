"""``stand emulate DEVICE --port URL``: run one device emulator alone, so a flight computer or a
terminal can be wired to it.

    stand emulate magnetorquer --port INTERFACE:CHANNEL [--field-nT X,Y,Z] [--duration S] [--seed N]
    stand emulate star-tracker --port URL [--address N] [--duration S] [--baud B]
                  [--ra DEG --dec DEG --roll DEG] [--rate-deg-s X,Y,Z] [--seed N]
                  [--noise-cross-arcsec A] [--noise-roll-arcsec A] [--boot-time-s S]
                  [--interval-s S] [--delay-s S]
    stand emulate star-tracker --source screen --port URL --screen-bind HOST:PORT
                  [--pre-distortion on|off] [--collimator-k1 K] [--collimator-shift-px DX,DY]
                  [--panel-latency-s S] [--defocus-sigma-px S] [--read-noise-e E] [--background-e E]
    stand emulate cage --port tcp://127.0.0.1:PORT | SERIAL [--duration S] [--baud B] [--seed N]

The star tracker is the truth-plus-noise emulator (``drivers.star_tracker.emulator``) with a
built-in measurement source: the boresight (+z of the tracker frame) at right ascension ``--ra``
and declination ``--dec`` (GCRS), rolled by ``--roll`` about it (roll 0: celestial north along
tracker -y, east along -x: north up and east left on the image), spinning at ``--rate-deg-s``
(tracker axes; default at rest). No Sun, Moon or Earth in the field. With ``--source screen`` the
tracker instead looks at the stand's star screen: it is the display node for the state a
scenario's ``screen = "state"`` tracker sends, and sees the rendered screen through a collimator
model (``stand.commands.screen_tracker``). Sim time is wall time since
start. It stops on Ctrl-C (or SIGTERM) or after ``--duration`` seconds and prints its counters as one JSON line.
The cage is the Helmholtz cage controller (``drivers.cage.emulator``, register map
``docs/cage_register_map.md``) on Modbus TCP (``tcp://HOST:PORT``) or Modbus RTU (a serial port),
running its coils in wall time with the nominal bench configuration.
Exit codes: 0 stopped normally, 1 a device error (port lost), 2 usage error (a port another stand or emulator
holds is refused as in use: serial ports and serial-line CAN adapters are opened exclusively).
What a flight computer sends that the device cannot decode is counted and dropped, never an error
(``rejected_*`` in the counters printed at the end).
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import threading

import numpy as np

from star_screen.attitude import q_SN_from_radec_roll

DEVICES = ("star-tracker", "magnetorquer", "cage")


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "emulate",
        help="run one device emulator on a port (star-tracker on serial, magnetorquer on CAN, cage on Modbus)",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("device", help="device to emulate: " + ", ".join(DEVICES))
    p.add_argument("--scenario", default=None,
                   help="feed the device from this scenario's truth (closed loop: the stand runs the scenario paced "
                        "with this device served on --port and the flight computer outside); without it the "
                        "emulator runs open loop")
    p.add_argument("--name", default=None, help="with --scenario: which device of that kind (default: the first)")
    p.add_argument("--speed", default=None, help="with --scenario: realtime (default) or a factor")
    p.add_argument("--out", default=None, help="with --scenario: the run's output directory")
    p.add_argument("--port", required=True, help="star tracker: a serial URL or path (/dev/ttyUSB0, a pty or socat "
                   "link, socket://...); magnetorquer: INTERFACE:CHANNEL of python-can (socketcan:can0, virtual:adcs); "
                   "cage: tcp://127.0.0.1:PORT (Modbus TCP) or a serial port (Modbus RTU)")
    p.add_argument("--field-nT", default="20000,0,-40000",
                   help="magnetorquer: the field its magnetometer sees, sensor axes, nT, as X,Y,Z")
    p.add_argument("--address", type=lambda s: int(s, 0), default=None, help="device address (default 0x21)")
    p.add_argument("--duration", type=float, default=None, help="stop after S seconds (default: until Ctrl-C)")
    p.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    p.add_argument("--ra", type=float, default=0.0, help="boresight right ascension, deg (default 0)")
    p.add_argument("--dec", type=float, default=0.0, help="boresight declination, deg in [-90, 90] (default 0)")
    p.add_argument("--roll", type=float, default=0.0, help="roll about the boresight, deg (default 0)")
    p.add_argument("--rate-deg-s", default="0,0,0", help="constant spin in tracker axes, deg/s, as X,Y,Z")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.add_argument("--noise-cross-arcsec", type=float, default=None, help="1-sigma noise across the boresight")
    p.add_argument("--noise-roll-arcsec", type=float, default=None, help="1-sigma noise about the boresight")
    p.add_argument("--boot-time-s", type=float, default=None, help="boot time, s (default 1)")
    p.add_argument("--interval-s", type=float, default=None, help="time between exposures, s (default 0.2)")
    p.add_argument("--delay-s", type=float, default=None, help="output delay after mid-exposure, s (default 0.1)")
    scr = p.add_argument_group("star tracker looking at the star screen (--source screen)")
    scr.add_argument("--source", choices=("spin", "screen"), default="spin",
                     help="star tracker: spin (built-in attitude, truth plus noise; default) or screen (display "
                          "node for the stand's screen state, collimator, camera, image solver)")
    scr.add_argument("--screen-bind", default="127.0.0.1:5600",
                     help="HOST:PORT the display node listens on for the stand's state (default 127.0.0.1:5600)")
    scr.add_argument("--pre-distortion", choices=("on", "off"), default="on",
                     help="render for the ChArUco-calibrated bench (on, default) or the nominal one (off)")
    scr.add_argument("--collimator-k1", type=float, default=0.0,
                     help="radial distortion k1 of the physical collimator (OpenCV model; default 0)")
    scr.add_argument("--collimator-shift-px", default="0,0",
                     help="physical collimator axis off the nominal one, screen px, as DX,DY (default 0,0)")
    scr.add_argument("--panel-latency-s", type=float, default=0.016,
                     help="from a rendered frame to its light on the panel, s (default 0.016: one 60 Hz frame)")
    scr.add_argument("--defocus-sigma-px", type=float, default=0.8,
                     help="tracker defocus blur, detector px (default 0.8)")
    scr.add_argument("--read-noise-e", type=float, default=10.0, help="camera read noise, e- rms (default 10)")
    scr.add_argument("--background-e", type=float, default=20.0, help="camera background, e- per pixel (default 20)")
    p.set_defaults(func=run)
    return p


def _fail(msg: str) -> int:
    print(f"stand emulate: error: {msg}", file=sys.stderr)
    return 2


class SpinSource:
    """Built-in measurement source: ``q_TN(t) = q0 (x) exp(omega t / 2)``, no bright body in view."""

    def __init__(self, q0: np.ndarray, omega_rad_s: np.ndarray) -> None:
        self.q0 = np.asarray(q0, dtype=float)
        self.omega = np.asarray(omega_rad_s, dtype=float)
        self.rate = float(np.linalg.norm(self.omega))

    def __call__(self, t_s: float):
        from drivers.star_tracker.emulator import TrackerTruth
        from sim.rotations import hamilton

        if self.rate > 0:
            angle = self.rate * t_s
            axis = self.omega / self.rate
            dq = np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * axis])
            q = hamilton(self.q0, dq)
        else:
            q = self.q0
        return TrackerTruth(q_TN=tuple(float(x) for x in q), omega_TN_T=tuple(float(x) for x in self.omega))


#: After a SIGTERM the emulator has this long to stop cleanly; then SIGALRM's default action ends the process
#: (a write to an output nobody drains, or a server thread that does not stop, cannot keep it alive).
SIGTERM_GRACE_S = 10


def _stop_on_sigterm():
    """SIGTERM stops like Ctrl-C, and for sure within ``SIGTERM_GRACE_S``; returns the previous handler (None off
    the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        return None

    def _term(signum, frame):
        signal.signal(signal.SIGALRM, signal.SIG_DFL)
        signal.alarm(SIGTERM_GRACE_S)
        raise KeyboardInterrupt

    return signal.signal(signal.SIGTERM, _term)


def serve_until_stopped(emu, duration_s: float | None, start=None) -> int:
    """Run an emulator's own loop until ``duration_s``, Ctrl-C or SIGTERM; a device error (the port lost) is
    printed and gives exit status 1. ``start`` runs first, inside the same handling (e.g. setting time zero)."""
    from drivers.errors import DriverError

    old = _stop_on_sigterm()
    try:
        if start is not None:
            start()
        emu.run(duration_s)
    except KeyboardInterrupt:
        pass
    except DriverError as exc:
        print(f"stand emulate: {exc}", file=sys.stderr)
        return 1
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)
    return 0


def run_magnetorquer(args) -> int:
    """The CAN magnetorquer board (with its magnetometer) on a python-can bus, in wall time."""
    import time

    from drivers.can_bus import ServedBus, open_device_bus
    from drivers.errors import DriverError
    from drivers.magnetorquer.codec import MagnetorquerCodec
    from drivers.magnetorquer.emulator import EmulatorConfig, MagnetorquerEmulator

    interface, _, channel = args.port.partition(":")
    if not interface or not channel:
        return _fail(f"--port {args.port!r} is not allowed for the magnetorquer; give INTERFACE:CHANNEL, "
                     "e.g. socketcan:can0 or virtual:adcs.")
    try:
        field_T = tuple(float(x) * 1e-9 for x in args.field_nT.split(","))
        if len(field_T) != 3 or not all(math.isfinite(x) for x in field_T):
            raise ValueError
    except ValueError:
        return _fail(f"--field-nT {args.field_nT!r} is not allowed; give three numbers X,Y,Z in nT.")
    try:
        # A serial-line adapter is held exclusively (a second emulator on it is refused: exit 2); what the flight
        # computer sends that the board cannot decode is counted and dropped, never raised (ServedBus).
        bus = ServedBus(open_device_bus(interface, channel), own_ids=MagnetorquerCodec().board_tx_ids)
    except DriverError as exc:
        return _fail(str(exc))
    old = _stop_on_sigterm()
    emu = MagnetorquerEmulator(bus, lambda _t: field_T, EmulatorConfig(), rng=args.seed, owns_bus=True)
    status = 0
    with emu:
        print(f"stand emulate: magnetorquer board on CAN {interface}:{channel}"
              + (f" for {args.duration:g} s" if args.duration else " until Ctrl-C") + OPEN_LOOP, flush=True)
        t0 = time.monotonic()
        try:
            while args.duration is None or time.monotonic() - t0 < args.duration:
                emu.service(time.monotonic() - t0)
                time.sleep(0.001)
        except KeyboardInterrupt:
            pass
        except DriverError as exc:  # the adapter lost
            print(f"stand emulate: {exc}", file=sys.stderr)
            status = 1
        finally:
            if old is not None:
                signal.signal(signal.SIGTERM, old)
        if bus.conflict:
            print(f"stand emulate: {bus.conflict}", file=sys.stderr)
        print(json.dumps({"device": args.device, "port": args.port, "counters": {**emu.counters, **bus.counters},
                          "rejected_frames": emu.rejected_frames + bus.counters["rejected_undecodable"]}), flush=True)
    return status


def run_cage(args) -> int:
    """The Helmholtz cage controller on Modbus TCP or RTU, its coils running in wall time."""
    from drivers.cage.emulator import MAX_REQUEST_RATE_HZ, CageEmulator
    from drivers.cage.host import parse_url
    from drivers.errors import DriverError

    try:
        kind, host, port = parse_url(args.port)
    except ValueError as exc:
        return _fail(str(exc))
    emu = CageEmulator(rng=args.seed, max_request_rate_hz=MAX_REQUEST_RATE_HZ)  # serves outside clients: limited
    old = _stop_on_sigterm()  # from before the banner: a SIGTERM any time after it stops cleanly
    status = 0
    try:
        try:
            if kind == "tcp":
                emu.serve_tcp(host, port)
            else:
                emu.serve_rtu(host, baudrate=args.baud)
        except DriverError as exc:
            emu.close()
            return _fail(str(exc))
        with emu:
            print(f"stand emulate: cage on {emu.where}" + (f" for {args.duration:g} s" if args.duration else
                                                          " until Ctrl-C") + OPEN_LOOP, flush=True)
            status = serve_until_stopped(emu, args.duration)
    except KeyboardInterrupt:
        emu.close()
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)
    print(json.dumps({"device": args.device, "port": args.port, "t_s": round(emu.t_s, 3),
                      "counters": emu.counters}), flush=True)
    if threading.current_thread() is threading.main_thread():
        signal.alarm(0)  # stopped cleanly: a caller in the same process (a test) lives on
    return status


OPEN_LOOP = "; open loop (no --scenario: a fixed source, not a simulated spacecraft)"
#: Device names of this command -> device kinds of scenarios, and how --port becomes the link's port fields.
SERVED_KINDS = {"star-tracker": "star_tracker", "magnetorquer": "magnetorquer"}


def run_served(args) -> int:
    """The closed-loop path: the scenario runs paced with this device served on --port (link = "served"), the
    rest of the scenario as it is; the same path as ``stand run`` of a scenario with a served device."""
    from stand import scenario as scenario_mod
    from stand.cli import main as stand_main
    from stand.errors import ScenarioError

    kind = SERVED_KINDS.get(args.device)
    if kind is None:
        return _fail(f"--scenario is not available for {args.device!r} yet; closed loop: "
                     + ", ".join(SERVED_KINDS) + ".")
    try:
        sc = scenario_mod.load(args.scenario)
    except ScenarioError as exc:
        return _fail(str(exc))
    names = [d.name for d in sc.devices if d.kind == kind and (args.name is None or d.name == args.name)]
    if not names:
        return _fail(f"--scenario {args.scenario!r} has no {kind} device" + (f" named {args.name!r}" if args.name
                                                                              else "") + ".")
    name = names[0]
    sets = [f"devices.{name}.link=served"]
    if kind == "magnetorquer":
        interface, _, channel = args.port.partition(":")
        if not interface or not channel:
            return _fail(f"--port {args.port!r} is not allowed for the magnetorquer; give INTERFACE:CHANNEL, "
                         "e.g. socketcan:can0 or serial:/dev/ttyUSB0.")
        sets += [f"devices.{name}.interface={interface}", f"devices.{name}.channel={channel}"]
    else:
        sets += [f"devices.{name}.port={args.port}", f"devices.{name}.baudrate={args.baud}"]
    print(f"stand emulate: {args.device} {name!r} of scenario {sc.name}, served on {args.port} and fed by the "
          "scenario's truth (closed loop with the flight computer on the other end)", flush=True)
    argv = ["run", args.scenario, "--speed", args.speed or "realtime"]
    for item in sets:
        argv += ["--set", item]
    if args.duration is not None:
        argv += ["--duration", str(args.duration)]
    if args.out:
        argv += ["--out", args.out]
    return stand_main(argv)


def run(args) -> int:
    if args.device not in DEVICES:
        return _fail(f"device {args.device!r} is not known; available: {', '.join(DEVICES)}.")
    if args.source != "spin" and args.device != "star-tracker":
        return _fail(f"--source {args.source} is for the star tracker only.")
    if args.scenario is not None:
        if args.source == "screen":
            return _fail("--source screen does not take --scenario: the tracker looks at the screen of a scenario "
                         "that `stand run` drives (screen = 'state' in its table), on --screen-bind.")
        return run_served(args)

    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        return _fail(f"--duration {args.duration!r} is not allowed; give a positive number of seconds.")
    if args.device == "magnetorquer":
        return run_magnetorquer(args)
    if args.device == "cage":
        return run_cage(args)
    if not -90.0 <= args.dec <= 90.0:
        return _fail(f"--dec {args.dec!r} is not allowed; give a declination from -90 to 90 deg.")
    try:
        rate = np.array([float(x) for x in args.rate_deg_s.split(",")])
        if rate.shape != (3,) or not np.all(np.isfinite(rate)):
            raise ValueError
    except ValueError:
        return _fail(f"--rate-deg-s {args.rate_deg_s!r} is not allowed; give three numbers X,Y,Z in deg/s.")
    if args.address is not None and not 0 <= args.address <= 255:
        return _fail(f"--address {args.address!r} is not allowed; give a number from 0 to 255.")

    if args.source == "screen":
        from stand.commands.screen_tracker import run_screen

        return run_screen(args, _fail)

    from drivers.errors import DriverError
    from drivers.star_tracker.emulator import EmulatorConfig, StarTrackerEmulator

    overrides = {
        "noise_cross_arcsec": args.noise_cross_arcsec,
        "noise_roll_arcsec": args.noise_roll_arcsec,
        "boot_time_s": args.boot_time_s,
        "output_interval_s": args.interval_s,
        "output_delay_s": args.delay_s,
        "address": args.address,
    }
    try:
        config = EmulatorConfig(**{k: v for k, v in overrides.items() if v is not None})
        source = SpinSource(q_SN_from_radec_roll(args.ra, args.dec, args.roll), np.radians(rate))
        emu = StarTrackerEmulator(args.port, source, config, rng=args.seed, baudrate=args.baud)
    except (ValueError, DriverError) as exc:
        return _fail(str(exc))

    with emu:
        print(f"stand emulate: star tracker at address 0x{emu.address:02X} on {args.port}"
              + (f" for {args.duration:g} s" if args.duration else " until Ctrl-C") + OPEN_LOOP, flush=True)
        status = serve_until_stopped(emu, args.duration)
        print(json.dumps({"device": args.device, "port": args.port, "mode": emu.mode, "counters": emu.counters}),
              flush=True)
    return status
