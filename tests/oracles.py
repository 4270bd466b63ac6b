"""What a test needs from outside the stand: an independent oracle (astropy, skyfield-data, jplephem, sgp4, satkit,
allantools...) or a compiled path (sim._native, drivers._bitpack).

On a developer's machine that lacks one the test is skipped, with the reason. Under CI (``CI`` set, as CI sets it)
the same lack is a failure: CI installs the test extra and has a C compiler, so a missing oracle or a build that did
not compile means the check it guards never ran, and a green run would vouch for what nobody checked.
"""

from __future__ import annotations

import importlib
import os
import shutil
from types import ModuleType

import pytest


def in_ci() -> bool:
    """True under CI: ``CI`` set to anything but empty, ``0`` or ``false``."""
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false")


def unavailable(reason: str) -> None:
    """Skip the test with ``reason``; under CI fail it instead (never returns)."""
    if in_ci():
        pytest.fail(f"CI: {reason} (a skip here would hide an unchecked result)", pytrace=False)
    pytest.skip(reason, allow_module_level=True)


def require(module: str, what: str = "the test extra") -> ModuleType:
    """Import and return ``module``, an independent oracle; skip locally, fail under CI, when it does not import."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        unavailable(f"{module} does not import ({exc}); it comes with {what}: pip install -e '.[test]'")
        raise  # not reached: unavailable() always raises


def require_compiled(native: str, extension: str) -> None:
    """Go on only when the compiled path runs (``native`` is the module's ``NATIVE``, ``extension`` its C module).

    ``STAND_NATIVE=0`` asks for the Python original on purpose: skipped everywhere. Otherwise a build that did not
    compile skips locally, and fails under CI when a C compiler (``cc``) is on the PATH, since setup.py would then
    have built it."""
    if native == "compiled":
        return
    if os.environ.get("STAND_NATIVE", "1") == "0":
        pytest.skip(f"STAND_NATIVE=0 asks for the Python original, not {extension}")
    reason = f"{extension} was not built (pip install -e . compiles it when a C compiler is present)"
    if in_ci() and shutil.which("cc"):
        pytest.fail(f"CI: {reason}, although a C compiler ({shutil.which('cc')}) is here", pytrace=False)
    pytest.skip(reason)


def require_tool(command: str, package: str) -> str:
    """The path of the program ``command`` (a Debian package that `.ci/run` installs); skip locally, fail under CI,
    when it is not on the PATH."""
    path = shutil.which(command)
    if path is None:
        unavailable(f"{command} is not installed (apt-get install {package}, as .ci/run does)")
    return path
