"""Kinds declare, the core iterates (issue 23, Build item 2): a kind the stand does not ship acts on the truth
through the one effector interface, and the core modules (loop, truth, report, plots, view, telemetry) name no
shipped kind."""

from __future__ import annotations

import ast
import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from sim.effects import EFFECT_TYPES, Effect
from stand import devices, telemetry
from stand.compose import build
from stand.loop import run
from stand.scenario import parse

from .test_gyro_wheel_links import small_scenario

ROOT = Path(__file__).resolve().parents[2]
#: The core: it iterates over what kinds declare and names none of them.
CORE = ["stand/loop.py", "sim/truth.py", "stand/report.py", "stand/plots.py", "stand/telemetry.py",
        *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "stand" / "view").glob("*.py"))]
INERTIA = (0.02, 0.03, 0.01)  # kg m^2, principal axes = body axes


@dataclass(frozen=True)
class RigSpec(devices.DeviceSpec):
    torque_B_Nm: tuple = (0.0, 0.0, 0.0)


class _TorqueRig(devices.DeviceKind):
    """A test rig's torque motor, a kind of an installed package: a constant torque on the body."""

    name = "torque_rig"
    actuates = ("torque",)
    column_meanings = {"torque_B": "the torque the rig applies to the body, body axes"}

    def parse(self, t, base, step_s):
        return RigSpec(**vars(base), torque_B_Nm=tuple(float(x) for x in t.vector("torque_B_Nm", 3)))

    def build(self, spec, ctx):
        return _Rig(spec)


class _Rig(devices.Device):
    def __init__(self, spec):
        self.name, self.torque = spec.name, spec.torque_B_Nm

    def columns(self):
        return [(f"{self.name}.torque_B", 3, "N m")]

    def row(self):
        return self.torque

    def torque_B(self):
        return self.torque

    def effects(self):
        return (Effect("torque", self.torque_B),)


@pytest.fixture
def torque_rig(monkeypatch):
    kind = _TorqueRig()
    monkeypatch.setattr(devices, "_installed_kinds", lambda: ("torque_rig",))
    monkeypatch.setitem(devices._loaded, "torque_rig", kind)
    return kind


def test_a_kind_not_shipped_turns_the_body_through_the_effector_interface_as_the_closed_form_says(torque_rig,
                                                                                                     tmp_path):
    # Two rigs about the intermediate principal axis, from rest and with no environment torque: the rate grows as
    # d omega = I^-1 (tau1 + tau2) t exactly (omega stays along a principal axis, so omega x I omega = 0, and RK4
    # integrates a constant derivative without error); the other axes stay at rest.
    rigs = [{"name": "rig_a", "kind": "torque_rig", "torque_B_Nm": [0.0, -3e-5, 0.0]},
            {"name": "rig_b", "kind": "torque_rig", "torque_B_Nm": [0.0, 1e-5, 0.0]}]
    data = small_scenario(rigs, 5.0)
    data["spacecraft"].update(inertia_kg_m2=list(INERTIA), omega_BN_B_deg_s=[0.0, 0.0, 0.0])
    scene = build(parse(data, "<test>"))
    try:
        result = run(scene, tmp_path)
    finally:
        scene.close()
    assert result.status == "completed", result.error
    tel = telemetry.load(tmp_path)
    t, w = tel["t_s"], tel["omega_BN_B"]
    assert t[-1] == pytest.approx(5.0)
    np.testing.assert_allclose(w[:, 1], -2e-5 / INERTIA[1] * t, rtol=1e-9, atol=1e-15)
    assert np.all(w[:, [0, 2]] == 0.0)
    # The kind's one-line meaning of its column reaches the telemetry's schema.
    schema = json.loads((tmp_path / "telemetry" / telemetry.SCHEMA).read_text())
    meanings = {c["name"]: c.get("meaning") for c in schema["columns"]}
    assert meanings["rig_a.torque_B"] == "the torque the rig applies to the body, body axes"


class _BrokenRig(_Rig):
    """An effect read through a plain function (not a method of the device) that fails at t >= 0.3 s."""

    def effects(self):
        truth_t = []

        def read():
            truth_t.append(None)
            if len(truth_t) > 3:
                raise ZeroDivisionError("the rig's torque sensor divided by zero")
            return self.torque

        return (Effect("torque", read),)


def test_an_effect_that_fails_is_blamed_on_its_device(torque_rig, tmp_path, monkeypatch):
    monkeypatch.setattr(_TorqueRig, "build", lambda self, spec, ctx: _BrokenRig(spec))
    data = small_scenario([{"name": "rig", "kind": "torque_rig", "torque_B_Nm": [0.0, 1e-5, 0.0]}], 2.0)
    scene = build(parse(data, "<test>"))
    try:
        result = run(scene, tmp_path)
    finally:
        scene.close()
    assert result.status == "aborted"
    assert result.error == ("at t = 0.300 s device rig (effect) raised ZeroDivisionError: the rig's torque sensor "
                            "divided by zero")


def test_the_truth_refuses_an_effect_it_does_not_know_or_a_rotor_it_does_not_have():
    from sim.truth import TruthModel

    truth = TruthModel(inertia=np.diag(INERTIA), q_BN=(1.0, 0.0, 0.0, 0.0), omega_BN_B=(0.0, 0.0, 0.0),
                       r_N=(7e6, 0.0, 0.0), v_N=(0.0, 7.5e3, 0.0), step_ns=100_000_000, torques=())
    with pytest.raises(ValueError, match="effect type 'thrust' is not one of dipole, torque, momentum_exchange"):
        truth.effector([Effect("thrust", lambda: (0.0, 0.0, 0.0))])
    with pytest.raises(ValueError, match=r"momentum_exchange targets \[0\], but the truth has no wheel cluster"):
        truth.effector([Effect("momentum_exchange", lambda: 0.0, 0)])
    assert EFFECT_TYPES == ("dipole", "torque", "momentum_exchange")


def test_a_momentum_exchange_reaches_its_rotor_and_the_body_takes_the_reaction():
    from sim.truth import TruthModel
    from sim.wheels import WheelCluster

    J, tau = 1e-3, 1e-4  # rotor spin inertia (kg m^2), net torque on rotor 1 (N m)
    cluster = WheelCluster(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).T, [J, J])
    truth = TruthModel(inertia=np.diag(INERTIA), q_BN=(1.0, 0.0, 0.0, 0.0), omega_BN_B=(0.0, 0.0, 0.0),
                       r_N=(7e6, 0.0, 0.0), v_N=(0.0, 7.5e3, 0.0), step_ns=100_000_000, torques=(), wheels=cluster)
    step = truth.effector([Effect("momentum_exchange", lambda: tau, 1)])
    for _ in range(10):  # 1 s
        step()
    # Rotor 1 (spin axis z) gains tau t; rotor 0, which no effect targets, keeps none; the body turns the other way
    # about z with the inertia left beside the rotor (I_zz - J), and the total stays zero.
    assert truth.h_wheels == pytest.approx((0.0, tau * 1.0), abs=1e-18)
    np.testing.assert_allclose(truth.w, (0.0, 0.0, -tau * 1.0 / (INERTIA[2] - J)), rtol=1e-12, atol=1e-18)
    assert np.max(np.abs(truth.angular_momentum_B())) < 1e-18
    with pytest.raises(ValueError, match=r"targets \[0, 0\]: each must name a different rotor column"):
        truth.effector([Effect("momentum_exchange", lambda: tau, 0), Effect("momentum_exchange", lambda: tau, 0)])


def _names_in(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every identifier, attribute, string and comment of a Python file."""
    text = path.read_text()
    found = [(tok.lineno, tok.id) for tok in ast.walk(ast.parse(text)) if isinstance(tok, ast.Name)]
    found += [(n.lineno, n.attr) for n in ast.walk(ast.parse(text)) if isinstance(n, ast.Attribute)]
    found += [(n.lineno, n.value) for n in ast.walk(ast.parse(text)) if isinstance(n, ast.Constant)
              and isinstance(n.value, str)]
    found += [(i + 1, line[line.index("#"):]) for i, line in enumerate(text.splitlines()) if "#" in line]
    return found


@pytest.mark.parametrize("path", CORE)
def test_the_core_names_no_shipped_kind(path):
    kinds = re.compile("|".join(devices.KINDS))
    named = [(line, text) for line, text in _names_in(ROOT / path) if kinds.search(text)]
    assert named == [], f"{path} names a kind: {named}"


def test_the_operator_page_names_no_shipped_kind():
    text = (ROOT / "stand" / "view" / "assets" / "view.js").read_text()
    named = [(i + 1, line.strip()) for i, line in enumerate(text.splitlines())
             if re.search("|".join(devices.KINDS), line)]
    assert named == [], f"view.js names a kind: {named}"


def test_every_shipped_kind_declares_from_the_one_vocabulary():
    for name in devices.KINDS:
        kind = devices.get(name)
        declared = (*kind.senses, *kind.actuates, *kind.provides)
        assert declared, f"{name} declares nothing it senses, actuates or stimulates"
        assert set(declared) <= set(devices.QUANTITIES), f"{name}: {declared}"
        assert kind.column_meanings and all(kind.column_meanings.values()), name
    bare = devices.DeviceKind()
    assert (bare.senses, bare.actuates, bare.provides, bare.column_meanings) == ((), (), (), {})


@pytest.mark.parametrize("name", ["detumble_cage", "detumble_igrf", "acquisition"])
def test_every_column_a_shipped_device_records_has_a_meaning(name):
    # Between them these scenarios hold every shipped kind: magnetorquer, cage, both sun sensors, tracker, gyro
    # and wheels.
    from stand.loop import column_meanings, columns
    from stand.scenario import find, load

    scene = build(load(find(name)))
    try:
        meanings = column_meanings(scene)
        missing = [c[0] for c in columns(scene) if c[0].partition(".")[0] in scene.devices and c[0] not in meanings]
    finally:
        scene.close()
    assert missing == []


def test_a_kind_that_declares_nothing_still_runs(torque_rig, tmp_path, monkeypatch):
    for attr, empty in (("actuates", ()), ("column_meanings", {})):
        monkeypatch.setattr(_TorqueRig, attr, empty)
    data = small_scenario([{"name": "rig", "kind": "torque_rig", "torque_B_Nm": [0.0, 3e-5, 0.0]}], 1.0)
    data["spacecraft"].update(inertia_kg_m2=list(INERTIA), omega_BN_B_deg_s=[0.0, 0.0, 0.0])
    scene = build(parse(data, "<test>"))
    try:
        result = run(scene, tmp_path)
    finally:
        scene.close()
    assert result.status == "completed", result.error
    schema = json.loads((tmp_path / "telemetry" / telemetry.SCHEMA).read_text())
    assert [c for c in schema["columns"] if c["name"] == "rig.torque_B"] == [
        {"name": "rig.torque_B", "width": 3, "unit": "N m"}]  # no meaning declared, none written
    # Its effect acts all the same: d omega = I^-1 tau t about the intermediate axis.
    assert telemetry.load(tmp_path)["omega_BN_B"][-1, 1] == pytest.approx(3e-5 / INERTIA[1] * 1.0, rel=1e-9)
