"""The fault types: name -> what a fault of that type needs (a tap), takes (parameters) and does (start, stop).

Three layers (docs/faults.md has the table of which kind offers which tap):

* ``physics``: the device itself (a sensor's measurement, a wheel's motor and bearing, a tracker's solution,
  a magnetorquer's coils, a cage's coil pairs), in its emulator or model;
* ``protocol``: the line or bus (frames dropped, corrupted, cut, delayed, reordered, duplicated, a babbling node,
  silence, CAN error frames) and the device's reboot;
* ``time``: the device clock that stamps its messages (a jump, a drift).

A type's ``start(tap, p, a)`` acts on the tap with the parameters ``p`` (SI, validated) and the activation ``a``
(:class:`Activation`: sim time, the fault's own random stream, the tap's size and unit) and returns a handle;
``stop(tap, handle, a)`` undoes exactly that.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sim import sensor_faults as T

DEG = math.pi / 180.0
AXES = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class Param:
    """One parameter of a fault type. ``key`` may hold ``{unit}``: the measurement's unit key of the device (gyro
    ``rad_s``, magnetometer ``T``...). ``shape``: ``number``, ``vector`` (one per measured axis), ``axis`` (an index
    or x/y/z), ``choice``. ``scale`` converts the scenario's unit to SI."""

    key: str
    shape: str
    default: Any
    text: str
    lo: float | None = None
    hi: float | None = None
    options: tuple = ()
    scale: float = 1.0


@dataclass
class Activation:
    """What a fault type's start and stop get besides the tap: when, the fault's own seeded random stream, the
    device's declared tap details (``n``, ``unit``) and scratch space kept between start and stop."""

    t_s: float
    rng: np.random.Generator
    info: dict
    keep: dict = field(default_factory=dict)


@dataclass(frozen=True)
class FaultType:
    name: str
    layer: str
    tap: str
    text: str
    params: tuple[Param, ...]
    start: Any
    stop: Any
    #: A fault that happens at an instant (a reboot, a clock jump): ``duration_s`` is refused.
    instant: bool = False


# -- measurement (physics, any sensor with a measurement tap) ----------------------------------------------------

def _vec(p, key, n):
    v = p[key]
    return tuple(float(x) for x in v) if isinstance(v, list | tuple) else (float(v),) * n


def _add(make):
    def start(tap, p, a):
        f = make(p, a)
        tap.add(f)
        return f
    return start


def _remove(tap, f, a):
    tap.remove(f)


def _measurement(name, text, params, make):
    return FaultType(name, "physics", "measurement", text, params, _add(make), _remove)


MEASUREMENT = (
    _measurement("stuck", "the output holds the last value it had when the fault began", (),
                 lambda p, a: T.stuck([])),
    _measurement("bias_step", "a constant bias is added to every axis", (
        Param("bias_{unit}", "vector", None, "the bias step per axis, in the measurement's unit"),),
        lambda p, a: T.bias(_vec(p, "bias_{unit}", a.info["n"]))),
    _measurement("bias_drift", "a bias that grows linearly from zero at the fault's start", (
        Param("drift_{unit}_per_s", "vector", None, "the drift rate per axis, measurement unit per second"),),
        lambda p, a: T.bias((0.0,) * a.info["n"], _vec(p, "drift_{unit}_per_s", a.info["n"]), a.t_s)),
    _measurement("scale_factor", "the output is multiplied by a factor per axis (1 = nominal)", (
        Param("factor", "vector", None, "the factor per axis (a number applies to every axis)", -100.0, 100.0),),
        lambda p, a: T.scale(_vec(p, "factor", a.info["n"]))),
    _measurement("noise_increase", "white noise added on top of the sensor's own, from the fault's seeded stream", (
        Param("sigma_{unit}", "number", None, "one-sigma of the added noise per sample, measurement unit", 0.0),),
        lambda p, a: T.noise(p["sigma_{unit}"], a.rng, a.info["n"])),
    _measurement("saturation", "the output is clamped to +-limit on each axis", (
        Param("limit_{unit}", "number", None, "the clamp, measurement unit", 0.0),),
        lambda p, a: T.saturate(p["limit_{unit}"])),
    _measurement("dead_axis", "one axis (or head) reads zero", (
        Param("axis", "axis", None, "the dead axis or head: an index from 0, or x, y, z"),),
        lambda p, a: T.dead(p["axis"])),
)


# -- attributes of an emulator or model (physics of one kind) -----------------------------------------------------

def _set(attr, value_of):
    """A fault that sets ``attr`` on the tap for its duration (the previous value comes back at the stop)."""
    def start(tap, p, a):
        old = getattr(tap, attr)
        setattr(tap, attr, value_of(p, old))
        return old

    def stop(tap, old, a):
        setattr(tap, attr, old)
    return start, stop


def _axis_item(attr, value):
    """A fault on one axis of a per-axis tuple attribute (``coil_gain``...), restored alone at the stop."""
    def start(tap, p, a):
        items = list(getattr(tap, attr))
        axis = p["axis"]
        old = items[axis]
        items[axis] = value
        setattr(tap, attr, tuple(items))
        return axis, old

    def stop(tap, handle, a):
        axis, old = handle
        items = list(getattr(tap, attr))
        items[axis] = old
        setattr(tap, attr, tuple(items))
    return start, stop


def _rotvec(p) -> tuple:
    """The rotation vector (rad) of a fault's ``angle_deg`` (SI by now) about its ``axis_S``."""
    axis = np.asarray(p["axis_S"], dtype=float)
    return tuple(float(x) for x in axis / np.linalg.norm(axis) * p["angle_deg"])


def _kind(name, tap, text, params, start_stop, instant=False):
    return FaultType(name, "physics", tap, text, params, *start_stop, instant=instant)


AXIS = Param("axis", "axis", None, "the axis: an index from 0, or x, y, z")

KIND_PHYSICS = (
    _kind("wheel_friction_rise", "wheel", "the bearing's friction is multiplied by a factor", (
        Param("factor", "number", 10.0, "the friction multiplier", 1.0, 1e6),),
        _set("friction_scale", lambda p, old: p["factor"])),
    _kind("wheel_seized", "wheel", "the rotor seizes: its speed goes to zero and stays there, the momentum goes "
          "to the body", (), _set("seized", lambda p, old: True)),
    _kind("wheel_torque_loss", "wheel", "the motor gives only part of the commanded torque", (
        Param("lost_fraction", "number", 0.5, "the part of the torque lost (1: none produced)", 0.0, 1.0),),
        _set("torque_scale", lambda p, old: 1.0 - p["lost_fraction"])),
    _kind("wheel_motor_off", "wheel", "the motor gives no torque; the bearing's friction still acts", (),
          _set("motor_on", lambda p, old: False)),
    _kind("wheel_speed_sensor_failure", "wheel", "the speed telemetry freezes", (),
          _set("speed_sensor_failed", lambda p, old: True)),
    _kind("tracker_blinded", "tracker", "no valid solution: the Sun or a bright body blinds the tracker", (),
          _set("blinded", lambda p, old: True)),
    _kind("tracker_lost", "tracker", "the tracker reports no solution (lost in space)", (),
          _set("lost", lambda p, old: True)),
    _kind("tracker_misidentified", "tracker", "misidentified stars: the attitude is off by an angle about an axis "
          "and still flagged valid", (
              Param("angle_deg", "number", 1.0, "the error angle", 0.0, 180.0, scale=DEG),
              Param("axis_S", "vector3", [1.0, 0.0, 0.0], "the error's rotation axis, sensor frame")),
          _set("misid_rad", lambda p, old: _rotvec(p))),
    _kind("tracker_slow", "tracker", "solutions come late", (
        Param("delay_s", "number", 0.5, "the extra latency of each solution", 0.0, 60.0),),
        _set("solution_delay_s", lambda p, old: p["delay_s"])),
    _kind("coil_open", "coils", "one coil is open: it produces no dipole", (AXIS,), _axis_item("coil_gain", 0.0)),
    _kind("coil_reversed", "coils", "one coil's polarity is reversed", (AXIS,), _axis_item("coil_gain", -1.0)),
    _kind("coil_stuck_on", "coils", "one coil holds its largest dipole whatever is commanded", (AXIS,),
          _axis_item("stuck_on_axes", True)),
    _kind("cage_coil_failure", "cage", "one coil pair of the cage produces no field", (AXIS,),
          _axis_item("coil_failed", True)),
    # Stimulators: physics faults a real sensor sees (docs/faults.md, "Every link").
    _kind("screen_wrong_attitude", "stimulus", "the star screen shows the sky of an attitude off by an angle about "
          "an axis: a real tracker reports it, valid", (
              Param("angle_deg", "number", 1.0, "the error angle", 0.0, 180.0, scale=DEG),
              Param("axis_S", "vector3", [1.0, 0.0, 0.0], "the error's rotation axis, tracker frame")),
          _set("screen_misid_rad", lambda p, old: _rotvec(p))),
    _kind("cage_field_step", "stimulus", "the Helmholtz cage adds a field step to what it reproduces: the "
          "magnetometer in it reads a bias", (
              Param("step_T", "vector3", None, "the step, body axes"),),
          _set("field_step_B_T", lambda p, old: tuple(p["step_T"]))),
)


# -- protocol (the line or bus) ---------------------------------------------------------------------------------

DIRECTION = Param("direction", "choice", "both", "which way frames are hit", options=("to_host", "to_device", "both"))
PROBABILITY = Param("probability", "number", 0.5, "the chance per frame", 0.0, 1.0)
#: Scenario key -> the link's parameter name (drivers.link_faults).
LINK_KEYS = {"probability": "rate", "frames": "frames", "bits": "bits", "keep_fraction": "keep_fraction",
             "latency_s": "delay_s", "jitter_max_s": "max_s", "frames_per_s": "frames_per_s", "direction": "direction"}


def _link(kind):
    def start(tap, p, a):
        return tap.start(kind, {LINK_KEYS[k]: v for k, v in p.items()}, a.rng, a.t_s)

    def stop(tap, handle, a):
        tap.stop(handle)
    return start, stop


def _protocol(name, kind, text, params):
    return FaultType(name, "protocol", "link", text, (*params, DIRECTION), *_link(kind))


PROTOCOL = (
    _protocol("frame_drop", "drop", "frames are dropped at random", (PROBABILITY,)),
    _protocol("frame_burst_drop", "burst_drop", "a burst of consecutive frames is dropped", (
        Param("frames", "integer", 10, "how many frames in a row", 1, 1e6),)),
    _protocol("bit_error", "bit_error", "bits flip in frames, so the receiver's CRC check fires", (
        PROBABILITY, Param("bits", "integer", 1, "bits flipped per hit frame", 1, 64))),
    _protocol("frame_truncated", "truncate", "frames are cut short", (
        PROBABILITY, Param("keep_fraction", "number", 0.5, "the part of a frame kept", 0.0, 1.0))),
    _protocol("frame_delay", "delay", "every frame arrives late", (
        Param("latency_s", "number", 0.1, "the added latency of every frame", 0.0, 60.0),)),
    _protocol("frame_jitter", "jitter", "frames arrive late by a random extra delay", (
        Param("jitter_max_s", "number", 0.05, "the largest extra delay (uniform)", 0.0, 60.0),)),
    _protocol("frame_reorder", "reorder", "frames swap places with the next one", (PROBABILITY,)),
    _protocol("frame_duplicate", "duplicate", "frames arrive twice", (PROBABILITY,)),
    _protocol("babble", "babble", "a babbling node floods the line or bus with frames", (
        Param("frames_per_s", "number", 1000.0, "frames of the flood per second", 0.0, 1e6),)),
    _protocol("silence", "silence", "nothing gets through", ()),
    _protocol("can_error_frame", "error_frame", "CAN error frames on the bus, where the interface carries them",
              (PROBABILITY,)),
)


def _reboot_start(tap, p, a):
    tap.reboot(a.t_s, boot_s=p["boot_s"])


def _clock(param, key):
    def start(tap, p, a):
        tap.clock_fault(a.t_s, **{key: p[param]})

    def stop(tap, handle, a):
        tap.clear_clock_fault(a.t_s)
    return start, stop


OTHER = (
    FaultType("reboot", "protocol", "reboot", "the device power-cycles: sequence numbers and clock reset, silent "
              "while it boots, a boot message where its ICD has one", (
                  Param("boot_s", "number", 1.0, "how long it is silent while booting", 0.0, 600.0),),
              _reboot_start, lambda tap, h, a: None, instant=True),
    FaultType("clock_jump", "time", "clock", "the device clock jumps: its time tags shift by the jump", (
        Param("jump_s", "number", 1.0, "the jump (negative: back in time)", -1e6, 1e6),), *_clock("jump_s", "jump_s")),
    FaultType("clock_drift", "time", "clock", "the device clock runs fast or slow from the fault's start", (
        Param("drift_ppm", "number", 100.0, "the rate error, parts per million", -1e5, 1e5, scale=1e-6),),
        *_clock("drift_ppm", "drift")),
)

#: Every fault type by name.
FAULT_TYPES: dict[str, FaultType] = {f.name: f for f in (*MEASUREMENT, *KIND_PHYSICS, *PROTOCOL, *OTHER)}
LAYERS = ("physics", "protocol", "time")
