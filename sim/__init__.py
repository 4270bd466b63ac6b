"""Pure physics for the stand: time, rotations, frames, orbit, attitude, environment, sensor and
actuator models, integrators.

Nothing here does I/O, starts threads or reads the wall clock; SI units inside (m, s, rad, kg,
N m, A m^2, T). Vectors are ``(..., 3)``, quaternions scalar-first ``(..., 4)``.
"""
