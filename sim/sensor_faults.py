"""Sensor faults on a measured vector: a tap put over the callable that produces a sensor's measurement, and the
transforms a fault applies through it (stuck, bias, drift, scale, noise, saturation, a dead axis).

Pure functions of the measurement and the time; the stand's fault schedule (``stand.faults``) puts the tap on a
device when a fault first starts there, so a run without faults never calls anything here.
"""

from __future__ import annotations

import compiled_paths

_draws = compiled_paths.load("numpy_draws")  # a tick's draws without the Generator's Python-facing layers


class VectorTap:
    """Transforms applied in turn to a measured vector. Put over ``obj.attr`` (a callable returning the vector,
    or a tuple whose first element is the vector when ``first``): the original is called, then each active
    transform ``f(t_s, v) -> v`` (tuples of floats). With none active the original's own result is returned,
    so the bits are unchanged."""

    def __init__(self, obj, attr: str, n: int, unit: str, *, first: bool = False):
        self.n, self.unit, self.first = n, unit, first
        self.transforms: list = []
        self._obj, self._attr = obj, attr
        self._inner = getattr(obj, attr)
        setattr(obj, attr, self._call)

    def _call(self, t_s, *args):
        out = self._inner(t_s, *args)
        if not self.transforms:
            return out
        v = tuple(float(x) for x in (out[0] if self.first else out))
        for f in self.transforms:
            v = f(t_s, v)
        return (v, *out[1:]) if self.first else v

    def add(self, transform) -> None:
        self.transforms.append(transform)

    def remove(self, transform) -> None:
        if transform in self.transforms:
            self.transforms.remove(transform)


def stuck(held: list):
    """Hold the first value seen after the start (``held`` keeps it)."""
    def f(t_s, v):
        if not held:
            held.append(v)
        return held[0]
    return f


def bias(b: tuple, drift_per_s: tuple | None = None, t0_s: float = 0.0):
    if drift_per_s is None:
        return lambda t_s, v: tuple(x + y for x, y in zip(v, b, strict=True))
    return lambda t_s, v: tuple(x + y + d * (t_s - t0_s) for x, y, d in zip(v, b, drift_per_s, strict=True))


def scale(factors: tuple):
    return lambda t_s, v: tuple(x * k for x, k in zip(v, factors, strict=True))


def noise(sigma: float, rng, n: int):
    # e * s on floats is the float64 product numpy's ``rng.standard_normal(n) * sigma`` gives, element by element
    s = float(sigma)
    return lambda t_s, v: tuple(x + e * s for x, e in zip(v, _draws.standard_normal(rng, n), strict=True))


def saturate(limit: float):
    return lambda t_s, v: tuple(min(max(x, -limit), limit) for x in v)


def dead(axis: int):
    return lambda t_s, v: tuple(0.0 if i == axis else x for i, x in enumerate(v))
