"""Only the compiled part of the build; everything else about the package is in pyproject.toml.

Every module listed in ``compiled_paths.MODULES`` is compiled by Cython in pure-Python mode under its twin name
(``sim/body_step.py`` -> ``sim._body_step_compiled``): the same file, so the readable source is the compiled one,
and the plain module stays beside it for ``STAND_NATIVE=0`` (docs/fast_paths.md).

The build is optional: without a C compiler (or Cython) the install goes on and the stand runs the plain Python,
which gives the same bits (``summary.json``'s ``compiled_paths`` and ``stand bench loop`` say which ran).
``STAND_REQUIRE_COMPILED=1`` makes it required (CI sets it on a machine with a compiler). -ffp-contract=off and
-fno-fast-math keep the C compiler from fusing a multiply and an add into one FMA or reordering sums, and the Cython
directives keep Python's semantics for division and ``**`` (no cdivision, no C pow), so the results are Python's to
the bit.
"""

import os
import runpy
import shutil
from pathlib import Path

from setuptools import setup

HERE = Path(__file__).resolve().parent
REQUIRED = os.environ.get("STAND_REQUIRE_COMPILED", "").strip() not in ("", "0")
FLAGS = ["-ffp-contract=off", "-fno-fast-math"] if os.name == "posix" else []
#: Python's semantics, stated (they are Cython 3's defaults too): true division checks for zero and follows Python
#: for negative operands, ``**`` returns what Python returns.
DIRECTIVES = {"language_level": 3, "cdivision": False, "cpow": False, "infer_types": None}


#: Modules that call numpy's C random distributions (numpy/random/c_distributions.pxd): they compile against numpy's
#: headers and link its static ``libnpyrandom``, numpy's documented way to extend its random module.
NUMPY_RANDOM = {"numpy_draws"}


def _numpy_random_options() -> dict | None:
    """Where numpy's headers and ``libnpyrandom`` are; None without numpy in the build (those modules then stay plain
    Python, unless the build is required)."""
    try:
        import numpy
    except ImportError:
        if REQUIRED:
            raise
        return None
    return {"include_dirs": [numpy.get_include()],
            "library_dirs": [str(Path(numpy.__file__).parent / "random" / "lib")], "libraries": ["npyrandom"]}


def _extensions():
    """The Cython extensions of compiled_paths.MODULES, or [] when Cython is missing (and not required)."""
    paths = runpy.run_path(str(HERE / "compiled_paths.py"))
    try:
        from Cython.Build import cythonize
        from setuptools import Extension
    except ImportError:
        if REQUIRED:
            raise
        return []
    # The twin's source is a copy of the module under the twin's name (Cython names the module after its file);
    # it lives in the build tree only.
    stage = HERE / "build" / "cython"
    extensions = []
    for name in paths["MODULES"]:
        twin = paths["twin"](name)
        source = HERE / (name.replace(".", "/") + ".py")
        options = _numpy_random_options() if name in NUMPY_RANDOM else {}
        if options is None:
            continue
        target = stage / (twin.replace(".", "/") + ".py")
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, target)
        extensions.append(Extension(twin, [str(target.relative_to(HERE))], extra_compile_args=FLAGS, **options))
    compiled = cythonize(extensions, compiler_directives=DIRECTIVES, build_dir=str(stage / "c"), quiet=True)
    for extension in compiled:  # set after cythonize, which does not carry it over
        extension.optional = not REQUIRED
    return compiled


setup(ext_modules=_extensions(), py_modules=["compiled_paths", "quat_floats", "numpy_draws"])
