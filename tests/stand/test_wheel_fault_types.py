"""Each wheel fault type of a scenario's ``[[faults]]`` on a run of one emulated wheel (issue 24): its effect on the
truth (the rotor's speed and the torques the motor model gives it) or on the wire (the RW_SPEED_TLM the stand
observes), and the rows before the fault, and a run without it, the same to the bit."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from drivers.reaction_wheel.codec import WheelSpeed
from stand import scenario, telemetry
from stand.compose import build
from stand.loop import run

_channel = itertools.count()
AT_S = 2.0
U_NM = 2e-3  # the held torque command
COULOMB, VISCOUS = 1e-4, 2e-6


def _run(scenario_dict, write_scenario, tmp_path, fault: dict | None):
    data = dict(scenario_dict)
    data["scenario"] = {**data["scenario"], "duration_s": 5.0}
    data["dynamics"] = {**data["dynamics"], "torques": []}
    data["spacecraft"] = {**data["spacecraft"], "omega_BN_B_deg_s": [0.0, 0.0, 0.0],
                          "inertia_kg_m2": [[1.2, 0.0, 0.0], [0.0, 1.5, 0.0], [0.0, 0.0, 1.0]]}
    data["devices"] = [{"name": "rw", "kind": "reaction_wheel", "spin_axis_B": [0, 0, 1], "inertia_kg_m2": 2e-3,
                        "max_torque_Nm": 0.01, "coulomb_Nm": COULOMB, "viscous_Nm_s": VISCOUS, "speed0_rpm": 300.0,
                        "channel": f"test-wf-{next(_channel)}"}]
    data["controller"] = {"kind": "none"}
    data["criteria"] = []
    data.pop("environment", None)
    if fault is not None:
        data["faults"] = [{"name": "f", "device": "rw", "at_s": AT_S, **fault}]
    name = fault["type"] if fault else "none"
    sc = scenario.load(write_scenario(data, f"{name}.toml"))
    with build(sc) as scene:
        scene.devices["rw"].host.command_torque(U_NM)  # held (no timeout) through the run
        result = run(scene, tmp_path / name)
        last = scene.devices["rw"].observer.latest(WheelSpeed)
    assert result.status == "completed"
    return telemetry.load(tmp_path / name), last


@pytest.fixture
def nominal(scenario_dict, write_scenario, tmp_path):
    return _run(scenario_dict, write_scenario, tmp_path, None)


@pytest.mark.parametrize("fault", [
    {"type": "wheel_seized"}, {"type": "wheel_torque_loss", "lost_fraction": 0.75}, {"type": "wheel_motor_off"},
    {"type": "wheel_friction_rise", "factor": 20.0}, {"type": "wheel_speed_sensor_failure"}])
def test_each_wheel_fault_acts_from_its_start_and_leaves_the_rows_before_it_alone(fault, nominal, scenario_dict,
                                                                                   write_scenario, tmp_path):
    tel0, last0 = nominal
    tel, last = _run(scenario_dict, write_scenario, tmp_path, fault)
    t = tel["t_s"]
    before, after = t <= AT_S - 1e-9, t >= AT_S + 0.5
    for name in tel0:
        assert tel[name][before].tobytes() == tel0[name][before].tobytes(), name
    w, w0 = tel["rw.speed_rad_s"], tel0["rw.speed_rad_s"]
    after[-1] = False  # each row's net torque acts over the step to the next row: its friction at the mean speed
    k = np.nonzero(after)[0]
    motor, net, w_mean = tel["rw.motor_torque_Nm"][k], tel["rw.net_torque_Nm"][k], 0.5 * (w[k] + w[k + 1])
    kind = fault["type"]
    if kind == "wheel_seized":
        # Stopped relative to the body: what the body's own spin-up within a step leaves falls by J / I_z = 2e-3 a step.
        assert np.all(np.abs(w[after]) < 1e-4) and np.all(w[t >= AT_S + 1.5] == 0.0) and w0[-1] > 30.0
        # No external torque: the body (1.0 kg m^2 about z, wheel included) took all the rotor's first momentum.
        assert tel["omega_BN_B"][-1, 2] == pytest.approx(2e-3 * 300.0 * np.pi / 30.0 / 1.0, rel=1e-6)
    elif kind == "wheel_torque_loss":
        np.testing.assert_allclose(motor, 0.25 * U_NM, rtol=1e-9)
        np.testing.assert_allclose(net, 0.25 * U_NM - COULOMB - VISCOUS * w_mean, rtol=0, atol=1e-8)
    elif kind == "wheel_motor_off":
        assert np.all(motor == 0.0)
        np.testing.assert_allclose(net, -COULOMB - VISCOUS * w_mean, rtol=0, atol=1e-8)  # friction alone
    elif kind == "wheel_friction_rise":
        # 1e-8 N m: the friction at the mean of the two rows' speeds against the exact exponential (2.2e-9 measured).
        np.testing.assert_allclose(net, U_NM - 20.0 * (COULOMB + VISCOUS * w_mean), rtol=0, atol=1e-8)
    else:  # the speed sensor: the truth runs on, the wire says 0 and not valid
        assert tel["rw.speed_rad_s"].tobytes() == tel0["rw.speed_rad_s"].tobytes()
        assert last0.valid and last0.speed_rad_s > 30.0
        assert not last.valid and last.speed_rad_s == 0.0
