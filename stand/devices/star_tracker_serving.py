"""How ``stand emulate star-tracker`` serves the star tracker kind: its options and the table keys of a served
tracker (the declaration ``stand.devices.star_tracker`` sets as ``KIND.serving``)."""

from __future__ import annotations

from stand.devices.serving import ServeOption as O
from stand.devices.serving import Serving, serial_port_fields


def _served_port_fields(port: str, args) -> dict[str, str]:

    if args.source == "screen":
        raise ValueError("--source screen does not take --scenario: the tracker looks at the screen of a scenario "
                         "that `stand run` drives (screen = 'state' in its table), on --screen-bind.")
    return serial_port_fields(port, args)


def serving():
    screen = "star tracker looking at the star screen (--source screen)"
    return Serving(
        summary="The star tracker on a serial line: a built-in attitude (truth plus noise) or the stand's star screen.",
        port_help="a serial URL or path (/dev/ttyUSB0, a pty or socat link, socket://...)",
        serve="stand.commands.emulate_star_tracker:serve",  # the screen source is the display node, a command
        port_fields=_served_port_fields,
        options=(
            O("--address", "device address (default 0x21)", None, lambda s: int(s, 0)),
            O("--baud", "baud rate (default 115200)", 115200, int),
            O("--seed", "noise seed (default 0)", 0, int),
            O("--ra", "boresight right ascension, deg (default 0)", 0.0, float),
            O("--dec", "boresight declination, deg in [-90, 90] (default 0)", 0.0, float),
            O("--roll", "roll about the boresight, deg (default 0)", 0.0, float),
            O("--rate-deg-s", "constant spin in tracker axes, deg/s, as X,Y,Z", "0,0,0"),
            O("--noise-cross-arcsec", "1-sigma noise across the boresight", None, float),
            O("--noise-roll-arcsec", "1-sigma noise about the boresight", None, float),
            O("--boot-time-s", "boot time, s (default 1)", None, float),
            O("--interval-s", "time between exposures, s (default 0.2)", None, float),
            O("--delay-s", "output delay after mid-exposure, s (default 0.1)", None, float),
            O("--source", "spin (built-in attitude, truth plus noise; default) or screen (display node for the "
                          "stand's screen state, collimator, camera, image solver)", "spin", str, ("spin", "screen"),
              screen),
            O("--screen-bind", "HOST:PORT the display node listens on for the stand's state (default "
                               "127.0.0.1:5600)", "127.0.0.1:5600", group=screen),
            O("--pre-distortion", "render for the ChArUco-calibrated bench (on, default) or the nominal one (off)",
              "on", str, ("on", "off"), screen),
            O("--collimator-k1", "radial distortion k1 of the physical collimator (OpenCV model; default 0)", 0.0,
              float, group=screen),
            O("--collimator-shift-px", "physical collimator axis off the nominal one, screen px, as DX,DY "
                                       "(default 0,0)", "0,0", group=screen),
            O("--panel-latency-s", "from a rendered frame to its light on the panel, s (default 0.016: one 60 Hz "
                                   "frame)", 0.016, float, group=screen),
            O("--defocus-sigma-px", "tracker defocus blur, detector px (default 0.8)", 0.8, float, group=screen),
            O("--read-noise-e", "camera read noise, e- rms (default 10)", 10.0, float, group=screen),
            O("--background-e", "camera background, e- per pixel (default 20)", 20.0, float, group=screen),
        ),
    )


