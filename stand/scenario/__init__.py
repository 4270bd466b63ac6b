"""Scenario files: TOML with units in the key names, validated before t = 0.

Every value is checked here, before anything is built, so an impossible run is refused at once
with one sentence naming the field, the value and what is allowed (``ScenarioError``), not at
minute nine. Units are converted to SI on the way in; nothing past this module sees degrees or km.

Layout (see ``fixtures/scenarios/detumble.toml`` for a complete, commented example)::

    [scenario]     name, description, epoch (UTC ISO 8601), duration_s, seed
    [dynamics]     step_s, integrator = "rk4" | "rkmk4" | "implicit_midpoint", torques
    [orbit]        altitude_km | a_km | p_km, e, i_deg, raan_deg, argp_deg, nu_deg | mean_anomaly_deg,
                   gravity = "point" | "j2" | "jgm3", gravity_degree, third_bodies, [orbit.drag], [orbit.srp],
                   step_s
    [spacecraft]   mass_kg, inertia_kg_m2 (3 principal moments or 3x3), q_BN, omega_BN_B_deg_s
    [environment]  magnetic_field = "igrf" | "dipole", igrf_degree, earth_rotation = "iau2006" | "uniform",
                   era0_deg, eop = "iers" | "none"
    [[devices]]    name, kind = "magnetorquer" | "star_tracker" | "sun_sensor" | "cage" | "gyro" | "reaction_wheel",
                   q_SB, and per kind:
                   magnetorquer: interface, channel, sample_rate_hz, max_dipole_A_m2, mag_noise_nT, ...
                   star_tracker: port, source = "truth" | "image", noise_cross_arcsec, fov_deg, ...
                   sun_sensor: type = "coarse" | "fine", port, rate_hz, noise_mA | noise_deg, fov_half_deg, ...
                   gyro: port, output_rate_hz, ideal, arw_deg_sqrt_h, bias_instability_deg_h, delay_s, ...
                   reaction_wheel: interface, channel, wheel, spin_axis_B, inertia_kg_m2, max_torque_Nm, ...
    [controller]   kind = "bdot" | "none" | "plugin" | "external" | "pointing", rate_hz, budget_s, ...
                   (pointing: [controller.options] of stand.adcs.pointing.PointingController, devices by name;
                   [controller.datasheet.NAME] of its star tracker and gyro, datasheet_margin: what its filter is
                   tuned from, never the simulated devices' own noise)
    [[criteria]]   name, metric, max | min, at_s (metrics that take a time only)
    [recording]    rate_hz
    [rendezvous]   shadows on a docking target during an approach (``stand shadow``; see stand.rendezvous, reached
                   through ``SECTIONS``: the loader does not import it)

A key the run would ignore is refused, not accepted: one another setting leaves unused (``era0_deg`` under
``earth_rotation = "iau2006"``, ``eop`` under ``"uniform"``, ``igrf_degree`` under a dipole, ``gravity_degree``
without ``"jgm3"``, an ``[environment]`` setting of a model nothing in the scene evaluates, ``at_s`` of a metric
without a time, a controller key of another kind), because a campaign dispersing it would record different
inputs for identical runs. A required key given without its unit (``duration = 10``) is named as the mistake,
with the key it probably meant. Numbers are finite and of normal size (a subnormal rate has an infinite period).

The package, one job a module: :mod:`.files` finds and reads a file and applies ``--set`` overrides,
:mod:`.loader` parses the sections in turn (devices and controllers through their registries, optional sections
through ``SECTIONS``) and the criteria, :mod:`.physics` validates the orbit, the spacecraft and the environment,
:mod:`.model` holds the frozen dataclasses. The validation helpers (``Table``, ``rate``...) live in the leaf
module :mod:`stand.checks`, which device and controller kinds import instead of this package.
"""

from __future__ import annotations

from stand.checks import CONTROL, KEY_PATTERN, MAX_STEPS_PER_PERIOD, NAME_PATTERN, Table, pair, rate, ticks_per
from stand.controllers import DEFAULT_BUDGET_S

from .files import DEFAULT_SCENARIO, FIXTURES, MAX_FILE_BYTES, SCENARIO_DIR, find, load, loads, set_value, shipped
from .loader import METRIC_UNITS, METRICS, SECTIONS, _device, all_metrics, parse, section
from .model import ControllerSpec, Criterion, EnvironmentSpec, OrbitSpec, Scenario, SpacecraftSpec
from .physics import HILL_KM, MAX_FIELD_T, MAX_INERTIA_KG_M2, TORQUES, earth_models

__all__ = ["CONTROL", "DEFAULT_BUDGET_S", "DEFAULT_SCENARIO", "FIXTURES", "HILL_KM", "KEY_PATTERN", "MAX_FIELD_T",
           "MAX_FILE_BYTES", "MAX_INERTIA_KG_M2", "MAX_STEPS_PER_PERIOD", "METRICS", "METRIC_UNITS", "NAME_PATTERN",
           "SCENARIO_DIR", "SECTIONS", "TORQUES", "ControllerSpec", "Criterion", "EnvironmentSpec", "OrbitSpec",
           "Scenario", "SpacecraftSpec", "Table", "_device", "all_metrics", "earth_models", "find", "load", "loads",
           "pair", "parse", "rate", "section", "set_value", "shipped", "ticks_per"]
