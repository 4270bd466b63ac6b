"""Three-axis rate gyro on a serial line (``drivers.gyro``, the ICD in ``fixtures/devices/gyro.toml``).

The stand hands the emulator the rate the gyro measures at each sample time: the true body rate, delayed by
``delay_s`` (a :class:`sim.sensors.DelayLine` of the truth), through the sensor model :class:`sim.sensors.Gyro`
(angle and rate random walk, bias instability, turn-on bias, scale factor, misalignment, the mount ``q_SB``).
The emulator adds what the wire does: quantisation to the datagram's LSB and saturation at ``range_deg_s``.
``ideal = true`` leaves out every error and the delay: the datagram carries the true rate in sensor axes.

Links: ``emulated`` (emulator and host on an in-process serial line, ``port = "pipe"`` (default) or a kernel pty
pair with ``port = "pty"``, every exchange settled within the tick, so a
run is bit-for-bit repeatable), ``hardware`` (the host on a real port), ``served`` (the emulator on a real
port, fed by the truth, for a flight computer outside).

Telemetry: ``NAME.omega_S`` (the newest sample on the link, rad/s, sensor axes) and ``NAME.valid``, observed beside
the flight code (:class:`drivers.framing.FrameObserver` on the host's framing layer, or on the served emulator's:
what it sent), never read from the flight code's driver.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivers.framing import FrameObserver
from drivers.gyro.codec import GyroRate
from sim.rotations import dcm
from sim.truth import rotate_to_body
from stand.checks import rate
from stand.devices import (
    SERIAL_LINES,
    BuildContext,
    Device,
    DeviceKind,
    DeviceSpec,
    SerialDevice,
    check_serial_url,
    fault_taps,
    settle_serial,
)
from stand.devices.serving import ServeOption, Serving, numbers, serial_port_fields, serve_serial

DEG = math.pi / 180.0
#: deg/sqrt(h) -> rad/sqrt(s); deg/h -> rad/s; deg/h/sqrt(h) -> rad/s/sqrt(s).
ARW_UNIT = DEG / 60.0
DEG_H = DEG / 3600.0
RRW_UNIT = DEG_H / 60.0
#: Sample periods a gyro may miss before it is reported silent.
SILENT_SAMPLES = 10
NAN4 = (math.nan,) * 4
#: Error-model keys (scenario units) that ``ideal = true`` refuses.
NOISE_KEYS = ("arw_deg_sqrt_h", "rrw_deg_h_sqrt_h", "bias_instability_deg_h", "bias_correlation_s", "bias_deg_h",
              "scale_factor_ppm", "misalignment_mrad", "delay_s")


@dataclass(frozen=True)
class GyroSpec(DeviceSpec):
    port: str = "pipe"
    baudrate: int = 460800
    output_rate_hz: float = 20.0
    ideal: bool = False
    arw_rad_sqrt_s: float = 0.0
    rrw_rad_s_sqrt_s: float = 0.0
    bias_instability_rad_s: float = 0.0
    bias_correlation_s: float = 100.0
    bias_rad_s: tuple = (0.0, 0.0, 0.0)
    scale_factor: tuple = (0.0, 0.0, 0.0)
    misalignment_rad: tuple = (0.0,) * 6  # off-diagonal terms, row order: xy, xz, yx, yz, zx, zy
    delay_s: float = 0.0
    range_rad_s: float = 400.0 * DEG
    latency_s: float = 5e-4
    startup_time_s: float = 0.0


def misalignment_matrix(off: tuple) -> np.ndarray:
    """The 3 x 3 small-angle misalignment (zero diagonal) from its six off-diagonal terms in row order."""
    m = np.zeros((3, 3))
    m[[0, 0, 1, 1, 2, 2], [1, 2, 0, 2, 0, 1]] = off
    return m


class GyroKind(DeviceKind):
    name = "gyro"
    senses = ("rate",)
    column_meanings = {"omega_S": "the newest rate sample the host decoded, sensor axes",
                       "valid": "1 when that sample is valid"}
    plot_files = {"gyro_{name}.png": "the rates in sensor axes, valid samples only"}
    view_plots = ({"title": "gyro rate", "unit": "rad/s", "column": "omega_S"},)  # the operator page's panel

    def parse(self, t, base: DeviceSpec, step_s: float) -> GyroSpec:
        ideal = t.flag("ideal", False)
        if ideal:
            for key in NOISE_KEYS:
                if t.has(key):
                    raise t.error(key, t.raw(key), "no error setting with ideal = true (the ideal gyro reports the "
                                  "true rate without noise, bias or delay); remove it or set ideal = false")
        if base.link == "emulated":
            port = t.choice("port", SERIAL_LINES, "pipe")
        else:
            port = check_serial_url(t, "port", t.text("port"))
        out_hz = rate(t, "output_rate_hz", step_s, 1.0 / step_s)
        if out_hz < 1.0:
            raise t.error("output_rate_hz", out_hz, "at least 1 Hz (SET_OUTPUT_PERIOD carries at most 1 s)")
        spec = GyroSpec(
            **base.__dict__, port=port, baudrate=int(t.number("baudrate", 460800, lo=1200, hi=4_000_000,
                                                              integer=True)),
            output_rate_hz=out_hz, ideal=ideal,
            arw_rad_sqrt_s=t.number("arw_deg_sqrt_h", 0.0, lo=0.0, hi=100.0) * ARW_UNIT,
            rrw_rad_s_sqrt_s=t.number("rrw_deg_h_sqrt_h", 0.0, lo=0.0, hi=1e4) * RRW_UNIT,
            bias_instability_rad_s=t.number("bias_instability_deg_h", 0.0, lo=0.0, hi=1e4) * DEG_H,
            bias_correlation_s=t.number("bias_correlation_s", 100.0, lo=0.0, lo_open=True, hi=1e7),
            bias_rad_s=tuple(t.vector("bias_deg_h", 3, [0.0, 0.0, 0.0], lo=-1e5, hi=1e5) * DEG_H),
            scale_factor=tuple(t.vector("scale_factor_ppm", 3, [0.0, 0.0, 0.0], lo=-1e5, hi=1e5) * 1e-6),
            misalignment_rad=tuple(t.vector("misalignment_mrad", 6, [0.0] * 6, lo=-50.0, hi=50.0) * 1e-3),
            delay_s=t.number("delay_s", 0.0, lo=0.0, hi=1.0),
            range_rad_s=t.number("range_deg_s", 400.0, lo=1.0, hi=512.0) * DEG,
            latency_s=t.number("latency_s", 5e-4, lo=0.0, hi=0.065),
            startup_time_s=t.number("startup_time_s", 0.0, lo=0.0, hi=600.0),
        )
        t.check_unknown()
        return spec

    def datasheet(self, spec: GyroSpec) -> dict:
        # Rates and range only: its noise and bias are the simulated unit's, not what a flight team knows.
        return {"output_rate_hz": spec.output_rate_hz, "range_rad_s": spec.range_rad_s, "latency_s": spec.latency_s,
                "startup_time_s": spec.startup_time_s}

    def describe(self, spec) -> str:
        model = "the true rate (ideal)" if spec.ideal else (
            f"ARW {spec.arw_rad_sqrt_s / ARW_UNIT:g} deg/sqrt(h), RRW {spec.rrw_rad_s_sqrt_s / RRW_UNIT:g} "
            f"deg/h/sqrt(h), bias instability {spec.bias_instability_rad_s / DEG_H:g} deg/h, delay "
            f"{spec.delay_s * 1e3:g} ms")
        return {"emulated": f"gyro emulated on an in-process serial {spec.port} at {spec.output_rate_hz:g} Hz, {model}",
                "hardware": f"gyro on serial {spec.port} at {spec.baudrate} Bd (hardware: the stand reads its rates)",
                "served": f"gyro served on serial {spec.port} for a flight computer outside at "
                          f"{spec.output_rate_hz:g} Hz, {model}"}[spec.link]

    def fault_taps(self, spec: GyroSpec) -> dict:
        return fault_taps(spec.link, measurement={"n": 3, "unit": "rad_s"})

    def build(self, spec: GyroSpec, ctx: BuildContext) -> Device:
        return {"emulated": EmulatedGyro, "hardware": HardwareGyro, "served": ServedGyro}[spec.link](spec, ctx)

    def plots(self, tel, name, out_dir, criteria) -> list[str]:
        # lazy: the figures load matplotlib, which only drawing a report needs
        from stand.devices.gyro_plots import plot_gyro

        return [plot_gyro(tel, out_dir, name)]


def rate_source(spec: GyroSpec, ctx: BuildContext):
    """``(push, source)``: ``push(t_s)`` records the true body rate each tick; ``source(t_k)`` is the rate the
    gyro measures at sample time ``t_k`` (sensor axes, rad/s)."""
    truth = ctx.truth
    q_SB = tuple(float(x) for x in spec.q_SB)
    if spec.ideal:
        def source(_t_s):
            return rotate_to_body(q_SB, truth.w)

        return None, source
    from sim.sensors import DelayLine, Gyro

    model = Gyro(sample_period_s=1.0 / spec.output_rate_hz, arw_rad_sqrt_s=spec.arw_rad_sqrt_s,
                 rrw_rad_s_sqrt_s=spec.rrw_rad_s_sqrt_s, bias_instability_rad_s=spec.bias_instability_rad_s,
                 bias_correlation_s=spec.bias_correlation_s, bias_rad_s=np.array(spec.bias_rad_s),
                 scale_factor=np.array(spec.scale_factor), misalignment=misalignment_matrix(spec.misalignment_rad),
                 delay_s=spec.delay_s, dcm_SB=dcm(spec.q_SB))
    line = DelayLine(spec.delay_s + 2.0 * ctx.step_s)
    rng = ctx.rng
    state = [model.initial_state(rng)]
    delay = spec.delay_s

    def push(t_s):
        line.push(t_s, truth.w)

    def source(t_k):
        y, _, state[0] = model.measure_one(line.at(t_k - delay), rng, state[0])
        return y

    return push, source


def _config(spec: GyroSpec):
    from drivers.gyro.emulator import GyroEmulatorConfig

    return GyroEmulatorConfig(output_period_s=1.0 / spec.output_rate_hz, range_rad_s=spec.range_rad_s,
                              latency_s=spec.latency_s, startup_time_s=spec.startup_time_s)


class _GyroDevice(SerialDevice):
    def __init__(self, spec: GyroSpec, ctx: BuildContext):
        self.name, self.spec = spec.name, spec
        self.silent_after_s = SILENT_SAMPLES / spec.output_rate_hz
        self.emulator = None
        self.host = None
        #: The link as the stand sees it beside the flight code (``_watch``); telemetry reads only this.
        self.observer = FrameObserver()

    def _watch(self, endpoint) -> None:
        """Observe the link at ``endpoint``'s framing layer: the host's received datagrams (emulated, hardware) or
        what the emulator sent and received (served). The flight code's driver is never read for telemetry."""
        endpoint.add_observer(self.observer)

    def columns(self):
        return [(f"{self.name}.omega_S", 3, "rad/s"), (f"{self.name}.valid", 1, "1")]

    def _latest(self):
        return self.observer.latest(GyroRate)

    def row(self):
        s = self.observer.latest(GyroRate)  # _latest(), read every tick
        return (*s.omega_rad_s, float(s.valid)) if s is not None else NAN4

    def activity(self):
        return self.observer.count(GyroRate)

    def summary(self):
        return {"observed_samples": self.observer.count(GyroRate), **self.driver_counters()}

    def fault_tap(self, name: str):
        if name == "measurement" and self.emulator is not None:  # the measured rate, before quantisation
            from sim.sensor_faults import VectorTap

            return VectorTap(self.emulator, "source", 3, "rad_s")
        return None


class EmulatedGyro(_GyroDevice):
    """Emulator and host on an in-process serial line (pipe or pty); every datagram reaches the host within its tick."""

    def __init__(self, spec: GyroSpec, ctx: BuildContext):
        from drivers.gyro.emulator import GyroEmulator
        from drivers.gyro.host import GyroHost

        super().__init__(spec, ctx)
        self._push, source = rate_source(spec, ctx)
        self.open_emulated(spec.port,
                           lambda end: GyroEmulator(end, source, _config(spec), name=f"{spec.name} emulator"),
                           lambda end: GyroHost(end, name=spec.name))
        self._watch(self.host)

    def publish(self, t_s: float) -> None:
        if self._push is not None:
            self._push(t_s)
        emu, host = self.emulator, self.host
        emu.service(t_s)
        # What a pipe line holds is there at once: the host takes it now, so settling only checks the counts.
        host.poll()
        settle_serial(emu, host, self.name, "RATE datagram")


class HardwareGyro(_GyroDevice):
    """The host driver on a real port: the stand reads (and records) what the gyro sends."""

    def __init__(self, spec: GyroSpec, ctx: BuildContext):
        from drivers.gyro.host import GyroHost

        super().__init__(spec, ctx)
        self.host = GyroHost(spec.port, baudrate=spec.baudrate, name=spec.name)
        self._watch(self.host)

    def publish(self, t_s: float) -> None:
        self.host.poll()


class ServedGyro(_GyroDevice):
    """The emulator on a real port, fed by the truth, for a flight computer outside; no host in the stand."""

    def __init__(self, spec: GyroSpec, ctx: BuildContext):
        from drivers.gyro.emulator import GyroEmulator

        super().__init__(spec, ctx)
        self._push, source = rate_source(spec, ctx)
        self.serve(GyroEmulator(spec.port, source, _config(spec), baudrate=spec.baudrate, name=f"{spec.name} emulator"))
        self._watch(self.emulator)

    def publish(self, t_s: float) -> None:
        if self._push is not None:
            self._push(t_s)
        self.emulator.service(t_s)
        self.rejections.check(t_s)


KIND = GyroKind()


# -- how `stand emulate gyro` serves it ---------------------------------------------------------------------------

def _serve(args, fail) -> int:
    """The serial gyro in wall time, measuring a fixed rate (open loop)."""
    from drivers.gyro.emulator import GyroEmulator, GyroEmulatorConfig

    try:
        rate_rad_s = tuple(math.radians(x) for x in numbers(args.rate_deg_s, 3, "--rate-deg-s", "deg/s (X,Y,Z)"))
        config = GyroEmulatorConfig(output_period_s=args.period_s)
    except ValueError as exc:
        return fail(str(exc))
    return serve_serial(args, fail, "gyro", lambda: GyroEmulator(args.port, lambda _t: rate_rad_s, config,
                                                                 baudrate=args.baud))


def _serving():
    return Serving(
        summary="The gyro on a serial line (datagrams of fixtures/devices/gyro.toml).",
        port_help="a serial URL or path (/dev/ttyUSB0, a pty or socat link, socket://...)",
        serve=_serve,
        port_fields=serial_port_fields,
        options=(ServeOption("--baud", "baud rate (default 460800)", 460800, int),
                 ServeOption("--rate-deg-s", "open loop: the rate it measures, sensor axes, deg/s, as X,Y,Z "
                                             "(default 0,0,0)", "0,0,0"),
                 ServeOption("--period-s", "time between RATE datagrams, s (default 0.01)", 0.01, float)),
    )


KIND.serving = _serving()
