"""Reaction wheels on CAN, one device per wheel (``drivers.reaction_wheel``, the DBC in ``fixtures/devices``).

A wheel is part of the truth's dynamics: composition asks every kind for its momentum wheels
(:meth:`stand.devices.DeviceKind.momentum_wheel`) and gives the truth a :class:`sim.wheels.WheelCluster` of them
before any device is built; each wheel device then knows its column in the cluster (``wheel_index``).

Each tick the device reads the command its emulator holds (``command_at``: TORQUE, SPEED or IDLE after the
watchdog), steps its motor model (:class:`sim.actuators.WheelMotor`: torque and speed limits, back-EMF roll-off,
first-order lag, Coulomb and viscous friction with stiction) from the truth's wheel speed, and gives the truth
the net torque on the rotor (``wheel_torque_Nm``) held over the step. ``ideal = true``: no friction, no lag
(the torque and speed limits stay: they are the wheel's rating).

Links:

* ``emulated``: emulator and host driver on an in-process python-can ``virtual`` bus;
* ``hardware``: the host on a real adapter; the truth gets the motor torque the wheel reports in RW_SPEED_TLM
  (the real rotor's speed is the wheel's, the truth's only mirrors it);
* ``served``: the emulator on a real adapter, fed by the truth, for a flight computer outside.

What the wheel sends is observed beside the flight code (:class:`drivers.framing.FrameObserver` on the host's CAN
node, through its listener hook): activity and the hardware link's torque and mode read the observer, never the
flight code's driver.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from drivers.framing import FrameObserver
from drivers.reaction_wheel.codec import Status as WheelStatus
from drivers.reaction_wheel.codec import WheelSpeed
from sim.effects import Effect
from sim.rotations import dcm
from stand.checks import rate
from stand.devices import BuildContext, Device, DeviceKind, DeviceSpec, can_endpoint, fault_taps
from stand.devices.served_can import CanSpec, ServedCan
from stand.devices.serving import ServeOption, can_serving, serve_can

RPM = math.pi / 30.0
MODE_CODES = {"IDLE": 0.0, "TORQUE": 1.0, "SPEED": 2.0}
#: Telemetry periods a wheel may miss before it is reported silent.
SILENT_PERIODS = 5


@dataclass(frozen=True)
class ReactionWheelSpec(CanSpec):
    wheel: int = 0
    spin_axis_B: tuple = (0.0, 0.0, 1.0)
    inertia_kg_m2: float = 2e-3
    max_torque_Nm: float = 4e-3
    max_speed_rad_s: float = 6000.0 * RPM
    coulomb_Nm: float = 0.0
    viscous_Nm_s: float = 0.0
    static_Nm: float | None = None
    time_constant_s: float = 0.0
    speed0_rad_s: float = 0.0
    telemetry_rate_hz: float = 10.0
    ideal: bool = False


@functools.cache
def _command_ranges() -> tuple[tuple[float, float], tuple[float, float]]:
    """The torque (N m) and speed (rad/s) ranges the shipped DBC's commands carry. Cached: building a codec parses
    the DBC and makes every packer, which a scenario load paid once per wheel only to read these two ranges."""
    from drivers.reaction_wheel.codec import ReactionWheelCodec

    codec = ReactionWheelCodec(0)
    return codec.torque_range_Nm, codec.speed_range_rad_s


class ReactionWheelKind(DeviceKind):
    name = "reaction_wheel"
    senses = ("wheel_momentum",)
    actuates = ("wheel_torque",)
    column_meanings = {"speed_rad_s": "the rotor's speed relative to the body",
                       "mode": "the wheel's mode (0 idle, 1 torque, 2 speed)",
                       "torque_cmd_Nm": "the torque (or, in speed mode, the speed) command held",
                       "motor_torque_Nm": "the motor's torque after its lag",
                       "net_torque_Nm": "the net torque on the rotor: motor minus friction"}
    plot_files = {"wheel_{name}.png": "speed, and the torques on the rotor"}

    def parse(self, t, base: DeviceSpec, step_s: float) -> ReactionWheelSpec:
        torque_range_Nm, speed_range_rad_s = _command_ranges()
        interface, channel = can_endpoint(t, base)
        if t.has("spin_axis_B") and t.has("q_SB"):
            raise t.error("spin_axis_B", t.raw("spin_axis_B"), "either spin_axis_B or q_SB (whose z axis is the "
                          "spin axis), not both")
        if t.has("spin_axis_B"):
            axis = t.vector("spin_axis_B", 3, lo=-1e3, hi=1e3)
            n = float(np.linalg.norm(axis))
            if n < 1e-9:
                raise t.error("spin_axis_B", axis.tolist(), "a non-zero direction in body axes")
            axis = axis / n
        else:
            axis = dcm(base.q_SB).T[:, 2]  # the wheel frame's z axis in body axes
        ideal = t.flag("ideal", False)
        if ideal:
            for key in ("coulomb_Nm", "viscous_Nm_s", "static_Nm", "time_constant_s"):
                if t.has(key):
                    raise t.error(key, t.raw(key), "no friction or lag setting with ideal = true; remove it or set "
                                  "ideal = false")
        max_torque = t.number("max_torque_Nm", 4e-3, lo=0.0, lo_open=True, hi=torque_range_Nm[1])
        max_speed = t.number("max_speed_rpm", 6000.0, lo=0.0, lo_open=True,
                             hi=speed_range_rad_s[1] / RPM) * RPM
        coulomb = 0.0 if ideal else t.number("coulomb_Nm", 0.0, lo=0.0, hi=max_torque)
        static = None if ideal or not t.has("static_Nm") else t.number("static_Nm", lo=coulomb, hi=max_torque)
        spec = ReactionWheelSpec(
            **base.__dict__, interface=interface, channel=channel,
            wheel=int(t.number("wheel", 0, lo=0, hi=15, integer=True)),
            spin_axis_B=tuple(float(x) for x in axis),
            inertia_kg_m2=t.number("inertia_kg_m2", 2e-3, lo=1e-7, hi=100.0),
            max_torque_Nm=max_torque, max_speed_rad_s=max_speed,
            coulomb_Nm=coulomb, static_Nm=static,
            viscous_Nm_s=0.0 if ideal else t.number("viscous_Nm_s", 0.0, lo=0.0, hi=1.0),
            time_constant_s=0.0 if ideal else t.number("time_constant_s", 0.0, lo=0.0, hi=10.0),
            speed0_rad_s=t.number("speed0_rpm", 0.0, lo=-max_speed / RPM, hi=max_speed / RPM) * RPM,
            telemetry_rate_hz=rate(t, "telemetry_rate_hz", step_s, min(10.0, 1.0 / step_s)),
            ideal=ideal,
        )
        t.check_unknown()
        return spec

    def momentum_wheel(self, spec: ReactionWheelSpec):
        return np.array(spec.spin_axis_B), spec.inertia_kg_m2, spec.speed0_rad_s

    def datasheet(self, spec: ReactionWheelSpec) -> dict:
        # The rating and the rotor; friction and lag are the simulated unit's.
        return {"spin_axis_B": spec.spin_axis_B, "inertia_kg_m2": spec.inertia_kg_m2,
                "max_torque_Nm": spec.max_torque_Nm, "max_speed_rad_s": spec.max_speed_rad_s,
                "telemetry_rate_hz": spec.telemetry_rate_hz, "wheel": spec.wheel}

    def describe(self, spec) -> str:
        where = f"CAN {spec.interface}:{spec.channel} node {spec.wheel}"
        axis = ", ".join(f"{x:.3f}" for x in spec.spin_axis_B)
        motor = "ideal motor" if spec.ideal else (f"friction {spec.coulomb_Nm:g} N m + {spec.viscous_Nm_s:g} N m s, "
                                                  f"lag {spec.time_constant_s:g} s")
        what = (f"spin axis [{axis}] B, J {spec.inertia_kg_m2:g} kg m^2, {spec.max_torque_Nm:g} N m, "
                f"{spec.max_speed_rad_s / RPM:g} rpm, {motor}")
        return {"emulated": f"reaction wheel emulated on {where}, {what}",
                "hardware": f"reaction wheel on {where} (hardware: the truth gets the motor torque it reports), {what}",
                "served": f"reaction wheel served on {where} for a flight computer outside, {what}"}[spec.link]

    def fault_taps(self, spec: ReactionWheelSpec) -> dict:
        return fault_taps(spec.link, "wheel", medium="can")

    def build(self, spec: ReactionWheelSpec, ctx: BuildContext) -> Device:
        return {"emulated": EmulatedWheel, "hardware": HardwareWheel, "served": ServedWheel}[spec.link](spec, ctx)

    def plots(self, tel, name, out_dir, criteria) -> list[str]:
        # lazy: the figures load matplotlib, which only drawing a report needs
        from stand.devices.reaction_wheel_plots import plot_wheel

        return [plot_wheel(tel, out_dir, name)]


class WheelFaults:
    """The wheel's physics faults as one object (``Device.fault_tap("wheel")``): ``friction_scale``, ``seized``,
    ``torque_scale`` and ``motor_on`` are the motor model's (:class:`sim.actuators.WheelMotor`),
    ``speed_sensor_failed`` the emulator's (:class:`drivers.reaction_wheel.emulator.ReactionWheelEmulator`)."""

    MOTOR = ("friction_scale", "seized", "torque_scale", "motor_on")

    def __init__(self, motor, emulator):
        object.__setattr__(self, "_motor", motor)
        object.__setattr__(self, "_emulator", emulator)

    def __getattr__(self, name):
        if name in WheelFaults.MOTOR:
            return getattr(self._motor, name)
        if name == "speed_sensor_failed":
            return self._emulator.speed_sensor_failed
        raise AttributeError(f"a wheel has no fault attribute {name!r}; it has {', '.join(WheelFaults.MOTOR)}, "
                             "speed_sensor_failed")

    def __setattr__(self, name, value):
        if name in WheelFaults.MOTOR:
            setattr(self._motor, name, value)
        elif name == "speed_sensor_failed":
            self._emulator.speed_sensor_failed = bool(value)
        else:
            self.__getattr__(name)  # the same refusal, naming what a wheel has


def motor_of(spec: ReactionWheelSpec):
    from sim.actuators import ReactionWheel, WheelMotor

    rotor = ReactionWheel(spec.inertia_kg_m2, spec.coulomb_Nm, spec.viscous_Nm_s, spec.static_Nm)
    return WheelMotor(rotor, spec.max_torque_Nm, spec.max_speed_rad_s, spec.time_constant_s)


class _Wheel(Device):

    def __init__(self, spec: ReactionWheelSpec, ctx: BuildContext):
        self.name, self.spec = spec.name, spec
        self.truth = ctx.truth
        self.h_s = ctx.step_s
        self.wheel_index = ctx.wheels[spec.name]
        self.silent_after_s = SILENT_PERIODS / spec.telemetry_rate_hz
        self.host = None
        self.emulator = None
        self._buses: list = []
        self._tau = 0.0  # net torque on the rotor over the next step
        self._motor_tau = 0.0  # the motor's torque now (its lag state)
        self._cmd = 0.0
        self._mode = MODE_CODES["TORQUE"]
        self.energy_friction_J = 0.0
        #: The link as the stand sees it beside the flight code (the host's CAN node, through its listener hook);
        #: telemetry reads only this.
        self.observer = FrameObserver()

    def speed_rad_s(self) -> float:
        return self.truth.wheel_speeds_rad_s[self.wheel_index]

    def fault_tap(self, name: str):
        """``"wheel"``: the :class:`WheelFaults` of an emulated or served wheel; None for any other tap, or on a real
        wheel (stand.faults then looks where a kind's taps conventionally are)."""
        if name == "wheel" and self.emulator is not None and getattr(self, "motor", None) is not None:
            return WheelFaults(self.motor, self.emulator)
        return None

    def columns(self):
        n = self.name
        return [(f"{n}.speed_rad_s", 1, "rad/s"), (f"{n}.mode", 1, "1"), (f"{n}.torque_cmd_Nm", 1, "N m"),
                (f"{n}.motor_torque_Nm", 1, "N m"), (f"{n}.net_torque_Nm", 1, "N m")]

    def row(self):
        # The truth's tuple read directly (speed_rad_s() is the same read one call further away; every wheel reads
        # its speed three times a tick: telemetry, motor, row).
        return (self.truth.wheel_speeds_rad_s[self.wheel_index], self._mode, self._cmd, self._motor_tau, self._tau)

    def wheel_torque_Nm(self) -> float:
        return self._tau

    def effects(self):
        return (Effect("momentum_exchange", self.wheel_torque_Nm, self.wheel_index),)

    def _source(self, _t_s):
        return self.truth.wheel_speeds_rad_s[self.wheel_index], self._motor_tau

    def _step_motor(self, cmd) -> None:
        """One dynamics step of the motor under the held command, from the truth's wheel speed."""
        w0 = self.truth.wheel_speeds_rad_s[self.wheel_index]
        mode = cmd.mode
        # Two dict operations rather than a call of dict.get (every wheel, every tick).
        self._mode = MODE_CODES[mode] if mode in MODE_CODES else -1.0
        # The motor's state (sim.actuators.WheelState) as a plain pair: speed, motor torque now.
        if mode == "SPEED":
            self._cmd = cmd.speed_rad_s
            state, body, friction = self.motor.step_speed((w0, self._motor_tau), cmd.speed_rad_s, self.h_s)
        else:
            tau0 = 0.0 if mode == "IDLE" else self._motor_tau  # IDLE: motor off, the rotor coasts on its friction
            self._cmd = cmd.torque_Nm
            state, body, friction = self.motor.step((w0, tau0), cmd.torque_Nm, self.h_s)
        self._motor_tau = state.motor_torque_Nm
        self._tau = -body  # the rotor gets what the body gives up: motor minus friction
        self.energy_friction_J += friction

    def summary(self):
        out = {"speed_end_rpm": round(self.speed_rad_s() / RPM, 3),
               "friction_energy_J": round(self.energy_friction_J, 9)}
        if self.host is not None:
            out["observed_samples"] = self.observer.count(WheelSpeed)
            out["host_counters"] = dict(self.host.counters)
        if self.emulator is not None:
            out["emulator_counters"] = dict(self.emulator.counters)
        return out

    def close(self):
        for endpoint in (self.host, self.emulator):
            if endpoint is not None:
                endpoint.close()
        for b in self._buses:
            b.shutdown()
        self._buses = []


def _emulator(spec: ReactionWheelSpec, bus, source):
    from drivers.reaction_wheel.emulator import ReactionWheelEmulator, WheelEmulatorConfig

    cfg = WheelEmulatorConfig(max_torque_Nm=spec.max_torque_Nm, max_speed_rad_s=spec.max_speed_rad_s,
                              telemetry_period_s=1.0 / spec.telemetry_rate_hz)
    return ReactionWheelEmulator(bus, source, cfg, wheel=spec.wheel, name=f"{spec.name} emulator")


class EmulatedWheel(_Wheel):
    def __init__(self, spec: ReactionWheelSpec, ctx: BuildContext):
        from drivers.can_bus import open_bus
        from drivers.reaction_wheel.host import ReactionWheelHost

        super().__init__(spec, ctx)
        self.motor = motor_of(spec)
        try:
            self._buses.append(open_bus(spec.interface, spec.channel))
            self._buses.append(open_bus(spec.interface, spec.channel))
            self.emulator = _emulator(spec, self._buses[0], self._source)
            self.host = ReactionWheelHost(self._buses[1], spec.wheel, name=spec.name)
            self.host.add_observer(self.observer)
        except BaseException:
            self.close()
            raise

    def publish(self, t_s):
        self.emulator.publish(t_s)
        # Move what reached the stand through the host's CAN node, read by the flight code or not (take_speed stays
        # theirs); the observer beside it sees every frame.
        self.host.poll()

    def receive(self, t_s):
        self.emulator.receive(t_s)
        self._step_motor(self.emulator.command_at(t_s))

    def activity(self):
        return self.observer.count(WheelSpeed)


class ServedWheel(ServedCan, _Wheel):
    """The emulator on a real adapter for a flight computer outside. What the flight computer sends that the wheel
    cannot decode is counted and dropped (:class:`drivers.can_bus.ServedBus`)."""

    def __init__(self, spec: ReactionWheelSpec, ctx: BuildContext):
        from drivers.reaction_wheel.codec import ReactionWheelCodec

        super().__init__(spec, ctx)
        self.motor = motor_of(spec)
        self._open_served(spec, ReactionWheelCodec(spec.wheel).wheel_tx_ids,
                          lambda link: _emulator(spec, link, self._source))

    def receive(self, t_s):
        self.emulator.receive(t_s)
        self._step_motor(self.emulator.command_at(t_s))
        self.rejections.check(t_s)

    def summary(self):
        out = _Wheel.summary(self)  # the wheel's own, not ServedCan's
        out["emulator_counters"].update(self.link.counters)
        out["rejected_frames"] = self.served.rejected_frames()
        return out


class HardwareWheel(_Wheel):
    """The host on a real wheel: the truth's rotor is driven by the motor torque the wheel reports."""

    def __init__(self, spec: ReactionWheelSpec, ctx: BuildContext):
        from drivers.can_bus import open_device_bus
        from drivers.reaction_wheel.host import ReactionWheelHost

        super().__init__(spec, ctx)
        self._buses.append(open_device_bus(spec.interface, spec.channel))
        self.host = ReactionWheelHost(self._buses[0], spec.wheel, name=spec.name)
        self.host.add_observer(self.observer)

    def publish(self, t_s):
        self.host.poll()

    def receive(self, t_s):
        self.host.poll()
        s = self.observer.latest(WheelSpeed)
        if s is not None:
            self._motor_tau = self._tau = s.torque_Nm
        st = self.observer.latest(WheelStatus)
        if st is not None:
            self._mode = MODE_CODES.get(st.mode, -1.0)

    def activity(self):
        return self.observer.count(WheelSpeed)


KIND = ReactionWheelKind()


# -- how `stand emulate reaction-wheel` serves it -----------------------------------------------------------------

def _serve(args, fail) -> int:
    """One reaction wheel on a python-can bus in wall time, reporting a fixed speed (open loop: no rotor model)."""
    from drivers.reaction_wheel.codec import ReactionWheelCodec
    from drivers.reaction_wheel.emulator import ReactionWheelEmulator

    if not 0 <= args.wheel <= 15:
        return fail(f"--wheel {args.wheel!r} is not allowed; give a wheel number from 0 to 15.")
    if not math.isfinite(args.speed_rad_s):
        return fail(f"--speed-rad-s {args.speed_rad_s!r} is not allowed; give a finite number of rad/s.")
    speed = args.speed_rad_s
    return serve_can(args, fail, f"reaction wheel {args.wheel}", ReactionWheelCodec(args.wheel).wheel_tx_ids,
                     lambda bus: ReactionWheelEmulator(bus, lambda _t: speed, wheel=args.wheel, owns_bus=True))


KIND.serving = can_serving(
    "One reaction wheel (node 0x20 + wheel number) on a CAN bus.", "reaction wheel", _serve,
    (ServeOption("--wheel", "wheel number, 0 to 15 (default 0)", 0, int),
     ServeOption("--speed-rad-s", "open loop: the rotor speed it reports, rad/s (default 0)", 0.0, float)))
