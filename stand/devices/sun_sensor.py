"""Sun sensors, coarse (six photodiode heads) or fine (two angles), on a serial line (``drivers.sun_sensor``, the
ICD in ``fixtures/devices/sun_sensor.toml``).

The stand hands the emulator what the sensor measures at each sample time: the Sun direction from the scene's
Sun track, turned into body axes, and the visible fraction of the Sun's disk from the conical shadow model,
through :class:`sim.sensors.CoarseSunSensors` (cosine heads on the six body faces, rotated by the mount) or
:class:`sim.sensors.FineSunSensor` (noise, field of view, invalid in umbra and deep penumbra). The emulator adds
what the wire does: quantisation to the datagram's LSB (1 urad, 0.1 uA, 1 %), the current range, angles sent
as 0 when not valid.

Links: ``emulated`` (default; emulator and host on an in-process serial line, ``port = "pipe"`` (default) or a
kernel pty pair with ``port = "pty"``, every exchange settled within the
tick, so a run is bit-for-bit repeatable), ``hardware`` (the host on a real port; at start the stand sets the
sensor's output period to ``1 / rate_hz``), ``served`` (the emulator on a real port, fed by the truth, for a
flight computer outside), and ``model`` (no protocol: :class:`SunSensorReader` hands the flight code the
model's unquantised reading).

On every link the flight code's ``take_sun()`` returns the codec's shape: a
:class:`~drivers.sun_sensor.codec.FineSunSample` (``.angles_rad``, ``.intensity``) or a
:class:`~drivers.sun_sensor.codec.CoarseSunSample` (``.currents_A``, ``.saturated``), with ``.valid``,
``.time_us`` (device clock; sim time on the emulated and model links) and ``.seq``.

Telemetry: ``NAME.currents`` (A, coarse) or ``NAME.angles`` (rad, fine) and ``NAME.valid``: the newest sample
on the link, observed beside the flight code (:class:`drivers.framing.FrameObserver` on the host's framing layer;
on a served link, what the emulator sent; on the model link, what the model gave), never read from the flight
code's driver; ``NAME.sun_fraction``:
the visible fraction of the Sun at that sample (NaN on a hardware link, where nothing is simulated).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivers.framing import FrameObserver
from drivers.sun_sensor.codec import CoarseSunSample, FineSunSample
from sim.environment import shadow_fraction
from sim.rotations import dcm
from sim.sensors import CoarseSunSensors, FineSunSensor
from sim.truth import rotate_to_body
from stand.checks import rate, ticks_per
from stand.devices import (
    LINKS,
    SERIAL_LINES,
    BuildContext,
    Device,
    DeviceCost,
    DeviceKind,
    DeviceSpec,
    SerialDevice,
    check_serial_url,
    fault_taps,
    settle_serial,
)
from stand.devices.serving import ServeOption, Serving, numbers, serial_port_fields, serve_serial

#: Coarse heads on the six body faces (+x, -x, +y, -y, +z, -z), rotated by the mount.
HEAD_LABELS = ["+x face", "-x face", "+y face", "-y face", "+z face", "-z face"]
FACE_NORMALS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
#: Sample periods a sun sensor may miss before it is reported silent.
SILENT_SAMPLES = 10
#: The longest output period SET_OUTPUT_PERIOD carries (s).
MAX_PERIOD_S = 60.0


@dataclass(frozen=True)
class SunSensorSpec(DeviceSpec):
    type: str = "coarse"  # "coarse" | "fine"
    rate_hz: float = 10.0
    noise: float = 0.0  # coarse: head current noise (A); fine: angle noise (rad)
    fov_half_deg: float = 90.0
    port: str = "pipe"
    baudrate: int = 115200

    @property
    def width(self) -> int:
        return len(FACE_NORMALS) if self.type == "coarse" else 2


class SunSensorReader:
    """The host-side reader of a modelled sun sensor (``link = "model"``): ``take_sun()`` returns the newest
    sample once, in the codec's shape (:class:`FineSunSample` or :class:`CoarseSunSample`, unquantised)."""

    def __init__(self, name: str):
        self.name = name
        self.latest_sample = None
        self._taken = True
        self.counters = {"samples": 0}

    def _put(self, sample) -> None:
        self.latest_sample, self._taken = sample, False
        self.counters["samples"] += 1

    def take_sun(self):
        if self._taken:
            return None
        self._taken = True
        return self.latest_sample

    def close(self) -> None:
        """Nothing to release: the sensor is a model."""


class SunSensorKind(DeviceKind):
    name = "sun_sensor"
    senses = ("sun",)
    column_meanings = {"currents": "the six heads' currents the host decoded (coarse sensor)",
                       "angles": "the Sun's two angles in the sensor frame the host decoded (fine sensor)",
                       "valid": "1 when that sample is valid",
                       "sun_fraction": "the visible fraction of the Sun's disc (Earth shadow) at that sample"}
    plot_files = {"sun_{name}.png": "head currents or angles with the Earth shadow, the Sun fraction and validity"}
    view_layer_meanings = {"fovs": "the field of view, one cone per head of a coarse sensor, lit by its current"}
    # invalid means no usable Sun (outside the field or in shadow): the grey "no solution" colour, never the red
    # the view's legend calls "Sun in field" (a tracker's Sun exclusion)
    view_state = {"missing": "no sample", "flags": False, "invalid": ["none", "no Sun (outside the field or shadow)"]}

    def view_layers(self, spec) -> dict:
        half = float(getattr(spec, "fov_half_deg", 90.0))
        if getattr(spec, "type", "fine") != "coarse":
            return {"fovs": [{"shape": "cone", "axis_S": [0.0, 0.0, 1.0], "half_deg": half, "label": spec.name}]}
        return {"fovs": [{"shape": "cone", "axis_S": [float(x) for x in n], "half_deg": half,
                          "label": f"{spec.name} {label}", "head": True}
                         for n, label in zip(FACE_NORMALS, HEAD_LABELS, strict=True)]}
    links = (*LINKS, "model")
    default_link = "emulated"

    def parse(self, t, base: DeviceSpec, step_s: float) -> SunSensorSpec:
        kind = t.choice("type", ("coarse", "fine"))
        if kind == "coarse":
            noise = t.number("noise_mA", 0.0, lo=0.0, hi=10.0) * 1e-3
        else:
            noise = math.radians(t.number("noise_deg", 0.0, lo=0.0, hi=10.0))
        # Coarse heads default to the bare cosine law (a 90 deg half-field); a fine sensor to 60 deg.
        fov = t.number("fov_half_deg", 90.0, lo=1.0, hi=90.0) if kind == "coarse" else \
            t.number("fov_half_deg", 60.0, lo=1.0, hi=89.0)
        rate_hz = rate(t, "rate_hz", step_s, 1.0 / step_s)
        if base.link in ("emulated", "model"):
            port = t.choice("port", SERIAL_LINES, "pipe")
        else:
            port = check_serial_url(t, "port", t.text("port"))
        if base.link != "model" and 1.0 / rate_hz > MAX_PERIOD_S:
            raise t.error("rate_hz", rate_hz, f"at least {1.0 / MAX_PERIOD_S:.6g} Hz on a {base.link} link "
                          f"(SET_OUTPUT_PERIOD carries at most {MAX_PERIOD_S:g} s)")
        spec = SunSensorSpec(**base.__dict__, type=kind, rate_hz=rate_hz, noise=noise, fov_half_deg=fov, port=port,
                             baudrate=int(t.number("baudrate", 115200, lo=1200, hi=4_000_000, integer=True)))
        t.check_unknown()
        return spec

    def needs(self, spec) -> dict[str, str]:
        if spec.link == "hardware":
            return {}
        why = f"sun sensor {spec.name}"
        return {"sun": why, "eclipse": why}

    def datasheet(self, spec: SunSensorSpec) -> dict:
        return {"type": spec.type, "rate_hz": spec.rate_hz, "fov_half_rad": math.radians(spec.fov_half_deg)}

    def describe(self, spec) -> str:
        what = f"{spec.type} sun sensor"
        fed = f"at {spec.rate_hz:g} Hz, sampled from the truth, eclipse-aware"
        return {"emulated": f"{what} emulated on an in-process serial {spec.port} {fed}",
                "hardware": f"{what} on serial {spec.port} at {spec.baudrate} Bd (hardware: the stand reads its "
                            f"samples, output period set to {1.0 / spec.rate_hz:g} s)",
                "served": f"{what} served on serial {spec.port} for a flight computer outside {fed}",
                "model": f"{what} {fed} (link = 'model': no bus)"}[spec.link]

    def cost(self, spec: SunSensorSpec) -> DeviceCost:
        # A sample evaluates the Sun's position and the Earth's shadow: about 50 us.
        return DeviceCost(rate_hz=None if spec.link in ("hardware", "served") else spec.rate_hz,
                          row_floats=spec.width + 2, publish_s=0.0 if spec.link == "hardware" else 50e-6)

    def fault_taps(self, spec: SunSensorSpec) -> dict:
        if spec.link == "model":  # no line and no emulator: nothing for a fault to act on
            return {}
        return fault_taps(spec.link, measurement={"n": spec.width, "unit": "A" if spec.type == "coarse" else "rad"})

    def build(self, spec: SunSensorSpec, ctx: BuildContext) -> Device:
        return {"emulated": EmulatedSunSensor, "hardware": HardwareSunSensor, "served": ServedSunSensor,
                "model": ModelSunSensor}[spec.link](spec, ctx)

    def plots(self, tel, name, out_dir, criteria) -> list[str]:
        # lazy: the figures load matplotlib, which only drawing a report needs
        from stand.devices.sun_sensor_plots import plot_sun_sensor

        return [plot_sun_sensor(tel, out_dir, name, head_labels=HEAD_LABELS if f"{name}.currents" in tel else None)]


class SunTruth:
    """What the sensor measures: ``measure(t_s) -> (values, valid, nu)`` from the truth as it stands (the values
    are the model's: six head currents in A, or two angles in rad, NaN when not valid), with ``nu`` the visible
    fraction of the Sun. Counts the samples taken and those in shadow or penumbra."""

    def __init__(self, spec: SunSensorSpec, ctx: BuildContext):
        self.truth = ctx.truth
        self.sun = ctx.tracks["sun"]
        self.rng = ctx.rng
        self.coarse = spec.type == "coarse"
        dcm_SB = dcm(spec.q_SB)
        if self.coarse:
            self.model = CoarseSunSensors(FACE_NORMALS @ dcm_SB, noise_A=spec.noise, cutoff_deg=spec.fov_half_deg)
        else:
            self.model = FineSunSensor(dcm_SB, fov_half_deg=spec.fov_half_deg, noise_rad=spec.noise)
        self.samples = 0
        self.eclipsed = 0
        self.nu = math.nan

    def measure(self, t_s: float) -> tuple[tuple, bool, float]:
        r = np.array(self.truth.r_N)
        r_sun = self.sun.position_gcrs(t_s)
        d = r_sun - r
        s_B = np.array(rotate_to_body(self.truth.q, tuple(d / np.linalg.norm(d))))
        nu = float(shadow_fraction(r, r_sun))
        self.samples += 1
        self.eclipsed += nu < 1.0
        self.nu = nu
        if self.coarse:
            return tuple(self.model.measure(s_B, nu, self.rng).tolist()), nu > 0.0, nu
        angles, valid = self.model.measure(s_B, nu, self.rng)
        return tuple(angles.tolist()), bool(valid), nu

    def counts(self) -> dict:
        return {"samples_in_shadow_or_penumbra": int(self.eclipsed)}


def _config(spec: SunSensorSpec):
    from drivers.sun_sensor.emulator import SunEmulatorConfig

    return SunEmulatorConfig(kind=spec.type, output_period_s=1.0 / spec.rate_hz)


class _SunSensorDevice(SerialDevice):
    def __init__(self, spec: SunSensorSpec, ctx: BuildContext):
        self.name, self.spec = spec.name, spec
        self.silent_after_s = SILENT_SAMPLES / spec.rate_hz
        self.nan_row = (math.nan,) * (spec.width + 2)
        self.emulator = None
        self.host = None
        self.sun: SunTruth | None = None
        #: The link as the stand sees it beside the flight code (``_watch``); telemetry reads only this.
        self.observer = FrameObserver()

    def _watch(self, endpoint) -> None:
        """Observe the link at ``endpoint``'s framing layer: the host's received datagrams (emulated, hardware) or
        what the emulator sent and received (served). The flight code's driver is never read for telemetry."""
        endpoint.add_observer(self.observer)

    def columns(self) -> list[tuple[str, int, str]]:
        reading = (f"{self.name}.currents", self.spec.width, "A") if self.spec.type == "coarse" else \
            (f"{self.name}.angles", 2, "rad")
        return [reading, (f"{self.name}.valid", 1, "1"), (f"{self.name}.sun_fraction", 1, "1")]

    def _latest(self):
        return self.observer.latest(FineSunSample, CoarseSunSample)

    def row(self) -> tuple:
        s = self._latest()
        if s is None:
            return self.nan_row
        values = s.currents_A if self.spec.type == "coarse" else s.angles_rad
        if len(values) != self.spec.width:  # a hardware sensor of the other type: its values do not fit the columns
            return self.nan_row
        return (*values, float(s.valid), self.sun.nu if self.sun is not None else math.nan)

    def _source(self, ctx: BuildContext):
        self.sun = SunTruth(self.spec, ctx)
        return self.sun.measure

    def activity(self) -> int:
        return self.observer.count(FineSunSample, CoarseSunSample)

    def summary(self) -> dict:
        out = self.sun.counts() if self.sun is not None else {}
        out["observed_samples"] = self.observer.count(FineSunSample, CoarseSunSample)
        out.update(self.driver_counters())
        return out

    def fault_tap(self, name: str):
        if name == "measurement" and self.emulator is not None:  # head currents (coarse) or angles (fine)
            from sim.sensor_faults import VectorTap

            return VectorTap(self.emulator, "source", self.spec.width, "A" if self.spec.type == "coarse" else "rad",
                             first=True)
        return None



class EmulatedSunSensor(_SunSensorDevice):
    """Emulator and host on an in-process serial line (pipe or pty); every sample reaches the host within its tick."""

    def __init__(self, spec: SunSensorSpec, ctx: BuildContext):
        from drivers.sun_sensor.emulator import SunSensorEmulator
        from drivers.sun_sensor.host import SunSensorHost

        super().__init__(spec, ctx)
        # Serviced only on its sample ticks: the emulator's output grid falls on them, and nothing else talks
        # to it in the loop (the flight code streams; a blocking request would wait for the next sample tick).
        self.every_ticks = ticks_per(spec.rate_hz, ctx.step_s)
        source = self._source(ctx)
        self.open_emulated(spec.port,
                           lambda end: SunSensorEmulator(end, source, _config(spec), name=f"{spec.name} emulator"),
                           lambda end: SunSensorHost(end, name=spec.name))
        self._watch(self.host)

    def publish(self, t_s: float) -> None:
        self.emulator.service(t_s)
        settle_serial(self.emulator, self.host, self.name, "sun sample")


class HardwareSunSensor(_SunSensorDevice):
    """The host driver on a real port: the stand reads (and records) what the sensor sends."""

    def __init__(self, spec: SunSensorSpec, ctx: BuildContext):
        from drivers.sun_sensor.host import SunSensorHost

        super().__init__(spec, ctx)
        self.host = SunSensorHost(spec.port, baudrate=spec.baudrate, name=spec.name)
        self._watch(self.host)

    def start(self, events) -> None:
        # The sensor streams at its own period; the scenario's rate is what the silence watch expects.
        self.host.set_output_period(1.0 / self.spec.rate_hz)

    def publish(self, t_s: float) -> None:
        self.host.poll()


class ServedSunSensor(_SunSensorDevice):
    """The emulator on a real port, fed by the truth, for a flight computer outside; no host in the stand."""

    def __init__(self, spec: SunSensorSpec, ctx: BuildContext):
        from drivers.sun_sensor.emulator import SunSensorEmulator

        super().__init__(spec, ctx)
        # Serviced every tick so that a REQUEST_SAMPLE from outside is answered within one step.
        self.serve(SunSensorEmulator(spec.port, self._source(ctx), _config(spec), baudrate=spec.baudrate,
                                     name=f"{spec.name} emulator"))
        self._watch(self.emulator)

    def publish(self, t_s: float) -> None:
        self.emulator.service(t_s)
        self.rejections.check(t_s)


class ModelSunSensor(_SunSensorDevice):
    """No protocol: the model's reading goes to the flight code through a :class:`SunSensorReader`."""

    def __init__(self, spec: SunSensorSpec, ctx: BuildContext):
        super().__init__(spec, ctx)
        self.silent_after_s = None  # a model cannot fall silent
        self.every_ticks = ticks_per(spec.rate_hz, ctx.step_s)
        self._measure = self._source(ctx)
        self.host = SunSensorReader(spec.name)
        self._seq = 0

    def publish(self, t_s: float) -> None:
        values, valid, nu = self._measure(t_s)
        time_us, seq = round(t_s * 1e6), self._seq
        self._seq = (seq + 1) & 0xFFFF
        if self.spec.type == "coarse":
            sample = CoarseSunSample(time_us, values, valid, False, False, seq)
        else:
            sample = FineSunSample(time_us, values, nu, valid, False, seq)
        self.host._put(sample)
        self.observer(sample)  # no link to tap: the stand sees the model's reading as it hands it over

    def summary(self) -> dict:
        return {"samples": self.sun.samples, **self.sun.counts()}


KIND = SunSensorKind()


# -- how `stand emulate sun-sensor` serves it ---------------------------------------------------------------------

def _serve(args, fail) -> int:
    """A fine or coarse sun sensor in wall time, seeing a fixed Sun (open loop)."""
    from drivers.sun_sensor.emulator import SunEmulatorConfig, SunSensorEmulator

    try:
        if args.type == "fine":
            values = tuple(math.radians(x) for x in numbers(args.angles_deg, 2, "--angles-deg", "deg (ALPHA,BETA)"))
        else:
            values = tuple(x * 1e-3 for x in numbers(args.currents_mA, 6, "--currents-mA", "mA (six heads)"))
        config = SunEmulatorConfig(kind=args.type, output_period_s=args.period_s)
    except ValueError as exc:
        return fail(str(exc))
    return serve_serial(args, fail, f"{args.type} sun sensor",
                        lambda: SunSensorEmulator(args.port, lambda _t: (values, True), config, baudrate=args.baud))


def _serving():
    return Serving(
        summary="A fine or coarse sun sensor on a serial line (datagrams of fixtures/devices/sun_sensor.toml).",
        port_help="a serial URL or path (/dev/ttyUSB0, a pty or socat link, socket://...)",
        serve=_serve,
        port_fields=serial_port_fields,
        options=(ServeOption("--baud", "baud rate (default 115200)", 115200, int),
                 ServeOption("--type", "fine (two angles, default) or coarse (six head currents)", "fine", str,
                             ("fine", "coarse")),
                 ServeOption("--angles-deg", "open loop, fine: the Sun's angles alpha,beta, deg (default 0,0)",
                             "0,0"),
                 ServeOption("--currents-mA", "open loop, coarse: the six head currents, mA (default 0,...)",
                             "0,0,0,0,0,0"),
                 ServeOption("--period-s", "time between samples sent unasked, s; 0: only on request "
                                           "(default 0.1)", 0.1, float)),
    )


KIND.serving = _serving()
