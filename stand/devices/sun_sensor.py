"""Sun sensors in the loop: sampled from the truth through ``sim.sensors`` at their own rate.

The Sun direction comes from the scene's Sun track, the visible fraction of its disk from the
conical shadow model, so eclipse and penumbra dim the coarse heads and invalidate the fine sensor.
There is no device protocol for them yet: the stand records their readings in the telemetry
(``NAME.currents`` or ``NAME.angles`` and ``NAME.valid``, with ``NAME.sun_fraction``) for the
ADCS under test or for post-analysis.
"""

from __future__ import annotations

import math

import numpy as np

from sim.environment import shadow_fraction
from sim.rotations import dcm
from sim.sensors import CoarseSunSensors, FineSunSensor
from sim.truth import rotate_to_body

#: Coarse heads on the six body faces (+x, -x, +y, -y, +z, -z), rotated by the mount.
FACE_NORMALS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)


class SunSensorLink:
    def __init__(self, spec, truth, sun_track, rng: np.random.Generator):
        self.name = spec.name
        self.spec = spec
        self.truth = truth
        self.sun = sun_track
        self.rng = rng
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

    def step(self, t_s: float) -> None:
        r = np.array(self.truth.r_N)
        r_sun = self.sun.position_gcrs(t_s)
        d = r_sun - r
        s_B = np.array(rotate_to_body(self.truth.q, tuple(d / np.linalg.norm(d))))
        nu = float(shadow_fraction(r, r_sun))
        self.samples += 1
        self.eclipsed += nu < 1.0
        if self.spec.type == "coarse":
            currents = self.model.measure(s_B, nu, self.rng)
            self.last = (*currents.tolist(), float(nu > 0.0), nu)
        else:
            angles, valid = self.model.measure(s_B, nu, self.rng)
            self.last = (*angles.tolist(), float(valid), nu)

    def summary(self) -> dict:
        return {"samples": self.samples, "samples_in_shadow_or_penumbra": int(self.eclipsed)}
