"""sim.sensors.Gyro: Allan deviation of each error term against the IEEE 952 closed forms (computed
with allantools), the deterministic error terms exactly, chunk invariance and seeding."""

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from sim.sensors import GM_PEAK_ADEV_OVER_SIGMA, GM_PEAK_TAU_OVER_T, DelayLine, Gyro, gauss_markov_adev
from tests.oracles import require

allantools = require("allantools")

REF = Path(__file__).resolve().parents[2] / "fixtures" / "reference" / "gyro_allan" / "allan_reference.csv"


def _reference() -> dict[str, list[tuple[float, float, float]]]:
    out: dict[str, list[tuple[float, float, float]]] = {}
    with open(REF) as f:
        rows = csv.DictReader(line for line in f if not line.startswith("#"))
        for r in rows:
            out.setdefault(r["case"], []).append((float(r["tau_s"]), float(r["adev_rad_s"]), float(r["rel_tol"])))
    return out


CASES = {  # the parameters in the CSV header
    "arw": (Gyro(sample_period_s=0.01, arw_rad_sqrt_s=1e-4), 100_000),
    "rrw": (Gyro(sample_period_s=0.1, rrw_rad_s_sqrt_s=1e-6), 200_000),
    "bias_instability": (Gyro(sample_period_s=0.1, bias_instability_rad_s=1e-5, bias_correlation_s=10.0), 200_000),
}


@pytest.mark.parametrize("case", list(CASES))
def test_allan_deviation_of_each_error_term_matches_the_closed_form(case):
    gyro, n = CASES[case]
    ref = _reference()[case]
    taus = [tau for tau, _, _ in ref]
    y, _, _ = gyro.measure(np.zeros((n, 3)), np.random.default_rng(0))
    adev = np.mean([allantools.oadev(y[:, k], rate=1.0 / gyro.sample_period_s, data_type="freq", taus=taus)[1]
                    for k in range(3)], axis=0)
    for (tau, want, tol), got in zip(ref, adev, strict=True):
        assert got == pytest.approx(want, rel=tol), f"{case} at tau = {tau} s"


def test_bias_instability_is_the_gauss_markov_peak_at_the_flicker_floor():
    g = Gyro(bias_instability_rad_s=2e-6, bias_correlation_s=50.0)
    peak = gauss_markov_adev(GM_PEAK_TAU_OVER_T * 50.0, g.gauss_markov_sigma_rad_s, 50.0)
    assert peak == pytest.approx(math.sqrt(2 * math.log(2) / math.pi) * 2e-6, rel=1e-12)
    around = gauss_markov_adev(GM_PEAK_TAU_OVER_T * 50.0 * np.array([0.9, 1.1]), 1.0, 50.0)
    assert np.all(around < GM_PEAK_ADEV_OVER_SIGMA)
    # Far below T the process is a rate random walk (ADEV sqrt(2 tau / 3 T) sigma), and the small-tau
    # series joins the closed form where it takes over (ADEV ~ sqrt(tau) across the seam).
    assert gauss_markov_adev(1e-8, 1.0, 1.0) == pytest.approx(math.sqrt(2e-8 / 3), rel=1e-8)
    below, above = gauss_markov_adev(np.array([0.999999e-3, 1.000001e-3]), 1.0, 1.0)
    assert below / above == pytest.approx(math.sqrt(0.999999 / 1.000001), rel=1e-7)


def test_noise_free_reading_applies_mount_scale_factor_misalignment_and_bias_exactly():
    dcm_SB = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    m = np.array([[0.0, 1e-3, -2e-3], [5e-4, 0.0, 1e-3], [0.0, -1e-3, 0.0]])
    g = Gyro(bias_rad_s=[1e-4, 0.0, -1e-4], scale_factor=[1e-3, -2e-3, 0.0], misalignment=m, dcm_SB=dcm_SB)
    w_B = np.array([0.1, -0.2, 0.3])
    y, sat, _ = g.measure(w_B, None)
    w_S = w_B[[1, 2, 0]]
    expected = w_S + np.array([1e-3, -2e-3, 0.0]) * w_S + m @ w_S + np.array([1e-4, 0.0, -1e-4])
    np.testing.assert_allclose(y, expected, rtol=0, atol=1e-16)
    assert not sat.any()


def test_quantisation_and_saturation():
    g = Gyro(lsb_rad_s=1e-3, range_rad_s=1.0)
    y, sat, _ = g.measure([[0.00149, -0.0016, 2.5], [0.0, -3.0, 0.9996]], None)
    np.testing.assert_allclose(y, [[1e-3, -2e-3, 1.0], [0.0, -1.0, 1.0]], atol=1e-15)
    np.testing.assert_array_equal(sat, [[False, False, True], [False, True, False]])


def test_one_call_or_many_give_identical_readings_and_the_seed_reproduces_them():
    g = Gyro(sample_period_s=0.1, arw_rad_sqrt_s=1e-4, rrw_rad_s_sqrt_s=1e-6, bias_instability_rad_s=1e-5,
             bias_correlation_s=20.0, lsb_rad_s=1e-6)
    w = np.random.default_rng(5).normal(0.0, 0.01, (300, 3))
    whole, _, _ = g.measure(w, np.random.default_rng(9))
    rng = np.random.default_rng(9)
    state = g.initial_state(rng)
    parts = []
    for chunk in (w[:1], w[1:100], w[100:101], w[101:]):
        y, _, state = g.measure(chunk, rng, state)
        parts.append(y)
    np.testing.assert_array_equal(np.vstack(parts), whole)
    again, _, _ = g.measure(w, np.random.default_rng(9))
    np.testing.assert_array_equal(again, whole)
    other, _, _ = g.measure(w, np.random.default_rng(10))
    assert not np.array_equal(other, whole)


def test_one_sample_at_a_time_on_floats_reads_as_the_batch_bit_for_bit():
    # The loop measures one sample per tick with measure_one (floats, tuples in and out); every reading, saturation
    # flag and the state after them must be the batch's, bit for bit, including saturated and quantised samples.
    g = Gyro(sample_period_s=0.1, arw_rad_sqrt_s=1e-4, rrw_rad_s_sqrt_s=1e-6, bias_instability_rad_s=1e-5,
             bias_correlation_s=20.0, bias_rad_s=[1e-4, -2e-4, 3e-5], scale_factor=[1e-3, -2e-3, 5e-4],
             misalignment=[[0.0, 1e-3, -2e-3], [5e-4, 0.0, 1e-3], [-1e-3, 2e-3, 0.0]], lsb_rad_s=1e-7,
             range_rad_s=0.02, dcm_SB=[[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    w = np.random.default_rng(5).normal(0.0, 0.01, (400, 3))
    whole, sat_whole, state_whole = g.measure(w, np.random.default_rng(9))
    rng = np.random.default_rng(9)
    state = g.initial_state(rng)
    rows, sats = [], []
    for sample in w.tolist():
        y, sat, state = g.measure_one(tuple(sample), rng, state)
        assert all(type(v) is float for v in y)
        rows.append(y)
        sats.append(sat)
    assert np.array(rows).tobytes() == whole.tobytes()
    # the range was reached, and flagged
    assert [list(s) for s in sats] == sat_whole.tolist() and any(any(s) for s in sats)
    assert np.array(state).tobytes() == np.array(state_whole).tobytes()
    y1, sat1, _ = g.measure(w[0], np.random.default_rng(9), g.initial_state(np.random.default_rng(9)))
    assert y1.shape == (3,) and sat1.shape == (3,)  # measure keeps its array interface for one sample
    with pytest.raises(ValueError, match="omega_BN_B"):
        g.measure_one((0.0, math.nan, 0.0), None)


def test_delay_line_gives_the_rate_one_delay_earlier():
    line = DelayLine(span_s=0.05)
    for k in range(20):
        line.push(0.01 * k, [0.01 * k, 0.0, -1.0])
    np.testing.assert_allclose(line.at(0.19 - 0.025), [0.165, 0.0, -1.0], atol=1e-15)
    np.testing.assert_allclose(line.at(1.0), [0.19, 0.0, -1.0])
    with pytest.raises(ValueError, match="after the last sample"):
        line.push(0.19, [0, 0, 0])


@pytest.mark.parametrize(("kw", "field"), [
    ({"sample_period_s": 0.0}, "sample_period_s"),
    ({"arw_rad_sqrt_s": -1.0}, "arw_rad_sqrt_s"),
    ({"scale_factor": [0.6, 0, 0]}, "scale_factor"),
    ({"misalignment": np.eye(3) * 1e-3}, "zero diagonal"),
    ({"dcm_SB": np.diag([1.0, 1.0, -1.0])}, "proper rotation"),
    ({"range_rad_s": 0.0}, "range_rad_s"),
])
def test_bad_parameters_are_named(kw, field):
    with pytest.raises(ValueError, match=field):
        Gyro(**kw)
    with pytest.raises(ValueError, match="omega_BN_B"):
        Gyro().measure([1.0, 2.0], None)
