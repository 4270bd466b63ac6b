"""Magnetorquer board with its magnetometer, on CAN (``drivers.magnetorquer``, the DBC in ``fixtures/devices``).

The coils act in body axes; the magnetometer reads in its sensor frame ``q_SB``. Links:

* ``emulated``: the board's emulator and the host driver on an in-process python-can bus; the emulator samples
  the true field and holds the dipole it was commanded (saturated, quantised, watchdog).
* ``hardware``: the host driver on a real adapter. The dipole applied to the truth is the one the board
  reports it produced: its coil currents (``MTQ_STATUS``) times ``coil_area_turns_m2``.
* ``served``: the emulator on a real adapter, fed by the truth, for a flight computer outside.

The magnetometer measures through the one sensor model of the stand (:mod:`drivers.magnetometer.sensor`; a
standalone unit is the ``magnetometer`` kind). Telemetry records the samples the board sent as a listen-only node of
the stand sees them on the bus (:class:`drivers.can_observer.CanObserver`), never through the flight code's driver;
on a hardware serial-line adapter, which the host driver holds alone, from the stand's host driver.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass

import numpy as np

from sim.effects import Effect
from sim.rotations import dcm
from stand.checks import rate
from stand.devices import BuildContext, Device, DeviceCost, DeviceSpec, can_endpoint, fault_taps
from stand.devices.magnetometer import FieldSensingKind, measurement_tap, sensor_field
from stand.devices.served_can import CanSpec, ObservedCan, ServedCan
from stand.devices.serving import SEED_OPTION, can_serving, field_option, serve_can_in_field

NAN3 = (math.nan, math.nan, math.nan)


#: A board whose magnetometer has sent nothing for this many sample periods is reported silent.
SILENT_PERIODS = 5


@dataclass(frozen=True)
class MagnetorquerSpec(CanSpec):
    sample_rate_hz: float = 10.0
    status_rate_hz: float = 1.0
    max_dipole_A_m2: float = 0.2
    dipole_lsb_A_m2: float = 1e-5
    mag_noise_T: float = 0.0
    mag_bias_T: tuple = (0.0, 0.0, 0.0)
    coil_coupling_T_per_A_m2: tuple = (0.0, 0.0, 0.0)
    coil_area_turns_m2: tuple = (2.0, 2.0, 2.0)
    field_source: str = "truth"  # or the name of a device that makes the field (a Helmholtz cage)


@functools.cache
def _codec():
    """The board's codec, for the limits its DBC sets (read only; built once, the DBC takes milliseconds to parse)."""
    from drivers.magnetorquer.codec import MagnetorquerCodec

    return MagnetorquerCodec()


class MagnetorquerKind(FieldSensingKind):
    name = "magnetorquer"
    field_reader = "magnetometer of {}"
    senses = ("magnetic_field",)
    actuates = ("dipole",)
    column_meanings = {"mag_S": "the newest magnetometer sample the host decoded, sensor axes",
                       "mag_coil_active": "1 when that sample was taken with the coils driven",
                       "dipole_B": "the dipole the board produced, held over the step, body axes"}
    plot_files = {"dipole.png": "the dipole commanded by the controller and produced by each board, per body axis"}
    view_plots = ({"title": "dipole", "unit": "A m²", "column": "dipole_B", "fallback": "dipole_cmd_B"},)

    def kind_plots(self, tel, names, out_dir) -> list[str]:
        # lazy: the figures load matplotlib, which only drawing a report needs
        from stand.devices.magnetorquer_plots import plot_dipole

        produced = {n: f"{n}.dipole_B" for n in names if f"{n}.dipole_B" in tel}
        commanded = "dipole_cmd_B" if "dipole_cmd_B" in tel else None
        return [plot_dipole(tel, out_dir, produced, commanded)] if produced or commanded else []

    def parse(self, t, base: DeviceSpec, step_s: float) -> MagnetorquerSpec:
        codec = _codec()
        dipole_max = codec.dipole_range_A_m2[1]  # what MTQ_DIPOLE_CMD can carry
        interface, channel = can_endpoint(t, base)
        max_dipole = t.number("max_dipole_A_m2", 0.2, lo=0.0, lo_open=True, hi=dipole_max)
        spec = MagnetorquerSpec(
            **base.__dict__,
            interface=interface, channel=channel,
            sample_rate_hz=rate(t, "sample_rate_hz", step_s, 10.0),
            status_rate_hz=rate(t, "status_rate_hz", step_s, 1.0),
            max_dipole_A_m2=max_dipole,
            # The produced dipole is quantised to the board's PWM step, no finer than the command's LSB.
            dipole_lsb_A_m2=t.number("dipole_lsb_A_m2", 1e-5, lo=codec.dbc.signal_scale("MTQ_DIPOLE_CMD", "dipole_x"),
                                     hi=max_dipole),
            mag_noise_T=t.number("mag_noise_nT", 0.0, lo=0.0, hi=1e5) * 1e-9,
            mag_bias_T=tuple(t.vector("mag_bias_nT", 3, [0.0, 0.0, 0.0], lo=-1e5, hi=1e5) * 1e-9),
            coil_coupling_T_per_A_m2=tuple(t.vector("coil_coupling_nT_per_A_m2", 3, [0.0, 0.0, 0.0], lo=-1e6,
                                                    hi=1e6) * 1e-9),
            coil_area_turns_m2=tuple(t.vector("coil_area_turns_m2", 3, [2.0, 2.0, 2.0], lo=1e-3, hi=1e4)),
            field_source=t.text("field_source", "truth"),
        )
        t.check_unknown()
        return spec

    def describe(self, spec) -> str:
        where = f"CAN {spec.interface}:{spec.channel}"
        return {"emulated": f"magnetorquer board emulated on {where}, magnetometer at {spec.sample_rate_hz:g} Hz",
                "hardware": f"magnetorquer board on {where} (hardware: the produced dipole is read back from its "
                            f"coil currents at {spec.status_rate_hz:g} Hz)",
                "served": f"magnetorquer board served on {where} for a flight computer outside, magnetometer at "
                          f"{spec.sample_rate_hz:g} Hz"}[spec.link]

    def cost(self, spec: MagnetorquerSpec) -> DeviceCost:
        return DeviceCost(rate_hz=spec.sample_rate_hz, row_floats=7)

    def fault_taps(self, spec: MagnetorquerSpec) -> dict:
        return fault_taps(spec.link, "coils", measurement={"n": 3, "unit": "T"})

    def build(self, spec: MagnetorquerSpec, ctx: BuildContext) -> Device:
        return {"emulated": EmulatedBoard, "hardware": HardwareBoard, "served": ServedBoard}[spec.link](spec, ctx)


class _Board(ObservedCan, Device):

    def __init__(self, spec: MagnetorquerSpec):
        self.name, self.spec = spec.name, spec
        self.silent_after_s = SILENT_PERIODS / spec.sample_rate_hz
        self._m = (0.0, 0.0, 0.0)
        self._buses: list = []

    def columns(self):
        n = self.name
        return [(f"{n}.mag_S", 3, "T"), (f"{n}.mag_coil_active", 1, "1"), (f"{n}.dipole_B", 3, "A m^2")]

    def dipole_B(self):
        return self._m

    def _observed_row(self):
        s = self.observer.poll_newest(self._sample_id)
        return (*s.b_T, float(s.coil_active), *self._m) if s else (*NAN3, math.nan, *self._m)

    def effects(self):
        return (Effect("dipole", self.dipole_B),)

    def fault_tap(self, name: str):
        return measurement_tap(getattr(self, "emulator", None), "magnetometer", name)

    def close(self) -> None:
        if self.observer is not None:
            self.observer.close()
        for b in self._buses:
            b.shutdown()
        self._buses = []


def _emulator(spec: MagnetorquerSpec, ctx: BuildContext, bus):
    from drivers.magnetorquer.emulator import EmulatorConfig, MagnetorquerEmulator

    config = EmulatorConfig(
        max_dipole_A_m2=spec.max_dipole_A_m2, dipole_lsb_A_m2=spec.dipole_lsb_A_m2,
        mag_noise_T=spec.mag_noise_T, mag_bias_T=tuple(spec.mag_bias_T),
        coil_coupling_T_per_A_m2=np.diag(spec.coil_coupling_T_per_A_m2) @ dcm(spec.q_SB).T,
        coil_area_turns_m2=tuple(spec.coil_area_turns_m2),
        sample_period_s=1.0 / spec.sample_rate_hz, status_period_s=1.0 / spec.status_rate_hz,
    )
    return MagnetorquerEmulator(bus, sensor_field(spec, ctx), config, ctx.rng)


class EmulatedBoard(_Board):
    def __init__(self, spec: MagnetorquerSpec, ctx: BuildContext):
        from drivers.magnetorquer.host import MagnetorquerBoard

        super().__init__(spec)
        codec = _codec()
        self._open_emulated(lambda bus: _emulator(spec, ctx, bus), lambda bus: MagnetorquerBoard(bus, name=spec.name),
                            codec, codec.id_mag_sample)
        self._publish, self._receive, self._held = self.emulator.publish, self.emulator.receive, \
            self.emulator.dipole_xyz_at

    def publish(self, t_s):
        self._publish(t_s)

    def receive(self, t_s):
        self._receive(t_s)
        self._m = self._held(t_s)

    def row(self):
        return self._observed_row()  # every sample that crossed the bus, whether or not the flight code took it

    def activity(self):
        return self._observed_samples()

    def summary(self):
        return {**self.host.counters, "emulator": dict(self.emulator.counters)}

    def close(self):
        if self.host is not None:
            self.host.close()
        super().close()


class HardwareBoard(_Board):
    """The host driver on a real board; the truth gets the dipole the board reports (coil currents x N A)."""

    def __init__(self, spec: MagnetorquerSpec, ctx: BuildContext):
        from drivers.can_bus import open_device_bus
        from drivers.magnetorquer.host import MagnetorquerBoard

        super().__init__(spec)
        self._buses.append(open_device_bus(spec.interface, spec.channel))
        self.host = MagnetorquerBoard(self._buses[0], name=spec.name)
        self._na = tuple(float(x) for x in spec.coil_area_turns_m2)
        self._status_seen = 0
        self._observe(_codec(), _codec().id_mag_sample)

    def start(self, events):
        # The board's DBC has no time message: its clock cannot be set. Its heartbeat uptime is logged against
        # the stand's clock so a reader can line the two up.
        t0 = time.monotonic()
        deadline = t0 + 2.0
        while self.host.last_heartbeat is None and time.monotonic() < deadline:
            self.host.poll()
            time.sleep(0.01)
        hb = self.host.last_heartbeat
        events.log("device_clock", f"{self.name}: the DBC has no time message, so the board clock is not set; "
                   + (f"its uptime is {hb.uptime_s} s at start" if hb else "no heartbeat within 2 s of start"),
                   device=self.name, uptime_s=hb.uptime_s if hb else None)

    def publish(self, t_s):
        self.host.poll()

    def receive(self, t_s):
        self.host.poll()
        st = self.host.latest_status
        if st is not None:
            ix, iy, iz = st.coil_current_A
            nx, ny, nz = self._na
            self._m = (ix * nx, iy * ny, iz * nz)

    def row(self):
        if self.observer is not None:
            return self._observed_row()
        s = self.host.latest_sample
        return (*s.b_T, float(s.coil_active), *self._m) if s else (*NAN3, math.nan, *self._m)

    def activity(self):
        return self._observed_samples() if self.observer is not None else self.host.counters["samples"]

    def summary(self):
        return dict(self.host.counters)

    def close(self):
        self.host.close()
        super().close()


class ServedBoard(ServedCan, _Board):
    """The emulator on a real adapter for a flight computer outside; the stand holds no host driver. What the flight
    computer sends that the board cannot decode is counted and dropped (:class:`drivers.can_bus.ServedBus`)."""

    def __init__(self, spec: MagnetorquerSpec, ctx: BuildContext):
        super().__init__(spec)
        self._open_served(spec, _codec().board_tx_ids, lambda link: _emulator(spec, ctx, link))
        # Silence here means the flight computer stopped commanding.
        self.silent_after_s = SILENT_PERIODS / spec.sample_rate_hz

    def receive(self, t_s):
        self.emulator.receive(t_s)
        self._m = self.emulator.dipole_xyz_at(t_s)
        self.rejections.check(t_s)

    def row(self):
        s = self.emulator.last_sample
        return (*s.b_T, float(s.coil_active), *self._m) if s else (*NAN3, math.nan, *self._m)



KIND = MagnetorquerKind()


# -- how `stand emulate magnetorquer` serves it -------------------------------------------------------------------

def _serve(args, fail) -> int:
    """The CAN magnetorquer board (with its magnetometer) on a python-can bus in wall time, seeing a fixed field."""
    from drivers.magnetorquer.emulator import EmulatorConfig, MagnetorquerEmulator

    return serve_can_in_field(args, fail, "magnetorquer board", _codec().board_tx_ids,
                              lambda bus, field: MagnetorquerEmulator(bus, field, EmulatorConfig(), rng=args.seed,
                                                                      owns_bus=True))


KIND.serving = can_serving(
    "The magnetorquer board (coils and magnetometer) on a CAN bus.", "magnetorquer", _serve,
    (field_option("open loop: the field its magnetometer sees, sensor axes, nT, as X,Y,Z"), SEED_OPTION))
