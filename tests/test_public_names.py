"""The Python names docs/public_surface.md promises stay importable (add, do not rename)."""

import importlib

import pytest

PUBLIC = {
    "sim.rotations": ["dcm", "quat_from_dcm", "compose", "conjugate", "quat_from_euler", "euler_from_quat",
                      "quat_from_axis_angle", "axis_angle"],
    "sim.time": ["Epoch"],
    "sim.frames": ["dcm_itrs_gcrs", "dcm_lvlh_gcrs", "dcm_rsw_gcrs", "dcm_esd_gcrs"],
    "sim.orbit": ["solve_kepler", "elements_to_state", "state_to_elements", "propagate_kepler"],
    "sim.environment": ["magnetic_field_itrs", "sun_position_gcrs", "moon_position_gcrs", "shadow_fraction"],
    "sim.attitude": ["propagate"],
    "stand.telemetry": ["load"],
    "stand.campaign": ["parse_dispersions", "case_values", "make_spec", "run_campaign", "aggregate", "load_case",
                       "run_case"],
}


@pytest.mark.parametrize("module", sorted(PUBLIC))
def test_design_names_are_importable(module):
    mod = importlib.import_module(module)
    missing = [name for name in PUBLIC[module] if not callable(getattr(mod, name, None))]
    assert not missing, f"{module} lacks {missing}"


def test_design_commands_exist():
    from stand.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    assert {"run", "check", "screen", "bench", "emulate"} <= set(sub.choices)
