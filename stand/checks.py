"""Validation helpers every part of a scenario uses: the ``Table`` accessor, rates and periods, pairs, names.

A leaf of the stand: it imports nothing of ``stand`` but :mod:`stand.errors`, so the scenario loader, the device
kinds, the controller kinds and the ``[rendezvous]`` section all validate with it without importing each other.
Every refusal is a :class:`stand.errors.ScenarioError`: one sentence naming the field, the value and what is
allowed.
"""

from __future__ import annotations

import difflib
import math
import re
import sys
from typing import Any

import numpy as np

from sim.time import NS_PER_S, seconds_to_ns

from .errors import MISSING, ScenarioError, shown

__all__ = ["CONTROL", "KEY_PATTERN", "MAX_STEPS_PER_PERIOD", "MISSING", "NAME_PATTERN", "ScenarioError", "Table",
           "pair", "rate", "shown", "ticks_per", "unusable"]

#: Longest period of a rate, in dynamics steps: whole numbers of steps stay exact in a float below 2**53, and a
#: period of 30 days at the smallest step (1e-6 s) is 2.6e12 steps.
MAX_STEPS_PER_PERIOD = 1e13
#: Run names become folder names under the output folder: a plain name, no path.
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,99}")
#: Keys printed as they are in an error; any other key is quoted and cut.
KEY_PATTERN = re.compile(r"[A-Za-z0-9_-]{1,100}")
#: Control characters (C0 but tab, DEL, C1): refused in text that reaches a console or a report.
CONTROL = re.compile("[\x00-\x08\x0a-\x1f\x7f-\x9f]")


class Table:
    """A TOML table that remembers its dotted path, hands out validated values and notices typos."""

    def __init__(self, data: Any, path: str, source: str | None):
        if not isinstance(data, dict):
            raise ScenarioError(path, data, "a table of key = value pairs is expected", source)
        self.data = data
        self.path = path
        self.source = source
        self.used: set[str] = set()
        # Keys only asked about (``has``): optional keys absent here are known all the same, so a key missing its
        # unit suffix (``duration`` for an optional ``duration_s``) is named with the key it meant.
        self.asked: set[str] = set()

    def _name(self, key: str) -> str:
        # A key is any string in TOML: one with a line break or a megabyte of text is quoted and cut, so the
        # error stays one short line.
        if not KEY_PATTERN.fullmatch(key):
            key = shown(key)
        return f"{self.path}.{key}" if self.path else key

    def error(self, key: str, value, allowed: str) -> ScenarioError:
        if value is MISSING and key not in self.data:
            # A required key is missing: when the table has it under another spelling (``duration = 10`` for
            # ``duration_s``), that key is the mistake to name, not the missing one.
            meant = [k for k in self.data if k not in self.used and key in _likely_meant(k, (key,))]
            if meant:
                return self.error(meant[0], self.data[meant[0]], f"this key is not known here; did you mean "
                                  f"{key!r} (units are part of the key's name)?")
        return ScenarioError(self._name(key), value, allowed, self.source)

    def raw(self, key: str, default=MISSING):
        self.used.add(key)
        return self.data.get(key, default)

    def has(self, key: str) -> bool:
        self.asked.add(key)
        return key in self.data

    def number(self, key: str, default=MISSING, *, lo=None, hi=None, lo_open=False, hi_open=False,
               integer=False) -> float:
        value = self.raw(key, default)
        rng = _range_text(lo, hi, lo_open, hi_open)
        kind = "a whole number" if integer else "a number"
        if value is MISSING:
            raise self.error(key, value, f"{kind}{rng} is required")
        if isinstance(value, bool) or not isinstance(value, int | float) or (integer and not isinstance(value, int)):
            raise self.error(key, value, f"{kind}{rng} is expected")
        if not math.isfinite(value):
            raise self.error(key, value, f"a finite number{rng} is expected")
        if 0 < abs(value) < sys.float_info.min:
            # A subnormal has lost its precision and its inverse (a period, a rate) overflows to infinity.
            raise self.error(key, value, f"a number of normal size{rng}, not a subnormal (below "
                             f"{sys.float_info.min:.4g}, whose inverse overflows to infinity)")
        if (lo is not None and (value < lo or (lo_open and value == lo))) or (
            hi is not None and (value > hi or (hi_open and value == hi))
        ):
            raise self.error(key, value, f"{kind}{rng} is expected")
        return value

    def choice(self, key: str, options, default=MISSING) -> str:
        value = self.raw(key, default)
        if value not in options:
            raise self.error(key, MISSING if value is MISSING else value,
                             "one of " + ", ".join(repr(o) for o in options))
        return value

    def text(self, key: str, default=MISSING) -> str:
        value = self.raw(key, default)
        if not isinstance(value, str) or not value or CONTROL.search(value):
            # Names, ports and paths reach file systems, buses and consoles: a NUL or an escape has no place there.
            raise self.error(key, value, "a non-empty string without control characters is expected")
        return value

    def vector(self, key: str, n: int, default=MISSING, *, lo=None, hi=None) -> np.ndarray:
        value = self.raw(key, default)
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError, OverflowError):
            arr = None
        rng = _range_text(lo, hi, False, False)
        if (value is MISSING or arr is None or arr.shape != (n,) or not np.all(np.isfinite(arr))
                or any(isinstance(v, bool) for v in value)):
            raise self.error(key, value, f"a list of {n} finite numbers{rng} is expected")
        if (lo is not None and np.any(arr < lo)) or (hi is not None and np.any(arr > hi)):
            raise self.error(key, value, f"a list of {n} numbers, each{rng}")
        return arr

    def flag(self, key: str, default=MISSING) -> bool:
        value = self.raw(key, default)
        if not isinstance(value, bool):
            raise self.error(key, value, "true or false")
        return value

    def table(self, key: str, required: bool = True) -> Table:
        value = self.raw(key, MISSING)
        if value is MISSING:
            if required:
                raise ScenarioError(self._name(key), value, "this table is required", self.source)
            value = {}
        return Table(value, self._name(key), self.source)

    def check_unknown(self, allowed_extra: tuple[str, ...] = ()) -> None:
        unknown = sorted(set(self.data) - self.used - set(allowed_extra))
        if unknown:
            known = sorted(self.used | self.asked | set(allowed_extra))
            # Name first a key that probably meant a known one (``duration`` beside a typo'd ``colour``): that
            # mistake is the one a reader cannot find alone; the others are listed after it.
            key = next((k for k in unknown if _likely_meant(k, known)), unknown[0])
            meant = _likely_meant(key, known)
            hint = f"did you mean {' or '.join(repr(m) for m in meant)}?" if meant else "a typo?"
            others = [KEY_PATTERN.fullmatch(k) and k or shown(k) for k in unknown if k != key]
            also = f"; also unknown: {', '.join(others[:5])}{', ...' if len(others) > 5 else ''}" if others else ""
            raise self.error(key, self.data[key], f"this key is not known here ({hint}){also}; known keys: "
                             + ", ".join(known))

    def refuse_unused(self, key: str, setting: str, what_to_do: str) -> None:
        """Refuse a key the scenario gives but whose value the run would ignore under ``setting``: a campaign that
        dispersed it would record different inputs for identical runs."""
        if key in self.data:
            raise self.error(key, self.data[key], f"{setting} leaves this key unused (its value, or a campaign's "
                             f"dispersion of it, would change nothing); {what_to_do}")


def _likely_meant(key: str, known) -> list[str]:
    """Known keys a given key probably meant: the same name with a unit suffix (``duration`` for ``duration_s``),
    another unit (``duration_min``), or a close spelling."""
    if not isinstance(key, str):
        return []
    stem = key.rsplit("_", 1)[0]
    out = [k for k in known if k != key and (k.startswith(key + "_") or (k.rsplit("_", 1)[0] == stem and "_" in k
                                                                          and "_" in key))]
    return out or difflib.get_close_matches(key, [k for k in known if k != key], n=2, cutoff=0.8)


def _range_text(lo, hi, lo_open, hi_open) -> str:
    if lo is None and hi is None:
        return ""
    parts = []
    if lo is not None:
        parts.append(f"{'>' if lo_open else '>='} {lo:g}")
    if hi is not None:
        parts.append(f"{'<' if hi_open else '<='} {hi:g}")
    return " " + " and ".join(parts)



def rate(t: Table, key: str, step_s: float, default=MISSING) -> float:
    """A rate in Hz whose period is a whole number of dynamics steps (rates are exact ratios)."""
    hz = t.number(key, default, lo=0, lo_open=True, hi=1.0 / step_s)
    # Compared before dividing: hz * step_s may underflow to 0 for a tiny rate.
    if hz < 1.0 / (MAX_STEPS_PER_PERIOD * step_s):
        raise t.error(key, hz, f"a rate whose period is at most {MAX_STEPS_PER_PERIOD:g} dynamics steps "
                      f"({step_s:g} s), i.e. >= {1.0 / (MAX_STEPS_PER_PERIOD * step_s):.6g} Hz")
    ratio = 1.0 / (hz * step_s)
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise t.error(key, hz, f"a rate whose period is a whole number of dynamics steps ({step_s:g} s), "
                      f"e.g. {1.0 / step_s:g}, {0.5 / step_s:g} or {0.1 / step_s:g} Hz")
    return hz


def pair(t: Table, key: str, default, lo, hi, integer: bool) -> tuple:
    """A list of two numbers ``[x, y]``, each within ``[lo, hi]``."""
    value = t.raw(key, list(default))
    kind = "whole numbers" if integer else "numbers"
    ok = isinstance(value, list) and len(value) == 2 and all(
        not isinstance(v, bool) and isinstance(v, int if integer else int | float)
        and math.isfinite(v) and lo <= v <= hi for v in value)
    if not ok:
        raise t.error(key, value, f"a list of 2 {kind} [x, y], each from {lo:g} to {hi:g}")
    return tuple(int(v) if integer else float(v) for v in value)



def ticks_per(rate_hz: float, step_s: float) -> int:
    """Dynamics steps per period of a rate (validated to be whole by :func:`rate`)."""
    return max(1, round(NS_PER_S / rate_hz) // seconds_to_ns(step_s))


def unusable(v) -> bool:
    """A value with a non-finite or subnormal number or a NUL byte anywhere inside."""
    if isinstance(v, float):
        return not math.isfinite(v) or 0.0 < abs(v) < sys.float_info.min
    if isinstance(v, str):
        return "\x00" in v
    if isinstance(v, list):
        return any(unusable(x) for x in v)
    if isinstance(v, dict):
        return any(unusable(x) for x in v.values())
    return False

