"""Euler-angle kinematics 3-2-1 and 3-1-3 (the seed paper's), for comparison with the quaternion.

Angles follow ``sim.rotations.quat_from_euler(angles, seq)``: ``angles = (a1, a2, a3)`` rad about
the axes of ``seq`` in order, ``dcm = M_a3 M_a2 M_a1``. Rates from body rates omega_BN_B (rad/s):

3-2-1 (yaw a1, pitch a2, roll a3), singular at cos(a2) = 0 (pitch +-90 deg)::

    a1' = (w2 sin a3 + w3 cos a3) / cos a2
    a2' =  w2 cos a3 - w3 sin a3
    a3' =  w1 + (w2 sin a3 + w3 cos a3) tan a2

3-1-3 (precession a1, nutation a2, spin a3), singular at sin(a2) = 0 (nutation 0 or 180 deg)::

    a1' = (w1 sin a3 + w2 cos a3) / sin a2
    a2' =  w1 cos a3 - w2 sin a3
    a3' =  w3 - (w1 sin a3 + w2 cos a3) cos a2 / sin a2

Euler angles are never the integrated state of the stand (the quaternion is); this module exists
to report what the seed paper's choice costs. ``integrate_euler`` integrates the angles by RK4 from
a body-rate history sampled at half steps (e.g. a quaternion run at half the step), so both see
the same rates, and refuses or flags (``on_singularity``) once the middle angle enters the guard
band round the singularity: there the rates blow up as 1/cos(a2) or 1/sin(a2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .rotations import angle_between, euler_from_quat, quat_from_euler

SEQUENCES = ("321", "313")

#: Default guard band (rad): within 1 deg of the singular middle angle the rate gain exceeds 57.
GUARD_BAND_RAD = math.radians(1.0)


class EulerSingularityError(ValueError):
    """The Euler-angle path entered the guard band round its kinematic singularity."""


def _check_seq(seq: str) -> str:
    if seq not in SEQUENCES:
        raise ValueError(f"seq = {seq!r}; Euler kinematics are implemented for {', '.join(SEQUENCES)}.")
    return seq


def singularity_distance(angles, seq: str) -> np.ndarray:
    """Angular distance (rad) of the middle angle from the sequence's singular value(s)."""
    a2 = np.asarray(angles, dtype=float)[..., 1]
    if _check_seq(seq) == "321":
        return np.abs(math.pi / 2 - np.abs(a2))
    return np.minimum(np.abs(a2), np.abs(math.pi - a2))


def euler_rates(angles, omega_BN_B, seq: str) -> np.ndarray:
    """Angle rates (rad/s) for angles ``(..., 3)`` (rad) and body rates ``(..., 3)`` (rad/s)."""
    _check_seq(seq)
    a = np.asarray(angles, dtype=float)
    w = np.asarray(omega_BN_B, dtype=float)
    s2, c2 = np.sin(a[..., 1]), np.cos(a[..., 1])
    s3, c3 = np.sin(a[..., 2]), np.cos(a[..., 2])
    w1, w2, w3 = w[..., 0], w[..., 1], w[..., 2]
    if seq == "321":
        u = w2 * s3 + w3 * c3
        return np.stack((u / c2, w2 * c3 - w3 * s3, w1 + u * s2 / c2), axis=-1)
    u = w1 * s3 + w2 * c3
    return np.stack((u / s2, w1 * c3 - w2 * s3, w3 - u * c2 / s2), axis=-1)


@dataclass
class EulerRun:
    """Result of :func:`integrate_euler`: times (s), angles (rad), and where it stopped, if it did."""

    t: np.ndarray
    angles: np.ndarray
    stopped_at_s: float | None
    min_distance_rad: float


def integrate_euler(angles0, omega_half_steps, step_s: float, seq: str,
                    guard_band_rad: float = GUARD_BAND_RAD, on_singularity: str = "raise") -> EulerRun:
    """RK4 on the Euler angles from rates sampled every ``step_s / 2`` (shape (2N + 1, 3), rad/s).

    Returns angles at the N + 1 full steps. Within ``guard_band_rad`` of the singularity
    ``on_singularity="raise"`` raises :class:`EulerSingularityError` naming the time, the angle and
    the band; ``"flag"`` stops there and returns the run so far with ``stopped_at_s`` set (never
    NaN or infinity).
    """
    _check_seq(seq)
    if on_singularity not in ("raise", "flag"):
        raise ValueError(f"on_singularity = {on_singularity!r}; allowed: 'raise', 'flag'.")
    if not (math.isfinite(step_s) and step_s > 0):
        raise ValueError(f"step_s = {step_s!r}; the step must be a positive number of seconds.")
    w = np.asarray(omega_half_steps, dtype=float)
    if w.ndim != 2 or w.shape[1] != 3 or w.shape[0] % 2 != 1:
        raise ValueError(f"omega_half_steps must have shape (2N + 1, 3) (rates every step_s / 2); got {w.shape}.")
    a = np.asarray(angles0, dtype=float).copy()
    out = [a.copy()]
    h = step_s
    min_d = float(singularity_distance(a, seq))
    if min_d < guard_band_rad:
        if on_singularity == "raise":
            raise EulerSingularityError(
                f"{seq} Euler angles start inside the guard band: the middle angle is "
                f"{math.degrees(float(a[1])):.6g} deg, {math.degrees(min_d):.3g} deg from the singularity "
                f"(band {math.degrees(guard_band_rad):.3g} deg). Use the quaternion."
            )
        return EulerRun(np.zeros(1), a[None, :], 0.0, min_d)
    stopped = None
    for k in range((w.shape[0] - 1) // 2):
        w0, wm, w1 = w[2 * k], w[2 * k + 1], w[2 * k + 2]
        k1 = euler_rates(a, w0, seq)
        k2 = euler_rates(a + 0.5 * h * k1, wm, seq)
        k3 = euler_rates(a + 0.5 * h * k2, wm, seq)
        k4 = euler_rates(a + h * k3, w1, seq)
        a_new = a + h / 6.0 * (k1 + 2.0 * (k2 + k3) + k4)
        d = float(singularity_distance(a_new, seq))
        if d < guard_band_rad or not np.all(np.isfinite(a_new)):
            t_hit = (k + 1) * h
            if on_singularity == "raise":
                raise EulerSingularityError(
                    f"{seq} Euler angles reached the guard band at t = {t_hit:.6g} s: the middle angle "
                    f"is {math.degrees(float(a_new[1])):.6g} deg, {math.degrees(d):.3g} deg from the "
                    f"singularity (band {math.degrees(guard_band_rad):.3g} deg), where the angle rates "
                    "grow without bound. Use the quaternion, or on_singularity='flag' to stop here."
                )
            stopped = t_hit - h
            break
        min_d = min(min_d, d)
        a = a_new
        out.append(a.copy())
    angles = np.array(out)
    return EulerRun(np.arange(len(angles)) * h, angles, stopped, min_d)


def error_against_quaternion(run: EulerRun, q_BN, seq: str) -> np.ndarray:
    """Attitude error (rad) of an Euler run against quaternions ``q_BN`` at the same times."""
    q = np.asarray(q_BN, dtype=float)[: len(run.t)]
    return angle_between(quat_from_euler(run.angles, seq), q)


def compare_with_quaternion(inertia, q_BN, omega_BN_B, duration_s: float, step_s: float, seq: str,
                            guard_band_rad: float = GUARD_BAND_RAD, on_singularity: str = "raise",
                            torque=None) -> dict:
    """Run the quaternion (RK4 at ``step_s / 2``) and feed its rates to the Euler angles at ``step_s``.

    Returns ``{"t", "error_rad", "max_error_deg", "stopped_at_s", "min_distance_deg"}``: the
    Euler run's attitude error against the quaternion run at every full step.
    """
    from .attitude import propagate

    t, q, w = propagate(inertia, q_BN, omega_BN_B, duration_s, 0.5 * step_s, torque=torque)
    if len(t) % 2 == 0:
        t, q, w = t[:-1], q[:-1], w[:-1]  # a trailing half step has no full step to land on
    a0 = euler_from_quat(q[0], seq)
    run = integrate_euler(a0, w, step_s, seq, guard_band_rad, on_singularity)
    err = error_against_quaternion(run, q[::2], seq)
    return {"t": run.t, "error_rad": err, "max_error_deg": float(np.degrees(np.max(err))),
            "stopped_at_s": run.stopped_at_s, "min_distance_deg": math.degrees(run.min_distance_rad)}
