"""Errors the stand reports to its users.

``ScenarioError`` is raised for anything wrong in a scenario file or its values. It carries the
dotted field name, the value given and what is allowed, and its message is one full sentence the
command line prints as is (exit code 2). Device failures come from ``drivers.errors``.
"""

from __future__ import annotations

import sys

#: Longest rendering of a value in an error message: a 60 MB value must not become a 60 MB sentence.
MAX_VALUE_CHARS = 200


def fail(message: str, prog: str = "stand") -> int:
    """Print one error sentence for the user and return the usage-error exit code (2)."""
    print(f"{prog}: error: {message}", file=sys.stderr)
    return 2


def shown(value) -> str:
    """``repr(value)``, cut to MAX_VALUE_CHARS."""
    text = repr(value)
    return text if len(text) <= MAX_VALUE_CHARS else f"{text[:MAX_VALUE_CHARS - 30]}... ({len(text)} characters)"


class ScenarioError(ValueError):
    """A scenario value is missing, of the wrong type or out of range."""

    def __init__(self, field: str, value, allowed: str, source: str | None = None):
        self.field = field
        self.value = value
        self.allowed = allowed
        self.source = source
        where = f" in {source}" if source else ""
        text = "missing" if value is _MISSING else shown(value)
        super().__init__(f"{field} = {text}{where} is not allowed: {allowed}.")


class _Missing:
    def __repr__(self) -> str:
        return "<missing>"


_MISSING = _Missing()
MISSING = _MISSING


def make_out_dir(path, option: str = "--out") -> None:
    """Make an output folder (and its parents; an existing one is fine), or raise a ScenarioError naming
    ``option``: the folder cannot be created, not some later figure (free disk, recording rate) measured on it."""
    from pathlib import Path

    p = Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise ScenarioError(option, str(p), "a directory (a file of that name is in the way)") from None
    except OSError as exc:
        raise ScenarioError(option, str(p), f"a folder the stand can create and write in "
                            f"({exc.strerror or exc})") from None
