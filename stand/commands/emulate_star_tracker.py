"""``stand emulate star-tracker``: the serve hook the star tracker kind declares (``stand.devices.star_tracker``).

The star tracker is the truth-plus-noise emulator (``drivers.star_tracker.emulator``) with a built-in measurement
source: the boresight (+z of the tracker frame) at right ascension ``--ra`` and declination ``--dec`` (GCRS), rolled
by ``--roll`` about it (roll 0: celestial north along tracker -y, east along -x: north up and east left on the
image), spinning at ``--rate-deg-s`` (tracker axes; default at rest). No Sun, Moon or Earth in the field. With
``--source screen`` the tracker instead looks at the stand's star screen: it is the display node for the state a
scenario's ``screen = "state"`` tracker sends, and sees the rendered screen through a collimator model
(``stand.commands.screen_tracker``). It lives among the commands because the screen source is the display node.
"""

from __future__ import annotations

import math

import numpy as np

from stand.devices.serving import banner, report, serve_until_stopped
from star_screen.attitude import q_SN_from_radec_roll


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


def serve(args, fail) -> int:
    """The star tracker open loop on a serial line: the spin source, or the star screen (``--source screen``)."""
    if not -90.0 <= args.dec <= 90.0:
        return fail(f"--dec {args.dec!r} is not allowed; give a declination from -90 to 90 deg.")
    try:
        rate = np.array([float(x) for x in args.rate_deg_s.split(",")])
        if rate.shape != (3,) or not np.all(np.isfinite(rate)):
            raise ValueError
    except ValueError:
        return fail(f"--rate-deg-s {args.rate_deg_s!r} is not allowed; give three numbers X,Y,Z in deg/s.")
    if args.address is not None and not 0 <= args.address <= 255:
        return fail(f"--address {args.address!r} is not allowed; give a number from 0 to 255.")

    if args.source == "screen":
        from stand.commands.screen_tracker import run_screen

        return run_screen(args, fail)

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
        return fail(str(exc))

    with emu:
        banner(f"star tracker at address 0x{emu.address:02X}", args.port, args.duration)
        status = serve_until_stopped(emu, args.duration)
        report(args, mode=emu.mode, counters=emu.counters)
    return status
