"""What a test needs from outside the stand: an independent oracle (astropy, skyfield-data, jplephem, sgp4, satkit,
allantools...) or a compiled path (a twin of compiled_paths.MODULES).

On a developer's machine that lacks an oracle the test is skipped, with the reason. Under CI (``CI`` set, as CI sets
it) the same lack is a failure: CI installs the test extra, so a missing oracle means the check it guards never ran,
and a green run would vouch for what nobody checked. A compiled path that did not build fails wherever a C compiler
is present (:func:`require_compiled`).
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


def require_compiled(name: str) -> ModuleType:
    """The compiled twin of ``name`` (one of ``compiled_paths.MODULES``), imported directly whatever ``STAND_NATIVE``
    says (a test compares it with the plain module).

    A missing twin is never a silent skip: it fails wherever a C compiler (``cc``) is on the PATH, since the install
    would then have built it; without a compiler it skips with the reason (-ra lists it)."""
    import compiled_paths

    twin = compiled_paths.twin(name)
    try:
        return importlib.import_module(twin)
    except ImportError as exc:
        reason = f"{twin} was not built ({exc}); pip install -e . compiles it when a C compiler is present"
        if shutil.which("cc"):
            pytest.fail(f"{reason}, and a C compiler ({shutil.which('cc')}) is here", pytrace=False)
        pytest.skip(reason)
        raise  # not reached


def build_fixtures(name: str) -> tuple:
    """Two pytest fixtures for the compiled path ``name``: ``compiled`` (its twin, :func:`require_compiled`) and
    ``build`` (the plain module, then the twin: a test taking it runs on both builds). In a test module:
    ``compiled, build = build_fixtures("sim.body_step")``."""

    @pytest.fixture(scope="module", name="compiled")
    def compiled() -> ModuleType:
        return require_compiled(name)

    @pytest.fixture(params=["python", "compiled"], name="build")
    def build(request) -> ModuleType:
        return importlib.import_module(name) if request.param == "python" else request.getfixturevalue("compiled")

    return compiled, build


def require_tool(command: str, package: str) -> str:
    """The path of the program ``command`` (a Debian package that `.ci/run` installs); skip locally, fail under CI,
    when it is not on the PATH."""
    path = shutil.which(command)
    if path is None:
        unavailable(f"{command} is not installed (apt-get install {package}, as .ci/run does)")
    return path
