"""Only the compiled part of the build; everything else about the package is in pyproject.toml.

Two small C extensions, each equal to a Python original to the bit (docs/fast_paths.md):

* ``sim._native`` (sim/_native.c): the default scenario's attitude step (sim.truth.rk4_magnetic_gg);
* ``drivers._bitpack`` (drivers/_bitpack.c): the DBC codec's per-message fast path (drivers.dbc.MessagePacker).

Both are optional: without a C compiler the install goes on and the stand runs the Python originals
(``stand bench loop`` says which ran; ``STAND_NATIVE=0`` asks for Python). -ffp-contract=off keeps the compiler from
fusing a multiply and an add into one FMA, which would change the last bit of the results.
"""

import os

from setuptools import Extension, setup

flags = ["-ffp-contract=off", "-fno-fast-math"] if os.name == "posix" else []
setup(ext_modules=[
    Extension("sim._native", ["sim/_native.c"], extra_compile_args=flags, optional=True),
    Extension("drivers._bitpack", ["drivers/_bitpack.c"], extra_compile_args=flags, optional=True),
])
