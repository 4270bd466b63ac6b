"""Single random draws from a ``numpy.random.Generator``, each the value the Generator's own method returns, for the
emulated devices that draw a few numbers every tick.

``rng.random()``, ``rng.poisson(lam)``, ``rng.binomial(n, p)`` and ``rng.standard_normal(k).tolist()`` each pass
through numpy's argument handling (dtype look-ups, array conversion, constraint checks) before numpy's C function
draws the number: well under a microsecond in a tight loop, but inside a run, where each tick runs a long chain of
device code first, those Python-facing layers are cold and the tracker's three draws cost about 20 us a tick
(docs/fast_paths.md, "Random draws").

Compiled (``compiled_paths`` lists this module; it is at the top of the package tree beside ``quat_floats`` because
``sim`` and ``drivers`` both draw and may not import each other), the functions below call numpy's own C
distributions (``random_standard_uniform``, ``random_poisson``, ``random_binomial``, ``random_standard_normal`` of
``numpy/random/c_distributions.pxd``, linked from numpy's ``libnpyrandom``, numpy's documented way to extend its
random module) on the Generator's bit generator, under the bit generator's lock as numpy's methods take it. Those
are the functions the methods end in, so the state advances the same way and the numbers are the same bits. In plain
Python they call the methods. Parameters the fast path does not take (a float ``n``, a NaN, values out of range) go
to the method too, which gives numpy's answer or numpy's error; so does anything but a ``Generator`` itself
(:func:`_direct`).

The compiled build checks itself once, at import: the same draws through both ways on two equal Generators, over
parameters that reach every algorithm (Poisson's multiplication and PTRS, the binomial's inversion and BTPE on both
sides of p = 0.5, the normal's ziggurat tail). Should the numpy that runs draw otherwise than the numpy the module
was built against (numpy does not promise the same stream across versions), :data:`DIRECT` is False and every
draw takes the method: slower, never different. ``tests/test_numpy_draws.py`` checks both builds against numpy.
"""

from __future__ import annotations

import cython
from numpy.random import Generator, default_rng

try:  # the C declarations; plain Python has none and never reaches the code that uses them
    from cython.cimports.cpython.pycapsule import PyCapsule_GetPointer
    from cython.cimports.numpy.random import bitgen_t
    from cython.cimports.numpy.random.c_distributions import (
        binomial_t,
        random_binomial,
        random_poisson,
        random_standard_normal,
        random_standard_uniform,
    )
except (ImportError, AttributeError):  # Cython's shadow module raises AttributeError for a package it cannot map
    pass

#: Means above this go to the method (which refuses those above numpy's POISSON_LAM_MAX, about 9.2e18).
_POISSON_LAM_FAST = cython.declare(cython.double, 1e15)
#: The largest number of trials the fast path takes (numpy's n is an int64).
_BINOMIAL_N_FAST = cython.declare(cython.longlong, 1 << 62)


@cython.cfunc
def _bitgen(rng) -> cython.pointer(bitgen_t):
    return cython.cast(cython.pointer(bitgen_t), PyCapsule_GetPointer(rng.bit_generator.capsule, b"BitGenerator"))


@cython.cfunc
@cython.inline
def _direct(rng) -> cython.bint:
    """Whether ``rng``'s draws may take numpy's C functions here: the check at import passed and ``rng`` is a
    ``Generator`` itself (not a legacy ``RandomState``, whose distributions are other algorithms, nor a subclass,
    which may override a method)."""
    return DIRECT and type(rng) is Generator


def random(rng) -> float:
    """``float(rng.random())``: one uniform draw in [0, 1)."""
    if cython.compiled:
        if _direct(rng):
            state = _bitgen(rng)
            with rng.bit_generator.lock:
                return random_standard_uniform(state)
    return float(rng.random())


def standard_normal(rng, k: int) -> list:
    """``rng.standard_normal(k).tolist()``: ``k`` standard normal floats."""
    if cython.compiled:
        if _direct(rng) and type(k) is int and 0 <= k <= 64:
            i: cython.Py_ssize_t
            out = [0.0] * k
            state = _bitgen(rng)
            with rng.bit_generator.lock:
                for i in range(k):
                    out[i] = random_standard_normal(state)
            return out
    return rng.standard_normal(k).tolist()


def poisson(rng, lam) -> int:
    """``int(rng.poisson(lam))``: one Poisson draw of mean ``lam``."""
    if cython.compiled:
        if _direct(rng) and isinstance(lam, float) and 0.0 <= cython.cast(cython.double, lam) <= _POISSON_LAM_FAST:
            state = _bitgen(rng)
            with rng.bit_generator.lock:
                return random_poisson(state, cython.cast(cython.double, lam))
    return int(rng.poisson(lam))


def binomial(rng, n, p) -> int:
    """``int(rng.binomial(n, p))``: one binomial draw of ``n`` trials of probability ``p``."""
    if cython.compiled:
        if (_direct(rng) and type(n) is int and isinstance(p, float) and 0 <= n <= _BINOMIAL_N_FAST
                and 0.0 <= cython.cast(cython.double, p) <= 1.0):
            # numpy keeps this block on the Generator to skip recomputing the setup of a repeated (n, p); a fresh one
            # makes the C function compute it, the same numbers either way.
            cache = cython.declare(binomial_t)
            cache.has_binomial = 0
            state = _bitgen(rng)
            with rng.bit_generator.lock:
                return random_binomial(state, cython.cast(cython.double, p), cython.cast(cython.longlong, n),
                                       cython.address(cache))
    return int(rng.binomial(n, p))


def _same_as_numpy() -> bool:
    """Whether this module's draws are numpy's on equal Generators, over parameters reaching every algorithm (numpy's
    side drawn in batches, which its methods fill with the same C function, one draw after another)."""
    ours, theirs = default_rng(20261127), default_rng(20261127)
    if [random(ours) for _ in range(20)] != theirs.random(20).tolist():
        return False
    for lam in (0.0, 0.5, 3.0, 9.99, 10.0, 42.5, 1e4):
        if [poisson(ours, lam) for _ in range(20)] != theirs.poisson(lam, 20).tolist():
            return False
    for n, p in ((0, 0.3), (5, 0.0), (5, 1.0), (12, 0.3), (40, 0.97), (255, 0.5), (1000, 0.2), (1000, 0.8)):
        if [binomial(ours, n, p) for _ in range(20)] != theirs.binomial(n, p, 20).tolist():
            return False
    # 3,000 normals in draws of 3: a few land in the ziggurat's tail and wedges
    return sum((standard_normal(ours, 3) for _ in range(1000)), []) == theirs.standard_normal(3000).tolist()


#: True when the draws take numpy's C functions directly (compiled, and checked at import against this numpy's
#: methods); False in plain Python, or when the check found a difference, and every draw calls the method.
DIRECT: bool = True  # while the check below runs, so that it draws through the C functions it checks
DIRECT = bool(cython.compiled) and _same_as_numpy()
