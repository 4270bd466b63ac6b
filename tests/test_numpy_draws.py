"""numpy_draws, the emulated devices' single random draws: on both builds each draw is the number the Generator's own
method returns on an equal Generator, and leaves the Generator in the same state (so every draw after it, by either
way, is the same too); parameters numpy refuses get numpy's error; the compiled build takes numpy's C functions
(its check at import passed) and is not fooled by a Generator drawn from another thread."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest

import numpy_draws as plain
from tests.oracles import build_fixtures

compiled, build = build_fixtures("numpy_draws")

# Every algorithm behind the three draws: Poisson's multiplication (lam < 10) and PTRS; the binomial's inversion
# (n p <= 30) and BTPE, each for p below and above 0.5 (numpy draws 1 - p then), and its edges (n = 0, p = 0, p = 1).
LAMS = (0.0, 1e-12, 0.5, 3.0, 9.999999, 10.0, 42.5, 300.0, 1e6, 1e12)
BINOMIALS = ((0, 0.4), (7, 0.0), (7, 1.0), (12, 0.3), (60, 0.5), (255, 0.97), (255, 0.02), (1000, 0.2), (1000, 0.8),
             (10**9, 0.5), (3, 1e-300))


def _pair(seed: int):
    return np.random.default_rng(seed), np.random.default_rng(seed)


def test_each_draw_is_the_generators_own_and_leaves_the_same_state(build) -> None:
    ours, theirs = _pair(11)
    for rep in range(40):
        got = build.random(ours)
        assert type(got) is float and got.hex() == float(theirs.random()).hex()
        for lam in LAMS:
            got = build.poisson(ours, lam)
            assert type(got) is int and got == int(theirs.poisson(lam)), (lam, rep)
        for n, p in BINOMIALS:
            got = build.binomial(ours, n, p)
            assert type(got) is int and got == int(theirs.binomial(n, p)), (n, p, rep)
        for k in (0, 1, 3, 9, 64, 65):
            got = build.standard_normal(ours, k)
            assert type(got) is list and [x.hex() for x in got] == [x.hex() for x in theirs.standard_normal(k).tolist()]
    assert ours.bit_generator.state == theirs.bit_generator.state


def test_mixed_draws_in_the_emulators_order_match_over_a_long_run(build) -> None:
    # The star tracker's exposure: stars in the field (Poisson), those matched (binomial), three attitude-noise normals.
    ours, theirs = _pair(2026)
    for _ in range(20_000):
        n = build.poisson(ours, 28.4)
        assert n == int(theirs.poisson(28.4))
        m = build.binomial(ours, n, 0.985)
        assert m == int(theirs.binomial(n, 0.985))
        assert build.standard_normal(ours, 3) == theirs.standard_normal(3).tolist()
    assert ours.bit_generator.state == theirs.bit_generator.state


@pytest.mark.parametrize("draw, args", [
    ("poisson", (-1.0,)), ("poisson", (math.nan,)), ("poisson", (1e30,)),
    ("binomial", (-1, 0.5)), ("binomial", (5, -0.1)), ("binomial", (5, 1.5)), ("binomial", (5, math.nan)),
    ("standard_normal", (-1,)),
])
def test_what_numpy_refuses_gets_numpys_error(build, draw, args) -> None:
    with pytest.raises(ValueError) as theirs:
        getattr(np.random.default_rng(0), draw)(*args)
    with pytest.raises(ValueError) as ours:
        getattr(build, draw)(np.random.default_rng(0), *args)
    assert str(ours.value) == str(theirs.value)


def test_other_number_types_take_the_method_and_get_its_answer(build) -> None:
    # np.int64 and float trial counts, np.float64 means, an integer mean: numpy's own conversion decides.
    for args in ((np.int64(20), 0.5), (20, np.float64(0.25)), (True, 0.5)):
        ours, theirs = _pair(5)
        assert build.binomial(ours, *args) == int(theirs.binomial(*args))
    for lam in (np.float64(4.5), 7, np.int32(3)):
        ours, theirs = _pair(6)
        assert build.poisson(ours, lam) == int(theirs.poisson(lam))
    ours, theirs = _pair(7)
    assert build.standard_normal(ours, np.int64(4)) == theirs.standard_normal(4).tolist()


def test_what_is_not_a_generator_itself_gets_its_own_methods(build) -> None:
    # A legacy RandomState draws with other algorithms; a subclass may override a method; None has no methods.
    legacy, reference = np.random.RandomState(4), np.random.RandomState(4)
    assert build.poisson(legacy, 6.5) == int(reference.poisson(6.5))
    assert build.binomial(legacy, 40, 0.3) == int(reference.binomial(40, 0.3))
    assert build.standard_normal(legacy, 3) == reference.standard_normal(3).tolist()
    assert build.random(legacy) == float(reference.random())

    class Fixed(np.random.Generator):
        def poisson(self, lam=1.0, size=None):
            return 7

    assert build.poisson(Fixed(np.random.PCG64(1)), 2.0) == 7
    with pytest.raises(AttributeError, match="'NoneType' object has no attribute 'poisson'"):
        build.poisson(None, 2.0)


@pytest.mark.parametrize("bit_generator", [np.random.PCG64DXSM, np.random.MT19937, np.random.Philox, np.random.SFC64])
def test_every_bit_generator_of_numpy_gives_the_methods_draws(build, bit_generator) -> None:
    ours, theirs = np.random.Generator(bit_generator(8)), np.random.Generator(bit_generator(8))
    for _ in range(500):
        assert build.poisson(ours, 12.5) == int(theirs.poisson(12.5))
        assert build.binomial(ours, 30, 0.9) == int(theirs.binomial(30, 0.9))
        assert build.standard_normal(ours, 3) == theirs.standard_normal(3).tolist()
        assert build.random(ours) == float(theirs.random())
    assert ours.bit_generator.random_raw() == theirs.bit_generator.random_raw()


def test_the_compiled_build_takes_numpys_c_functions_and_plain_python_the_methods(compiled) -> None:
    assert compiled.DIRECT is True  # its check at import found this numpy's methods draw the same
    assert plain.DIRECT is False
    assert compiled._same_as_numpy() is True


def test_the_compiled_draws_hold_the_bit_generators_lock(compiled) -> None:
    # Two threads drawing from one Generator: the draws are atomic, as the methods' are (each thread's numbers are
    # whole draws of the stream, none torn by the other's). The stream's union is checked against one thread's.
    rng = np.random.default_rng(99)
    got: list[list[float]] = [[], []]

    def work(i: int) -> None:
        for _ in range(5000):
            got[i].extend(compiled.standard_normal(rng, 3))

    threads = [threading.Thread(target=work, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    reference = np.random.default_rng(99).standard_normal(30_000).tolist()
    assert sorted(got[0] + got[1]) == sorted(reference)
    # a thread holding the lock blocks the draw until it lets go
    with rng.bit_generator.lock:
        waiter = threading.Thread(target=compiled.poisson, args=(rng, 2.0))
        waiter.start()
        waiter.join(timeout=0.2)
        assert waiter.is_alive()
    waiter.join(timeout=10)
    assert not waiter.is_alive()
