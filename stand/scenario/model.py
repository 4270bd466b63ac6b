"""The validated scenario: frozen dataclasses in SI units, what every other part of the stand reads."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sim.orbit import elements_to_state
from sim.time import Epoch
from stand.controllers import ControllerSpec
from stand.devices import WALL_TIME_LINKS, DeviceSpec

__all__ = ["ControllerSpec", "Criterion", "EnvironmentSpec", "OrbitSpec", "Scenario", "SpacecraftSpec"]


@dataclass(frozen=True)
class OrbitSpec:
    e: float
    i_rad: float
    raan_rad: float
    argp_rad: float
    a_m: float | None
    p_m: float | None
    nu_rad: float | None
    mean_anomaly_rad: float | None
    gravity: str
    step_s: float
    gravity_degree: int = 20
    third_bodies: tuple[str, ...] = ()
    drag: dict | None = None
    srp: dict | None = None


    def initial_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity at the epoch, GCRS (m, m/s), from the elements."""
        r, v = elements_to_state(e=self.e, i=self.i_rad, raan=self.raan_rad, argp=self.argp_rad, a=self.a_m,
                                 p=self.p_m, nu=self.nu_rad, M=self.mean_anomaly_rad)
        return np.asarray(r, dtype=float), np.asarray(v, dtype=float)


@dataclass(frozen=True)
class SpacecraftSpec:
    mass_kg: float
    inertia_kg_m2: np.ndarray
    q_BN: np.ndarray
    omega_BN_B: np.ndarray


@dataclass(frozen=True)
class EnvironmentSpec:
    magnetic_field: str
    earth_rotation: str
    era0_rad: float
    igrf_degree: int = 13
    eop: str = "iers"


@dataclass(frozen=True)
class Criterion:
    name: str
    metric: str
    max: float | None
    min: float | None
    at_s: float | None


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    source: str
    epoch: Epoch
    duration_s: float
    seed: int
    step_s: float
    integrator: str
    torques: tuple[str, ...]
    orbit: OrbitSpec
    spacecraft: SpacecraftSpec
    environment: EnvironmentSpec
    devices: tuple[DeviceSpec, ...]
    controller: ControllerSpec
    criteria: tuple[Criterion, ...]
    record_rate_hz: float
    #: Optional sections declared in ``stand.scenario.SECTIONS`` that the scenario has: key -> their parsed spec.
    sections: dict[str, Any] = field(default_factory=dict)
    #: ``[[faults]]``: what goes wrong during the run (``stand.faults.FaultSpec``, in the scenario's order).
    faults: tuple = ()

    def device(self, kind: str) -> DeviceSpec | None:
        return next((d for d in self.devices if d.kind == kind), None)

    @property
    def rendezvous(self):
        """The ``[rendezvous]`` section's spec (``stand.rendezvous.RendezvousSpec``), or None without one."""
        return self.sections.get("rendezvous")

    @property
    def wall_time_links(self) -> list[str]:
        """Devices whose other end runs in wall time (hardware and served links): the run must be paced."""
        return [d.name for d in self.devices if d.link in WALL_TIME_LINKS]
