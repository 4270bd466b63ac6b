"""The GNSS receiver as a device kind of the stand: its scenario table, how it is built on each link, its
telemetry, its metric and how ``stand emulate gnss`` serves it.

The stand finds it through the entry point ``adcs_stand.devices`` (``gnss = "stand_gnss.kind:KIND"`` in this
package's ``pyproject.toml``); nothing in the stand names it. A scenario uses it as::

    [[devices]]
    name = "gps"
    kind = "gnss"
    link = "emulated"          # or "hardware" / "served" with port = "/dev/ttyUSB1"
    output_rate_hz = 1.0
    position_noise_m = 5.0     # one sigma per axis
    velocity_noise_m_s = 0.05

Telemetry (per row, the newest fix the host decoded): ``NAME.r_N`` (m), ``NAME.v_N`` (m/s), ``NAME.gps_week``,
``NAME.tow_s`` (s), ``NAME.t_fix_s`` (the sim time of the fix, from its GPS time, s) and ``NAME.valid``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivers.framing import FrameObserver
from stand.checks import rate
from stand.devices import (
    SERIAL_LINES,
    BuildContext,
    Device,
    DeviceCost,
    DeviceKind,
    DeviceSpec,
    SerialDevice,
    check_serial_url,
    settle_serial,
)
from stand.devices.serving import ServeOption, Serving, numbers, serial_port_fields, serve_serial
from stand_gnss.codec import GnssFix

#: Fix periods a receiver may miss before the stand's watch reports it silent.
SILENT_FIXES = 5
NAN10 = (math.nan,) * 10
METRIC = "gnss_position_error_m"


@dataclass(frozen=True)
class GnssSpec(DeviceSpec):
    port: str = "pipe"
    baudrate: int = 115200
    output_rate_hz: float = 1.0
    position_noise_m: float = 0.0
    velocity_noise_m_s: float = 0.0
    satellites: int = 9


class GnssKind(DeviceKind):
    name = "gnss"
    senses = ("position", "velocity", "time")
    column_meanings = {"r_N": "the newest fix's position, inertial axes", "v_N": "its velocity, inertial axes",
                       "gps_week": "its GPS week", "tow_s": "its GPS time of week",
                       "t_fix_s": "its GPS time as stand time", "valid": "1 when the receiver says it is valid"}
    metrics = {METRIC: "largest distance between a fix and the truth's position at the fix's time, m"}

    def parse(self, t, base: DeviceSpec, step_s: float) -> GnssSpec:
        if base.link == "emulated":
            port = t.choice("port", SERIAL_LINES, "pipe")
        else:
            port = check_serial_url(t, "port", t.text("port"))
        out_hz = rate(t, "output_rate_hz", step_s, min(1.0, 1.0 / step_s))
        if not 0.1 <= out_hz <= 10.0:
            raise t.error("output_rate_hz", out_hz, "0.1 to 10 Hz (SET_OUTPUT_PERIOD carries 0.1 s to 10 s)")
        spec = GnssSpec(
            **base.__dict__, port=port, output_rate_hz=out_hz,
            baudrate=int(t.number("baudrate", 115200, lo=1200, hi=4_000_000, integer=True)),
            position_noise_m=t.number("position_noise_m", 0.0, lo=0.0, hi=1e4),
            velocity_noise_m_s=t.number("velocity_noise_m_s", 0.0, lo=0.0, hi=100.0),
            satellites=int(t.number("satellites", 9, lo=0, hi=255, integer=True)),
        )
        t.check_unknown()
        return spec

    def describe(self, spec: GnssSpec) -> str:
        noise = f"{spec.position_noise_m:g} m, {spec.velocity_noise_m_s:g} m/s noise (1 sigma per axis)"
        return {"emulated": f"GNSS receiver emulated on an in-process serial {spec.port} at {spec.output_rate_hz:g} "
                            f"Hz, {noise}",
                "hardware": f"GNSS receiver on serial {spec.port} at {spec.baudrate} Bd (the stand reads its fixes)",
                "served": f"GNSS receiver served on serial {spec.port} for a flight computer outside at "
                          f"{spec.output_rate_hz:g} Hz, {noise}"}[spec.link]

    def cost(self, spec: GnssSpec) -> DeviceCost:
        return DeviceCost(rate_hz=spec.output_rate_hz, row_floats=10)

    def build(self, spec: GnssSpec, ctx: BuildContext) -> Device:
        return {"emulated": EmulatedGnss, "hardware": HardwareGnss, "served": ServedGnss}[spec.link](spec, ctx)

    def metric(self, metric: str, at_s, tel: dict, names: list[str]) -> float:
        """The largest fix error over every device ``names``, on the rows recorded at a fix's own time."""
        worst = math.nan
        for name in names:
            at_fix = np.isclose(tel[f"{name}.t_fix_s"], tel["t_s"], rtol=0.0, atol=1e-6)
            if np.any(at_fix):
                err = np.linalg.norm(tel[f"{name}.r_N"][at_fix] - tel["r_BN_N"][at_fix], axis=1)
                worst = float(np.nanmax([worst, err.max()]))
        return worst


def _source(spec: GnssSpec, ctx: BuildContext):
    from stand_gnss.behaviour import fix_source

    return fix_source(ctx.truth, ctx.epoch, ctx.rng, spec.position_noise_m, spec.velocity_noise_m_s, spec.satellites)


def _emulator(port, spec: GnssSpec, ctx: BuildContext, **kw):
    from stand_gnss.emulator import GnssEmulator

    return GnssEmulator(port, _source(spec, ctx), output_period_s=1.0 / spec.output_rate_hz,
                        name=f"{spec.name} emulator", **kw)


class _GnssDevice(SerialDevice):
    def __init__(self, spec: GnssSpec, ctx: BuildContext):
        from stand_gnss.behaviour import gps_seconds

        self.name, self.spec = spec.name, spec
        self.silent_after_s = SILENT_FIXES / spec.output_rate_hz
        self._gps0_s = gps_seconds(ctx.epoch)  # GPS seconds at sim time 0, to give each fix its sim time
        self.emulator = None
        self.host = None
        # What the telemetry records: the link as the stand sees it beside the flight code's driver (every fix the
        # host's framing layer decodes, or a served emulator sends), never the driver's own state.
        self.observer = FrameObserver()

    def columns(self):
        n = self.name
        return [(f"{n}.r_N", 3, "m"), (f"{n}.v_N", 3, "m/s"), (f"{n}.gps_week", 1, "week"), (f"{n}.tow_s", 1, "s"),
                (f"{n}.t_fix_s", 1, "s"), (f"{n}.valid", 1, "1")]

    def _latest(self):
        return self.observer.latest(GnssFix)

    def row(self):
        f = self._latest()
        if f is None:
            return NAN10
        from stand_gnss.emulator import SECONDS_PER_WEEK

        t_fix_s = f.gps_week * SECONDS_PER_WEEK + f.tow_s - self._gps0_s
        return (*f.r_N_m, *f.v_N_m_s, float(f.gps_week), f.tow_s, t_fix_s, float(f.valid))

    def activity(self):
        return self.observer.count(GnssFix)

    def summary(self):
        return self.driver_counters()


class EmulatedGnss(_GnssDevice):
    """Emulator and host on an in-process serial line; every fix reaches the host within its tick."""

    def __init__(self, spec: GnssSpec, ctx: BuildContext):
        from stand_gnss.host import GnssHost

        super().__init__(spec, ctx)
        self.open_emulated(spec.port, lambda end: _emulator(end, spec, ctx), lambda end: GnssHost(end, name=spec.name))
        self.host.add_observer(self.observer)

    def publish(self, t_s: float) -> None:
        self.emulator.service(t_s)
        settle_serial(self.emulator, self.host, self.name, "FIX datagram")


class HardwareGnss(_GnssDevice):
    """The host driver on a real port: the stand reads (and records) the receiver's fixes."""

    def __init__(self, spec: GnssSpec, ctx: BuildContext):
        from stand_gnss.host import GnssHost

        super().__init__(spec, ctx)
        self.host = GnssHost(spec.port, baudrate=spec.baudrate, name=spec.name)
        self.host.add_observer(self.observer)

    def publish(self, t_s: float) -> None:
        self.host.poll()


class ServedGnss(_GnssDevice):
    """The emulator on a real port, fed by the truth, for a flight computer outside; no host in the stand."""

    def __init__(self, spec: GnssSpec, ctx: BuildContext):
        super().__init__(spec, ctx)
        self.serve(_emulator(spec.port, spec, ctx, baudrate=spec.baudrate))
        self.emulator.add_observer(self.observer)  # what it sent, decoded as the flight computer decodes it

    def publish(self, t_s: float) -> None:
        self.emulator.service(t_s)
        self.rejections.check(t_s)



KIND = GnssKind()


# -- how `stand emulate gnss` serves it ---------------------------------------------------------------------------

def _serve(args, fail) -> int:
    """The receiver in wall time, open loop: a fixed position and velocity, GPS time running from the start."""
    from stand_gnss.emulator import SECONDS_PER_WEEK, GnssEmulator, Measured

    try:
        r = numbers(args.position_m, 3, "--position-m", "m, frame N (X,Y,Z)")
        v = numbers(args.velocity_m_s, 3, "--velocity-m-s", "m/s, frame N (X,Y,Z)")
        if not 0 <= args.tow_s < SECONDS_PER_WEEK:
            raise ValueError(f"--tow-s {args.tow_s:g} is not allowed; give 0 to {SECONDS_PER_WEEK} s (not included).")
        if args.gps_week < 0:
            raise ValueError(f"--gps-week {args.gps_week} is not allowed; give 0 or more.")
    except ValueError as exc:
        return fail(str(exc))
    gps0 = args.gps_week * SECONDS_PER_WEEK + args.tow_s
    return serve_serial(args, fail, "GNSS receiver",
                        lambda: GnssEmulator(args.port, lambda t: Measured(r, v, gps0 + t),
                                             output_period_s=args.period_s, baudrate=args.baud))


KIND.serving = Serving(
    summary="A GNSS receiver on a serial line (FIX datagrams of stand_gnss/icd.toml).",
    port_help="a serial URL or path (/dev/ttyUSB1, a pty or socat link, socket://...)",
    serve=_serve,
    port_fields=serial_port_fields,
    options=(ServeOption("--baud", "baud rate (default 115200)", 115200, int),
             ServeOption("--position-m", "open loop: the position it reports, frame N, m, as X,Y,Z "
                                         "(default 6878137,0,0)", "6878137,0,0"),
             ServeOption("--velocity-m-s", "open loop: the velocity it reports, frame N, m/s, as X,Y,Z "
                                           "(default 0,7612.6,0)", "0,7612.6,0"),
             ServeOption("--gps-week", "GPS week at the start (default 2410)", 2410, int),
             ServeOption("--tow-s", "GPS time of week at the start, s (default 0)", 0.0, float),
             ServeOption("--period-s", "time between FIX datagrams, s (default 1)", 1.0, float)),
)
