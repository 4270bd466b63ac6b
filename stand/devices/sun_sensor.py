"""Sun sensors: sampled from the truth through ``sim.sensors`` at their own rate.

The Sun direction comes from the scene's Sun track, the visible fraction of its disk from the conical shadow
model, so eclipse and penumbra dim the coarse heads and invalidate the fine sensor. They have no device protocol
yet (``link = "model"``): the flight code reads them through :class:`SunSensorReader`, a host-side reader with
the shape of a host driver, and the stand records their readings (``NAME.currents`` or ``NAME.angles``,
``NAME.valid``, ``NAME.sun_fraction``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.environment import shadow_fraction
from sim.rotations import dcm
from sim.sensors import CoarseSunSensors, FineSunSensor
from sim.truth import rotate_to_body
from stand.devices import BuildContext, Device, DeviceCost, DeviceKind, DeviceSpec

#: Coarse heads on the six body faces (+x, -x, +y, -y, +z, -z), rotated by the mount.
HEAD_LABELS = ["+x face", "-x face", "+y face", "-y face", "+z face", "-z face"]
FACE_NORMALS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)


@dataclass(frozen=True)
class SunSensorSpec(DeviceSpec):
    type: str = "coarse"  # "coarse" | "fine"
    rate_hz: float = 10.0
    noise: float = 0.0  # coarse: head current noise (A); fine: angle noise (rad)
    fov_half_deg: float = 90.0


@dataclass(frozen=True)
class SunReading:
    """One sun-sensor sample as the flight code gets it: ``currents_A`` (coarse, one per head) or
    ``angles_rad`` (fine, two axes), ``valid`` and the sim time it was taken."""

    time_s: float
    valid: bool
    currents_A: tuple | None = None
    angles_rad: tuple | None = None


class SunSensorReader:
    """The host-side reader of a modelled sun sensor: ``take_sun()`` returns the newest reading once."""

    def __init__(self, name: str):
        self.name = name
        self.latest: SunReading | None = None
        self._taken = True
        self.counters = {"samples": 0}

    def _put(self, reading: SunReading) -> None:
        self.latest, self._taken = reading, False
        self.counters["samples"] += 1

    def take_sun(self) -> SunReading | None:
        if self._taken:
            return None
        self._taken = True
        return self.latest

    def close(self) -> None:
        """Nothing to release: the sensor is a model."""


class SunSensorKind(DeviceKind):
    name = "sun_sensor"
    links = ("model",)
    default_link = "model"

    def parse(self, t, base: DeviceSpec, step_s: float) -> SunSensorSpec:
        from stand.scenario import rate

        kind = t.choice("type", ("coarse", "fine"))
        if kind == "coarse":
            noise = t.number("noise_mA", 0.0, lo=0.0, hi=10.0) * 1e-3
        else:
            noise = math.radians(t.number("noise_deg", 0.0, lo=0.0, hi=10.0))
        # Coarse heads default to the bare cosine law (a 90 deg half-field); a fine sensor to 60 deg.
        fov = t.number("fov_half_deg", 90.0, lo=1.0, hi=90.0) if kind == "coarse" else \
            t.number("fov_half_deg", 60.0, lo=1.0, hi=89.0)
        spec = SunSensorSpec(**base.__dict__, type=kind, rate_hz=rate(t, "rate_hz", step_s, 1.0 / step_s),
                             noise=noise, fov_half_deg=fov)
        t.check_unknown()
        return spec

    def needs(self, spec) -> dict[str, str]:
        why = f"sun sensor {spec.name}"
        return {"sun": why, "eclipse": why}

    def describe(self, spec) -> str:
        return f"{spec.type} sun sensor sampled from the truth at {spec.rate_hz:g} Hz, eclipse-aware (no bus)"

    def cost(self, spec: SunSensorSpec) -> DeviceCost:
        # A sample evaluates the Sun's position and the Earth's shadow: about 50 us.
        return DeviceCost(rate_hz=spec.rate_hz, row_floats=(len(FACE_NORMALS) if spec.type == "coarse" else 2) + 2,
                          publish_s=50e-6)

    def build(self, spec: SunSensorSpec, ctx: BuildContext) -> Device:
        return SunSensor(spec, ctx)

    def plots(self, tel, name, out_dir, criteria) -> list[str]:
        from stand.plots import plot_sun_sensor

        return [plot_sun_sensor(tel, out_dir, name, head_labels=HEAD_LABELS if f"{name}.currents" in tel else None)]


class SunSensor(Device):
    def __init__(self, spec: SunSensorSpec, ctx: BuildContext):
        from stand.compose import ticks_per

        self.name, self.spec = spec.name, spec
        self.truth = ctx.truth
        self.sun = ctx.tracks["sun"]
        self.rng = ctx.rng
        self.every_ticks = ticks_per(spec.rate_hz, ctx.step_s)
        self.host = SunSensorReader(spec.name)
        dcm_SB = dcm(spec.q_SB)
        if spec.type == "coarse":
            self.model = CoarseSunSensors(FACE_NORMALS @ dcm_SB, noise_A=spec.noise, cutoff_deg=spec.fov_half_deg)
            self.width = len(FACE_NORMALS)
        else:
            self.model = FineSunSensor(dcm_SB, fov_half_deg=spec.fov_half_deg, noise_rad=spec.noise)
            self.width = 2
        self.samples = 0
        self.eclipsed = 0
        self.last = (math.nan,) * (self.width + 2)

    def columns(self) -> list[tuple[str, int, str]]:
        reading = (f"{self.name}.currents", self.width, "A") if self.spec.type == "coarse" else \
            (f"{self.name}.angles", 2, "rad")
        return [reading, (f"{self.name}.valid", 1, "1"), (f"{self.name}.sun_fraction", 1, "1")]

    def publish(self, t_s: float) -> None:
        r = np.array(self.truth.r_N)
        r_sun = self.sun.position_gcrs(t_s)
        d = r_sun - r
        s_B = np.array(rotate_to_body(self.truth.q, tuple(d / np.linalg.norm(d))))
        nu = float(shadow_fraction(r, r_sun))
        self.samples += 1
        self.eclipsed += nu < 1.0
        if self.spec.type == "coarse":
            currents = tuple(self.model.measure(s_B, nu, self.rng).tolist())
            valid = nu > 0.0
            self.host._put(SunReading(t_s, valid, currents_A=currents))
            self.last = (*currents, float(valid), nu)
        else:
            angles, valid = self.model.measure(s_B, nu, self.rng)
            angles = tuple(angles.tolist())
            self.host._put(SunReading(t_s, bool(valid), angles_rad=angles))
            self.last = (*angles, float(valid), nu)

    def row(self) -> tuple:
        return self.last

    def summary(self) -> dict:
        return {"samples": self.samples, "samples_in_shadow_or_penumbra": int(self.eclipsed)}


KIND = SunSensorKind()
