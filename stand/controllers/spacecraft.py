"""What flight code is told of its spacecraft, and how it reports pointing and knowledge back (docs/plugins.md).

A plug-in whose constructor takes a ``spacecraft`` keyword gets a :class:`Spacecraft` built from the scenario:
what a flight team knows from its mass-properties sheet, its drawings (each device's mount) and its devices'
datasheets and ICDs (rates, ranges, ratings; a wheel's spin axis and rotor inertia). Never the simulator's truth:
no initial attitude or rate, no simulated noise, bias or friction. Everything is frozen and in SI units, the unit
named in the field (``inertia_kg_m2``, ``max_torque_Nm``); vectors are tuples, body axes ``_B``; quaternions are
scalar first, ``q_SB`` the device frame relative to the body (docs/conventions.md).

The criteria on pointing and knowledge read telemetry columns the flight code records (``telemetry_columns()``
and ``telemetry()``): :data:`POINTING_COLUMNS` names them, :data:`METRIC_COLUMNS` says which criterion reads
which, and :func:`unwritten` finds a criterion whose columns the controller does not record.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np

from stand.adcs.metrics import ESTIMATE, MODE, REFERENCE, SIGMA3
from stand.devices import get as device_kind

#: The columns the pointing and knowledge criteria read, as ``telemetry_columns()`` declares them:
#: ``(name, width, unit)``. ``adcs_q_BN_est``: the flight code's attitude estimate (body relative to GCRS, scalar
#: first); ``adcs_sigma3_B``: its 3-sigma error per body axis (rad); ``adcs_q_RN``: the commanded (reference)
#: attitude; ``adcs_mode``: the flight code's mode as a number of its own (drawn, never judged). Record NaN while
#: there is no estimate or no reference: those rows are left out of the criteria.
POINTING_COLUMNS = ((ESTIMATE, 4, ""), (SIGMA3, 3, "rad"), (REFERENCE, 4, ""), (MODE, 1, ""))
#: Criterion metric -> the columns it reads (besides the truth's ``q_BN``, which the stand records itself).
METRIC_COLUMNS = {
    "pointing_error_arcsec_p95_after": (REFERENCE,),
    "knowledge_error_arcsec_p95_after": (ESTIMATE,),
    "knowledge_within_3sigma_fraction": (ESTIMATE, SIGMA3),
}


@dataclass(frozen=True)
class DeviceInfo:
    """One device as the flight team knows it.

    ``link``: ``emulated`` or ``hardware`` (its host driver is in ``devices[name]``) or ``served`` (a flight computer
    outside holds it; ``devices[name]`` is None). ``q_SB``: the device frame relative to the body. ``datasheet``: a
    read-only mapping of what the kind declares (``DeviceKind.datasheet``): a gyro's ``output_rate_hz`` and
    ``range_rad_s``, a wheel's ``spin_axis_B``, ``inertia_kg_m2``, ``max_torque_Nm``, ``max_speed_rad_s``, a star
    tracker's ``output_interval_s`` and exclusion angles (``sun_exclusion_rad``...), a magnetorquer's
    ``max_dipole_A_m2``; docs/plugins.md lists each kind's."""

    name: str
    kind: str
    link: str
    q_SB: tuple[float, float, float, float]
    datasheet: MappingProxyType

    def dcm_SB(self) -> np.ndarray:
        """The attitude matrix taking body components to device components (``v_S = dcm_SB() @ v_B``)."""
        from sim.rotations import dcm

        return dcm(np.asarray(self.q_SB, dtype=float))


@dataclass(frozen=True)
class Wheel:
    """A momentum wheel: ``spin_axis_B`` (unit, body axes), ``inertia_kg_m2`` (the rotor about its axis), the
    rating ``max_torque_Nm`` and ``max_speed_rad_s`` (None when its kind declares none). A positive
    ``command_torque`` speeds the rotor up about ``spin_axis_B`` and torques the body by ``-torque * spin_axis_B``."""

    name: str
    spin_axis_B: tuple[float, float, float]
    inertia_kg_m2: float
    max_torque_Nm: float | None
    max_speed_rad_s: float | None


@dataclass(frozen=True)
class Spacecraft:
    """The spacecraft handed to flight code (``ClassName(devices, period_s, spacecraft=..., **options)``).

    ``inertia_kg_m2``: 3 x 3 about the centre of mass in body axes, wheels included (the mass-properties sheet's
    number). ``devices``: name -> :class:`DeviceInfo`, every device of the scenario in its order. ``wheels``: the
    momentum wheels in that order. ``epoch_iso``: UTC at t = 0 (sim time ``t_s`` counts from it);
    ``orbit_r_N_m``, ``orbit_v_N_m_s``: the orbit at t = 0 in GCRS, as a ground station's orbit determination
    would uplink it (propagating it is the flight code's business)."""

    scenario: str
    mass_kg: float
    inertia_kg_m2: tuple[tuple[float, float, float], ...]
    devices: MappingProxyType
    wheels: tuple[Wheel, ...]
    epoch_iso: str
    orbit_r_N_m: tuple[float, float, float]
    orbit_v_N_m_s: tuple[float, float, float]

    def device(self, name: str) -> DeviceInfo:
        """The device called ``name`` (KeyError naming those there are)."""
        try:
            return self.devices[name]
        except KeyError:
            raise KeyError(f"no device {name!r} in scenario {self.scenario!r}; there are: "
                           f"{', '.join(self.devices) or 'none'}") from None

    def of_kind(self, kind: str) -> tuple[DeviceInfo, ...]:
        """The devices of one kind (``"gyro"``, ``"star_tracker"``...), in the scenario's order."""
        return tuple(d for d in self.devices.values() if d.kind == kind)

    def wheel_axes_B(self) -> np.ndarray:
        """The wheels' spin axes as the columns of a 3 x n matrix (``A``: the body torque is ``-A @ torques``)."""
        return np.array([w.spin_axis_B for w in self.wheels], dtype=float).reshape(-1, 3).T


def _floats(x) -> tuple:
    return tuple(float(v) for v in np.asarray(x, dtype=float).ravel())


def _frozen(value: Any) -> Any:
    """A datasheet value made immutable: arrays and lists become tuples of floats."""
    if isinstance(value, np.ndarray | list | tuple):
        return tuple(_frozen(v) for v in value)
    if isinstance(value, np.floating | np.integer):
        return value.item()
    return value


def spacecraft_of(scenario) -> Spacecraft:
    """The :class:`Spacecraft` of a parsed scenario (:class:`stand.scenario.Scenario`)."""
    infos, wheels = {}, []
    for spec in scenario.devices:
        kind = device_kind(spec.kind)
        # A kind of a bench's own that predates the hook declares nothing beyond the mount.
        sheet = {k: _frozen(v) for k, v in (getattr(kind, "datasheet", None) or (lambda _s: {}))(spec).items()}
        infos[spec.name] = DeviceInfo(spec.name, spec.kind, spec.link, _floats(spec.q_SB), MappingProxyType(sheet))
        wheel = kind.momentum_wheel(spec) if hasattr(kind, "momentum_wheel") else None
        if wheel is not None:
            axis, inertia, _speed0 = wheel  # the initial speed is the truth's, not the flight team's
            wheels.append(Wheel(spec.name, _floats(axis), float(inertia), sheet.get("max_torque_Nm"),
                                sheet.get("max_speed_rad_s")))
    r, v = scenario.orbit.initial_state()
    inertia = np.asarray(scenario.spacecraft.inertia_kg_m2, dtype=float)
    return Spacecraft(scenario.name, float(scenario.spacecraft.mass_kg), tuple(_floats(row) for row in inertia),
                      MappingProxyType(infos), tuple(wheels), scenario.epoch.iso, _floats(r), _floats(v))


def unwritten(criteria, columns) -> list[tuple[str, str, tuple[str, ...]]]:
    """``(criterion name, metric, missing columns)`` of every criterion that reads a column (:data:`METRIC_COLUMNS`)
    the controller does not record (``columns``: the names it declares)."""
    have = set(columns)
    out = []
    for c in criteria:
        missing = tuple(col for col in METRIC_COLUMNS.get(c.metric, ()) if col not in have)
        if missing:
            out.append((c.name, c.metric, missing))
    return out


def unwritten_text(problems, who: str) -> str:
    """One sentence for :func:`unwritten`'s list: which criterion reads which column that ``who`` does not record."""
    parts = [f"criterion {name!r} ({metric}) reads {', '.join(missing)}" for name, metric, missing in problems]
    return (f"{'; '.join(parts)}, which {who} does not record: nothing would write "
            f"{'it' if sum(len(p[2]) for p in problems) == 1 else 'them'}, so the criterion could never be computed "
            "(a plug-in records them through telemetry_columns() and telemetry(), docs/plugins.md; or remove the "
            "criterion).")
