"""A standalone magnetometer on CAN (``drivers.magnetometer``, the DBC ``fixtures/devices/magnetometer.dbc``).

A unit of its own (a fluxgate or AMR magnetometer on a boom or its own board, node 0x18), away from the
magnetorquer's coils; the board's own magnetometer is part of the magnetorquer kind and measures through the same
sensor model (:class:`drivers.magnetometer.sensor.MagnetometerModel`). CAN, because it shares the bus the
magnetorquer board and the wheels already use: one harness, one adapter on the flight computer. It reads in its
sensor frame ``q_SB``. Links:

* ``emulated``: the emulator and the host driver on an in-process python-can bus, fed by the truth;
* ``hardware``: the host driver on a real adapter;
* ``served``: the emulator on a real adapter, fed by the truth, for a flight computer outside.

Telemetry (``NAME.mag_S``, ``NAME.mag_valid``) records what the unit sent, seen by a listen-only node of the stand
on the same bus (:class:`drivers.can_observer.CanObserver`), never through the flight code's driver.

Table keys: ``interface``, ``channel``, ``sample_rate_hz`` (10), ``status_rate_hz`` (1), ``noise_nT`` (1-sigma per
axis, 0), ``bias_nT`` (3, sensor axes, [0, 0, 0]), ``lsb_nT`` (quantisation, a whole multiple of the ICD's 1 nT, 1),
``field_source`` ("truth", or the name of a device that makes the field, a Helmholtz cage).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

from sim.truth import rotate_to_body
from stand.checks import rate
from stand.devices import BuildContext, Device, DeviceCost, DeviceKind, DeviceSpec, can_endpoint, fault_taps
from stand.devices.served_can import CanSpec, ObservedCan, ServedCan
from stand.devices.serving import SEED_OPTION, ServeOption, can_serving, field_option, serve_can_in_field

NAN3 = (math.nan, math.nan, math.nan)
#: A unit that has sent nothing for this many sample periods is reported silent.
SILENT_PERIODS = 5


@functools.cache
def _codec():
    """The unit's codec, for the limits its DBC sets (built once)."""
    from drivers.magnetometer.codec import MagnetometerCodec

    return MagnetometerCodec()


@dataclass(frozen=True)
class MagnetometerSpec(CanSpec):
    sample_rate_hz: float = 10.0
    status_rate_hz: float = 1.0
    noise_T: float = 0.0
    bias_T: tuple = (0.0, 0.0, 0.0)
    lsb_T: float = 1e-9
    field_source: str = "truth"


class FieldSensingKind(DeviceKind):
    """A kind with a magnetometer reading the truth's field, or a cage's (its ``field_source``): this one and the
    magnetorquer board's."""

    #: What reads the field, named in the needs of the run (``{}``: the device's name).
    field_reader = "magnetometer {}"

    def refs(self, spec) -> dict[str, tuple[str, str]]:
        return {} if spec.field_source == "truth" else {"field_source": (spec.field_source, "magnetic_field")}

    def needs(self, spec) -> dict[str, str]:
        if spec.link == "hardware" or spec.field_source != "truth":
            return {}  # a real magnetometer, or one in a cage, reads the field where it is
        return {"magnetic_field": self.field_reader.format(spec.name)}


class MagnetometerKind(FieldSensingKind):
    name = "magnetometer"
    senses = ("magnetic_field",)
    column_meanings = {"mag_S": "the newest field sample the unit sent, sensor axes",
                       "mag_valid": "1 when that sample is valid (not saturated, no fault)"}

    def parse(self, t, base: DeviceSpec, step_s: float) -> MagnetometerSpec:
        codec = _codec()
        wire_nT = codec.mag_lsb_T * 1e9
        interface, channel = can_endpoint(t, base)
        lsb_nT = t.number("lsb_nT", wire_nT, lo=wire_nT, hi=1e4)
        if abs(lsb_nT / wire_nT - round(lsb_nT / wire_nT)) > 1e-6:
            raise t.error("lsb_nT", lsb_nT, f"a whole multiple of the ICD's MAG_FIELD step ({wire_nT:g} nT)")
        spec = MagnetometerSpec(
            **base.__dict__, interface=interface, channel=channel,
            sample_rate_hz=rate(t, "sample_rate_hz", step_s, 10.0),
            status_rate_hz=rate(t, "status_rate_hz", step_s, 1.0),
            noise_T=t.number("noise_nT", 0.0, lo=0.0, hi=1e5) * 1e-9,
            bias_T=tuple(t.vector("bias_nT", 3, [0.0, 0.0, 0.0], lo=-1e5, hi=1e5) * 1e-9),
            lsb_T=lsb_nT * 1e-9,
            field_source=t.text("field_source", "truth"),
        )
        t.check_unknown()
        return spec

    def describe(self, spec) -> str:
        where = f"CAN {spec.interface}:{spec.channel}"
        return {"emulated": f"magnetometer emulated on {where} at {spec.sample_rate_hz:g} Hz",
                "hardware": f"magnetometer on {where}",
                "served": f"magnetometer served on {where} for a flight computer outside, at "
                          f"{spec.sample_rate_hz:g} Hz"}[spec.link]

    def cost(self, spec: MagnetometerSpec) -> DeviceCost:
        return DeviceCost(rate_hz=spec.sample_rate_hz, row_floats=4)

    def fault_taps(self, spec: MagnetometerSpec) -> dict:
        return fault_taps(spec.link, measurement={"n": 3, "unit": "T"})

    def build(self, spec: MagnetometerSpec, ctx: BuildContext) -> Device:
        return {"emulated": EmulatedMagnetometer, "hardware": HardwareMagnetometer,
                "served": ServedMagnetometer}[spec.link](spec, ctx)


def _row(sample) -> tuple:
    return (*sample.b_T, float(sample.valid)) if sample is not None else (*NAN3, math.nan)


class _Unit(ObservedCan, Device):
    def __init__(self, spec: MagnetometerSpec):
        self.name, self.spec = spec.name, spec
        self.silent_after_s = SILENT_PERIODS / spec.sample_rate_hz
        self._buses: list = []

    def columns(self):
        return [(f"{self.name}.mag_S", 3, "T"), (f"{self.name}.mag_valid", 1, "1")]

    def row(self):
        return _row(self.observer.poll_newest(self._sample_id))

    def activity(self):
        return 0 if self.observer is None else self._observed_samples()

    def fault_tap(self, name: str):
        return measurement_tap(getattr(self, "emulator", None), "sensor", name)

    def close(self) -> None:
        for part in (self.host, getattr(self, "emulator", None), self.observer):
            if part is not None:
                part.close()
        for b in self._buses:
            b.shutdown()
        self._buses = []


def measurement_tap(emulator, sensor: str, name: str):
    """The measured field (sensor axes, T, after the sensor's noise and quantiser) of ``emulator.<sensor>``, for a
    fault of tap ``name`` = "measurement" (None for any other tap: the conventions find it)."""
    if name != "measurement" or emulator is None:
        return None
    from sim.sensor_faults import VectorTap

    return VectorTap(getattr(emulator, sensor), "measure", 3, "T", first=True)


def sensor_field(spec, ctx: BuildContext):
    """``t_s -> field at the sensor, sensor axes, T`` of a magnetometer mounted at ``spec.q_SB``: the truth's, or
    in a cage (``spec.field_source``) the cage's field, read through the mount."""
    truth = ctx.truth
    q_SB = tuple(float(x) for x in spec.q_SB)
    if spec.field_source != "truth":
        stimulus = ctx.stimuli[spec.field_source].stimulus_field_B

        def field_S(_t_s):
            return rotate_to_body(q_SB, stimulus())  # the unit sits in the cage, reading it through its mount
    elif q_SB == (1.0, 0.0, 0.0, 0.0):
        field_S = truth.b_B  # sensor axes are body axes: the truth's own (cached) field
    else:
        def field_S(_t_s):
            # Composition of q_SB after q_BN on floats: v_S = dcm(q_SB) dcm(q_BN) b_N.
            return rotate_to_body(q_SB, truth.b_B())
    return field_S


def _emulator(spec: MagnetometerSpec, ctx: BuildContext, bus):
    from drivers.magnetometer.emulator import MagnetometerConfig, MagnetometerEmulator

    config = MagnetometerConfig(noise_T=spec.noise_T, bias_T=tuple(spec.bias_T), lsb_T=spec.lsb_T,
                                sample_period_s=1.0 / spec.sample_rate_hz, status_period_s=1.0 / spec.status_rate_hz)
    return MagnetometerEmulator(bus, sensor_field(spec, ctx), config, ctx.rng, codec=_codec())


class EmulatedMagnetometer(_Unit):
    def __init__(self, spec: MagnetometerSpec, ctx: BuildContext):
        from drivers.magnetometer.host import MagnetometerHost

        super().__init__(spec)
        codec = _codec()
        self._open_emulated(lambda bus: _emulator(spec, ctx, bus),
                            lambda bus: MagnetometerHost(bus, codec=codec, name=spec.name), codec, codec.id_sample)

    def publish(self, t_s):
        self.emulator.publish(t_s)

    def receive(self, t_s):
        self.emulator.receive(t_s)

    def summary(self):
        return {**self.host.counters, "emulator": dict(self.emulator.counters)}


class HardwareMagnetometer(_Unit):
    """The host driver on a real unit. On an adapter every handle of which sees the whole bus (socketcan,
    udp_multicast) telemetry comes from a listen-only handle of its own; on a serial-line adapter, which one process
    holds alone, it comes from the stand's host driver (the flight code on a hardware link is the stand's)."""

    def __init__(self, spec: MagnetometerSpec, ctx: BuildContext):
        from drivers.can_bus import open_device_bus
        from drivers.magnetometer.host import MagnetometerHost

        super().__init__(spec)
        self._buses.append(open_device_bus(spec.interface, spec.channel))
        self.host = MagnetometerHost(self._buses[0], codec=_codec(), name=spec.name)
        self._observe(_codec(), _codec().id_sample)

    def publish(self, t_s):
        self.host.poll()

    def row(self):
        if self.observer is not None:
            return super().row()
        self.host.poll()
        return _row(self.host.latest_sample)

    def activity(self):
        return super().activity() if self.observer is not None else self.host.counters["samples"]

    def summary(self):
        return dict(self.host.counters)


class ServedMagnetometer(ServedCan, _Unit):
    """The emulator on a real adapter for a flight computer outside; telemetry is what the emulator sent."""

    def __init__(self, spec: MagnetometerSpec, ctx: BuildContext):
        super().__init__(spec)
        self._open_served(spec, _codec().unit_tx_ids, lambda link: _emulator(spec, ctx, link))

    def receive(self, t_s):
        self.emulator.receive(t_s)
        self.rejections.check(t_s)

    def row(self):
        return _row(self.emulator.last_sample)

    def activity(self):
        return self.emulator.counters["sent"]


KIND = MagnetometerKind()


# -- how `stand emulate magnetometer` serves it ---------------------------------------------------------------------

def _serve(args, fail) -> int:
    """The standalone magnetometer on a python-can bus in wall time, seeing a fixed field."""
    from drivers.magnetometer.emulator import MagnetometerConfig, MagnetometerEmulator

    if not (math.isfinite(args.noise_nT) and args.noise_nT >= 0):
        return fail(f"--noise-nT {args.noise_nT:g} is not allowed; give a noise of 0 nT or more.")
    config = MagnetometerConfig(noise_T=args.noise_nT * 1e-9)
    return serve_can_in_field(args, fail, "magnetometer", _codec().unit_tx_ids,
                              lambda bus, field: MagnetometerEmulator(bus, field, config, rng=args.seed, owns_bus=True))


KIND.serving = can_serving(
    "A standalone 3-axis magnetometer on a CAN bus.", "magnetometer", _serve,
    (field_option("open loop: the field it sees, sensor axes, nT, as X,Y,Z"),
     ServeOption("--noise-nT", "1-sigma noise per axis, nT (default 0)", 0.0, float), SEED_OPTION))
