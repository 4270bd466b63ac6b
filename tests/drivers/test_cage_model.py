"""The cage model, pure and stepped directly (no Modbus): its coil update against
``sim.actuators.CoilLR``, its supply and thermal physics against closed forms, and the interlocks
as properties that hold for any sequence of writes (Hypothesis)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.cage.model import EXC_ILLEGAL_ADDRESS, EXC_ILLEGAL_VALUE, CageConfig, CageModel
from sim.actuators import CoilLR

H = 1e-3  # the default regulator period


def on(model: CageModel, hb: int = 1) -> None:
    assert model.write(5, [hb]) == 0
    assert model.write(0, [1]) == 0
    assert model.output_on


def setpoints(model: CageModel, amps, polarity: int = 0, hb: int | None = None) -> None:
    hb = (model.heartbeat + 1) & 0xFFFF if hb is None else hb
    assert model.write(1, [polarity, *[round(a / 1e-4) for a in amps], hb]) == 0


def run(model: CageModel, seconds: float, heartbeat_every_s: float | None = 0.1) -> list[tuple]:
    """Step period by period, refreshing the heartbeat; returns (t, i_signed, v, relay, dead) per period."""
    out = []
    n = round(seconds / model.config.regulator_period_s)
    every = None if heartbeat_every_s is None else round(heartbeat_every_s / model.config.regulator_period_s)
    for k in range(n):
        if every is not None and k % every == 0:
            model.write(5, [(model.heartbeat + 1) & 0xFFFF])
        model.advance(model.t_s + model.config.regulator_period_s)
        out.append((model.t_s, model.currents_A(), tuple(ax.v_V for ax in model.axes),
                    tuple(ax.negative for ax in model.axes), tuple(ax.dead_until_s is not None for ax in model.axes)))
    return out


def test_coil_update_equals_sim_coil_lr_for_the_voltages_the_supply_applied():
    cfg = CageConfig()
    m = CageModel(cfg)
    on(m)
    setpoints(m, (1.5, 0.7, 2.2), polarity=0b010)
    trace = run(m, 0.4)
    coils = [CoilLR(L, R) for L, R in zip(cfg.inductance_H, cfg.resistance_ohm, strict=True)]
    i = np.zeros(3)
    for _, cur, v, _, _ in trace:
        i = np.array([c.step(i[a], v[a], H) for a, c in enumerate(coils)])
        assert np.abs(i) == pytest.approx(np.abs(cur), abs=1e-12)
    # and the regulator lands on the set point exactly once the ramp is over (deadbeat, within compliance)
    assert trace[-1][1] == pytest.approx((1.5, -0.7, 2.2), abs=1e-9)


def test_slew_ramp_and_compliance_voltage_follow_the_closed_form():
    cfg = CageConfig(slew_limit_A_s=10.0)
    m = CageModel(cfg)
    on(m)
    setpoints(m, (3.0, 0.0, 0.0))
    trace = run(m, 0.5)
    # within compliance the current follows the ramp i(t) = slew t exactly
    for t, cur, v, _, _ in trace[:250]:
        assert cur[0] == pytest.approx(min(10.0 * t, 3.0), abs=1e-9)
        if t < 0.3 - H / 2:  # on the ramp: V = R i + L di/dt, with i at mid-period (the ZOH to O(h^2))
            mid = 10.0 * (t - H / 2)
            assert v[0] == pytest.approx(cfg.resistance_ohm[0] * mid + cfg.inductance_H[0] * 10.0, rel=1e-3)
    assert trace[-1][1][0] == pytest.approx(3.0, abs=1e-9)


def test_ramp_down_is_never_faster_than_the_coil_decay_single_quadrant():
    cfg = CageConfig(slew_limit_A_s=60.0)
    m = CageModel(cfg)
    on(m)
    setpoints(m, (2.0, 0.0, 0.0))
    run(m, 0.3)
    setpoints(m, (0.0, 0.0, 0.0))
    trace = run(m, 0.2)
    tau = cfg.inductance_H[0] / cfg.resistance_ohm[0]
    for t_rel, (_, cur, v, _, _) in enumerate(trace, start=1):
        assert v[0] >= 0.0
        # the fastest a single-quadrant supply can bring it down is the free decay at V = 0
        assert cur[0] >= 2.0 * math.exp(-t_rel * H / tau) - 1e-12


def test_thermal_model_is_the_first_order_closed_form_and_trips_at_the_limit():
    cfg = CageConfig(thermal_time_constant_s=2.0, thermal_resistance_K_W=0.5, temperature_trip_C=60.0,
                     temperature_reset_C=50.0, heartbeat_timeout_s=5.0)
    m = CageModel(cfg)
    on(m)
    setpoints(m, (3.0, 0.0, 0.0))
    run(m, 0.3)  # ramp done at 0.3 s: from here P = R i^2 is constant
    t0, temp0 = m.t_s, m.axes[0].temperature_C
    p = cfg.resistance_ohm[0] * 9.0  # 44.1 W -> steady 22 + 22.05 = 44.05 degC, below the trip
    run(m, 3.0)
    t_ss = cfg.ambient_C + 0.5 * p
    expected = t_ss + (temp0 - t_ss) * math.exp(-(m.t_s - t0) / 2.0)
    assert m.axes[0].temperature_C == pytest.approx(expected, rel=1e-9)
    assert m.output_on and not m.over_temperature
    setpoints(m, (4.0, 0.0, 0.0))  # 81.6 W -> steady 62.8 degC: above the 60 degC trip
    run(m, 20.0)
    assert m.over_temperature and not m.output_on
    assert m.events.over_temperature_trips == 1
    assert max(ax.temperature_C for ax in m.axes) < cfg.temperature_trip_C + 0.1


def test_field_is_coil_constants_times_currents_plus_lab_field_and_the_magnetometer_samples_it():
    cfg = CageConfig(mag_noise_T=0.0)
    m = CageModel(cfg, rng=1)
    on(m)
    setpoints(m, (1.0, 0.5, 0.25), polarity=0b100)
    run(m, 0.5)
    k = np.array(cfg.coil_T_per_A)
    expected = k @ np.array([1.0, 0.5, -0.25]) + np.array(cfg.lab_field_T)
    assert m.cage_field_T() == pytest.approx(expected, abs=1e-15)
    assert m.field_valid and m.field_T == pytest.approx(tuple(expected), abs=1e-15)
    assert m.field_time_s == pytest.approx(0.5, abs=cfg.mag_period_s)


def test_magnetometer_noise_has_the_configured_sigma_and_is_reproducible():
    cfg = CageConfig(mag_noise_T=5e-9, mag_period_s=0.001)
    a, b = CageModel(cfg, rng=7), CageModel(cfg, rng=7)
    samples = []
    for k in range(1, 2001):
        a.advance(k * H)
        b.advance(k * H)
        assert a.field_T == b.field_T
        samples.append(a.field_T)
    noise = np.array(samples) - np.array(cfg.lab_field_T)
    assert noise.std() == pytest.approx(5e-9, rel=0.05)


def test_refused_writes_apply_nothing():
    m = CageModel()
    on(m)
    before = m.holding_words()
    assert m.write(1, [8, 100, 100, 100, 9]) == EXC_ILLEGAL_VALUE  # polarity 8: no such bit
    assert m.write(0, [2]) == EXC_ILLEGAL_VALUE
    assert m.write(5, [1, 2]) == EXC_ILLEGAL_ADDRESS  # runs past the last holding register
    assert m.holding_words() == before
    assert m.events.refused_writes == 3
    assert m.read("input", 1, 2) == EXC_ILLEGAL_ADDRESS  # would split current_x_A
    assert m.read("input", 0, 2) != EXC_ILLEGAL_ADDRESS


@pytest.mark.parametrize("field, value", [("inductance_H", (0.05, -1.0, 0.05)), ("current_limit_A", 7.0),
                                          ("temperature_reset_C", 70.0), ("coil_T_per_A", ((1, 0, 0),) * 3)])
def test_bad_config_is_refused_with_a_sentence_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        CageConfig(**{field: value})


def test_time_only_moves_forward():
    m = CageModel()
    m.advance(1.0)
    with pytest.raises(ValueError, match="only moves forward"):
        m.advance(0.5)


# -- interlocks as properties: whatever is written, at whatever time -------------------------------

_amps = st.one_of(st.integers(0, 0xFFFF), st.sampled_from([0, 5000, 20000, 30000, 40000, 65535]))
_op = st.one_of(
    # a host's tick: polarity, three set points, a new heartbeat (any values the registers carry)
    st.tuples(st.just("tick"), st.integers(0, 7), st.tuples(_amps, _amps, _amps), st.integers(1, 40)),
    # anything at all, anywhere (mostly refused, or a stale heartbeat, or an enable)
    st.tuples(st.just("raw"), st.integers(0, 6), st.lists(_amps | st.integers(0, 8), min_size=1, max_size=6),
              st.integers(1, 40)),
    st.tuples(st.just("enable"), st.integers(1, 40)),
    st.tuples(st.just("silence"), st.integers(1, 120)),  # the host stops: the heartbeat goes stale
)


def _apply(m: CageModel, op) -> int:
    kind = op[0]
    if kind == "tick":
        m.write(1, [op[1], *op[2], (m.heartbeat + 1) & 0xFFFF])
    elif kind == "raw":
        m.write(op[1], op[2])
    elif kind == "enable":
        m.write(5, [(m.heartbeat + 1) & 0xFFFF])
        m.write(0, [1])
    return op[-1]


@settings(max_examples=80, deadline=None)
@given(st.lists(_op, min_size=1, max_size=30))
def test_interlocks_hold_whatever_is_written(ops):
    cfg = CageConfig(heartbeat_timeout_s=0.03, polarity_dead_time_s=0.005, slew_limit_A_s=20.0,
                     thermal_time_constant_s=0.5, thermal_resistance_K_W=20.0, current_limit_A=3.0)
    m = CageModel(cfg, rng=0)
    step_max = cfg.slew_limit_A_s * H
    prev = [0.0, 0.0, 0.0]
    prev_rel = [False, False, False]
    zero_since = [0.0, 0.0, 0.0]  # when each axis' current last went below the zero threshold
    on(m)
    for op in ops:
        for _ in range(_apply(m, op)):
            hb_age = m.t_s - m._t_heartbeat
            was_on = m.output_on
            m.advance(m.t_s + H)
            if was_on and hb_age > cfg.heartbeat_timeout_s:
                assert not m.output_on and m.heartbeat_lost  # a stale heartbeat always switches off
            if m.output_on:
                assert m.t_s - H - m._t_heartbeat <= cfg.heartbeat_timeout_s + 1e-12
                assert not m.over_temperature
            for a, ax in enumerate(m.axes):
                assert 0.0 <= ax.v_V <= cfg.compliance_V
                assert ax.i_A <= cfg.current_limit_A + 1e-12  # current interlock
                assert ax.i_A - prev[a] <= step_max + 1e-12  # slew interlock (rising)
                if ax.negative != prev_rel[a]:  # the relay switched: only with no current, after the dead time
                    assert prev[a] < cfg.zero_current_A
                    assert m.t_s - zero_since[a] >= cfg.polarity_dead_time_s - 1e-9
                if ax.i_A >= cfg.zero_current_A:
                    zero_since[a] = math.inf
                elif zero_since[a] == math.inf:
                    zero_since[a] = m.t_s - H
                prev[a], prev_rel[a] = ax.i_A, ax.negative
            flags = m.interlock_flags()
            for a, name in enumerate(m.map.axes):
                assert (f"current_limit_{name}" in flags) == (m.setpoint_raw[a] * 1e-4 > cfg.current_limit_A)
                assert (f"polarity_held_{name}" in flags) == (bool(m.polarity_request >> a & 1) != m.axes[a].negative)
