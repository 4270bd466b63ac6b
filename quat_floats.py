"""The Hamilton product of scalar-first quaternions written out on floats: the one copy ``sim`` and ``drivers`` share.

It sits at the top of the package tree, beside ``compiled_paths``, because ``sim`` and ``drivers`` may not import each
other (the import contracts in pyproject.toml) and both compose quaternions of plain floats: the truth's steppers and
``sim.rotations``, and the emulated star tracker's attitude noise and misidentification. A numpy call on one
quaternion costs more than the arithmetic. It imports nothing.
"""

from __future__ import annotations


def hamilton(p, q) -> tuple:
    """Hamilton product ``p (x) q`` of scalar-first quaternions given as 4 floats (or 4 arrays of one shape) each."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    )
