"""Errors the stand reports to its users.

``ScenarioError`` is raised for anything wrong in a scenario file or its values. It carries the
dotted field name, the value given and what is allowed, and its message is one full sentence the
command line prints as is (exit code 2). Device failures come from ``drivers.errors``.
"""

from __future__ import annotations


class ScenarioError(ValueError):
    """A scenario value is missing, of the wrong type or out of range."""

    def __init__(self, field: str, value, allowed: str, source: str | None = None):
        self.field = field
        self.value = value
        self.allowed = allowed
        self.source = source
        where = f" in {source}" if source else ""
        shown = "missing" if value is _MISSING else f"{value!r}"
        super().__init__(f"{field} = {shown}{where} is not allowed: {allowed}.")


class _Missing:
    def __repr__(self) -> str:
        return "<missing>"


_MISSING = _Missing()
MISSING = _MISSING
