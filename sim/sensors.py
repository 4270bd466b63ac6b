"""Sensor models: coarse (cosine) sun-sensor heads, a two-axis fine sun sensor, a three-axis rate gyro.

Sun sensors: inputs are the Sun direction in the body frame (``sHat_B``, unit, ``(..., 3)``, e.g.
``dcm(q_BN) @ unit(r_sun_N - r_sat_N)``) and the visible fraction of the Sun's disk
(``nu`` from :func:`sim.environment.shadow_fraction`: 1 full sun, 0 umbra), so eclipse and
penumbra dim every head. Noise comes only from the ``numpy.random.Generator`` passed in; with
``rng=None`` the output is noise-free. Earth albedo is not modelled (it adds up to ~30 % of the
Sun's signal to a nadir-facing coarse head; a known limitation).
"""

from __future__ import annotations

import math
from bisect import bisect_left
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

import compiled_paths

__all__ = ["CoarseSunSensors", "DelayLine", "FineSunSensor", "Gyro", "GyroState", "gauss_markov_adev"]

_draws = compiled_paths.load("numpy_draws")  # a sample's 9 draws without the Generator's Python-facing layers


def _unit_rows(v, name: str) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if v.shape[-1:] != (3,) or np.any(n == 0) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be finite non-zero vectors of shape (..., 3); got shape {v.shape}.")
    return v / n


@dataclass(frozen=True)
class CoarseSunSensors:
    """Cosine-law photodiode heads: ``I_k = I_max nu max(0, n_k . sHat_B) + noise``, clipped at 0.

    ``normals_B``: ``(k, 3)`` head normals in the body frame; ``i_max_A``: current at normal
    incidence in full sun (A); ``noise_A``: 1-sigma white noise (A); ``cutoff_deg``: incidence
    beyond which a head reads 0 (its housing; 90 is the bare cosine law).
    """

    normals_B: np.ndarray
    i_max_A: float = 1e-3
    noise_A: float = 0.0
    cutoff_deg: float = 90.0

    def __post_init__(self):
        object.__setattr__(self, "normals_B", _unit_rows(np.atleast_2d(self.normals_B), "normals_B"))
        if not (np.isfinite(self.i_max_A) and self.i_max_A > 0):
            raise ValueError(f"coarse sun sensor i_max_A = {self.i_max_A!r} must be a finite positive current.")
        if not (np.isfinite(self.noise_A) and self.noise_A >= 0):
            raise ValueError(f"coarse sun sensor noise_A = {self.noise_A!r} must be finite and >= 0.")
        if not 0 < self.cutoff_deg <= 90:
            raise ValueError(f"coarse sun sensor cutoff_deg = {self.cutoff_deg!r} is outside (0, 90].")

    def measure(self, sHat_B, nu, rng: np.random.Generator | None = None) -> np.ndarray:
        """Head currents (A), shape ``(..., k)``."""
        s = _unit_rows(sHat_B, "sHat_B")
        cosang = s @ self.normals_B.T
        lit = cosang >= np.cos(np.radians(self.cutoff_deg)) - 1e-15
        i = self.i_max_A * np.asarray(nu, dtype=float)[..., None] * np.where(lit, np.maximum(cosang, 0.0), 0.0)
        if rng is not None and self.noise_A > 0:
            i = i + rng.normal(0.0, self.noise_A, size=i.shape)
        return np.maximum(i, 0.0)

    def estimate_sun_B(self, currents_A) -> np.ndarray:
        """Least-squares Sun direction (unit, body) from head currents; needs >= 3 lit heads spanning 3D."""
        c = np.asarray(currents_A, dtype=float)
        x, *_ = np.linalg.lstsq(self.normals_B, c.T, rcond=None)
        x = x.T
        return x / np.linalg.norm(x, axis=-1, keepdims=True)


@dataclass(frozen=True)
class FineSunSensor:
    """Two-axis fine sun sensor, boresight +z of its frame: angles ``alpha = atan2(s_x, s_z)``,
    ``beta = atan2(s_y, s_z)`` (rad) with white noise ``noise_rad``; valid only with the Sun
    within ``fov_half_deg`` of the boresight and ``nu >= min_fraction`` (it needs a bright enough
    spot: penumbra below that and umbra read invalid, angles NaN).

    ``dcm_SB``: body -> sensor frame (from the mount quaternion).
    """

    dcm_SB: np.ndarray
    fov_half_deg: float = 60.0
    noise_rad: float = 0.0
    min_fraction: float = 0.5

    def __post_init__(self):
        d = np.asarray(self.dcm_SB, dtype=float)
        if d.shape != (3, 3) or not np.allclose(d @ d.T, np.eye(3), atol=1e-9) or np.linalg.det(d) < 0:
            raise ValueError("fine sun sensor dcm_SB must be a 3x3 proper rotation matrix.")
        object.__setattr__(self, "dcm_SB", d)
        if not 0 < self.fov_half_deg < 90:
            raise ValueError(f"fine sun sensor fov_half_deg = {self.fov_half_deg!r} is outside (0, 90).")
        if not (np.isfinite(self.noise_rad) and self.noise_rad >= 0):
            raise ValueError(f"fine sun sensor noise_rad = {self.noise_rad!r} must be finite and >= 0.")
        if not 0 < self.min_fraction <= 1:
            raise ValueError(f"fine sun sensor min_fraction = {self.min_fraction!r} is outside (0, 1].")

    def measure(self, sHat_B, nu, rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(angles (..., 2) rad, valid (...) bool)``; invalid samples carry NaN angles."""
        s = _unit_rows(sHat_B, "sHat_B") @ self.dcm_SB.T
        valid = (s[..., 2] >= np.cos(np.radians(self.fov_half_deg))) & (np.asarray(nu) >= self.min_fraction)
        ang = np.stack((np.arctan2(s[..., 0], s[..., 2]), np.arctan2(s[..., 1], s[..., 2])), axis=-1)
        if rng is not None and self.noise_rad > 0:
            ang = ang + rng.normal(0.0, self.noise_rad, size=ang.shape)
        return np.where(valid[..., None], ang, np.nan), valid


# -- gyro ------------------------------------------------------------------------------------------

#: Allan deviation of flicker (bias-instability) noise: sigma(tau) = sqrt(2 ln 2 / pi) B, flat in tau.
FLICKER_ADEV_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)
#: The Allan deviation of a first-order Gauss-Markov process of standard deviation s and correlation
#: time T peaks at tau = 1.8926 T with the value 0.61736 s (the maximum of gauss_markov_adev).
GM_PEAK_TAU_OVER_T = 1.8926178601723587
GM_PEAK_ADEV_OVER_SIGMA = 0.6173642831444414


def gauss_markov_adev(tau_s, sigma, correlation_s):
    """Allan deviation of a first-order Gauss-Markov rate (std ``sigma``, correlation ``correlation_s``).

    With x = tau / T: AVAR = sigma^2 / x^2 (2 x - 3 + 4 e^-x - e^-2x), the exponentially correlated
    noise term of IEEE Std 952 Annex C with (q_c T_c)^2 = 2 sigma^2 T.
    """
    x = np.asarray(tau_s, dtype=float) / correlation_s
    # Series for small x (the process looks like a rate random walk there): the closed form loses
    # digits to cancellation.
    small = x < 1e-3
    xs = np.where(small, 1.0, x)
    avar = np.where(small, x * (2.0 / 3.0 - x / 2.0 + 7.0 * x * x / 30.0),
                    (2.0 * xs - 3.0 + 4.0 * np.exp(-xs) - np.exp(-2.0 * xs)) / (xs * xs))
    return sigma * np.sqrt(avar)


class GyroState(NamedTuple):
    """The gyro's slowly varying biases after the last sample (rad/s, sensor axes): 3 floats each, an array
    after a batch of samples, a tuple after one; either is taken back."""

    rate_random_walk: np.ndarray | tuple
    gauss_markov: np.ndarray | tuple


def _vec3(value, name: str) -> np.ndarray:
    v = np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()
    if not np.all(np.isfinite(v)):
        raise ValueError(f"gyro {name} = {value!r} must be finite (a number or 3 numbers).")
    return v


@dataclass(frozen=True)
class Gyro:
    """Three-axis rate gyro sampled every ``sample_period_s``; output in sensor axes (rad/s).

    ``omega_S = Q(sat((I + diag(scale_factor) + misalignment) dcm_SB omega_BN_B + b0 + b_rrw + b_gm + n))``

    - ``arw_rad_sqrt_s`` N, angle random walk: white rate noise of density N, so one sample (the
      average over a period dt) has sigma N / sqrt(dt) and the Allan deviation is N / sqrt(tau).
    - ``rrw_rad_s_sqrt_s`` K, rate random walk: b_rrw steps by K sqrt(dt) per sample; Allan
      deviation K sqrt(tau / 3).
    - ``bias_instability_rad_s`` B with ``bias_correlation_s`` T: the flicker floor 0.664 B of the
      Allan deviation, approximated by a first-order Gauss-Markov bias whose Allan deviation peaks
      at that value at tau = 1.89 T (sigma_gm = 0.664 B / 0.617); its first value is drawn from its
      stationary distribution.
    - ``bias_rad_s`` b0 (turn-on bias), ``scale_factor`` (fraction, per axis), ``misalignment`` (3x3
      small angles, rad, zero diagonal: row i = how much of the other axes sensor axis i sees).
    - ``lsb_rad_s`` quantisation (0 = none), ``range_rad_s`` saturation per axis.
    - ``delay_s``: the output at time t measures the rate at t - delay_s; the caller samples the
      truth there (:class:`DelayLine` keeps the history).
    - ``dcm_SB``: body -> sensor axes (from the mount quaternion).

    :meth:`measure` is vectorised over consecutive samples and draws from the Generator it is given
    in one fixed order (9 normals per sample), so measuring n samples at once or one at a time
    gives identical output.
    """

    sample_period_s: float = 0.01
    arw_rad_sqrt_s: float = 0.0
    rrw_rad_s_sqrt_s: float = 0.0
    bias_instability_rad_s: float = 0.0
    bias_correlation_s: float = 100.0
    bias_rad_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale_factor: np.ndarray = field(default_factory=lambda: np.zeros(3))
    misalignment: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    lsb_rad_s: float = 0.0
    range_rad_s: float = math.inf
    delay_s: float = 0.0
    dcm_SB: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        for name in ("sample_period_s", "bias_correlation_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"gyro {name} = {v!r} must be a finite number > 0.")
        for name in ("arw_rad_sqrt_s", "rrw_rad_s_sqrt_s", "bias_instability_rad_s", "lsb_rad_s", "delay_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"gyro {name} = {v!r} must be a finite number >= 0.")
        if not (self.range_rad_s > 0):
            raise ValueError(f"gyro range_rad_s = {self.range_rad_s!r} must be > 0 (inf for no saturation).")
        object.__setattr__(self, "bias_rad_s", _vec3(self.bias_rad_s, "bias_rad_s"))
        sf = _vec3(self.scale_factor, "scale_factor")
        if np.any(np.abs(sf) >= 0.5):
            raise ValueError(f"gyro scale_factor = {self.scale_factor!r} is a fraction; |each| must be below 0.5.")
        object.__setattr__(self, "scale_factor", sf)
        m = np.asarray(self.misalignment, dtype=float)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)) or np.any(np.diag(m) != 0) or np.any(np.abs(m) >= 0.1):
            raise ValueError("gyro misalignment must be a finite 3x3 matrix of small angles (|each| < 0.1 rad) with "
                             f"a zero diagonal (the scale factor is separate); got {self.misalignment!r}.")
        object.__setattr__(self, "misalignment", m)
        d = np.asarray(self.dcm_SB, dtype=float)
        if d.shape != (3, 3) or not np.allclose(d @ d.T, np.eye(3), atol=1e-9) or np.linalg.det(d) < 0:
            raise ValueError("gyro dcm_SB must be a 3x3 proper rotation matrix.")
        object.__setattr__(self, "dcm_SB", d)
        # Derived once: the loop measures one sample per tick.
        object.__setattr__(self, "_input_T", ((np.eye(3) + np.diag(sf) + m) @ d).T.copy())
        x = self.sample_period_s / self.bias_correlation_s
        gm_step = self.gauss_markov_sigma_rad_s * math.sqrt(-math.expm1(-2.0 * x))
        object.__setattr__(self, "_gm", (math.exp(-x), gm_step))
        object.__setattr__(self, "_white", self.arw_rad_sqrt_s / math.sqrt(self.sample_period_s))
        object.__setattr__(self, "_walk", self.rrw_rad_s_sqrt_s * math.sqrt(self.sample_period_s))
        object.__setattr__(self, "_bias_floats", tuple(self.bias_rad_s.tolist()))

    @property
    def gauss_markov_sigma_rad_s(self) -> float:
        """Standard deviation of the Gauss-Markov bias that stands in for bias instability."""
        return FLICKER_ADEV_FACTOR * self.bias_instability_rad_s / GM_PEAK_ADEV_OVER_SIGMA

    @property
    def input_matrix(self) -> np.ndarray:
        """``(I + diag(scale_factor) + misalignment) dcm_SB``: body rate -> sensor reading."""
        return (np.eye(3) + np.diag(self.scale_factor) + self.misalignment) @ self.dcm_SB

    def initial_state(self, rng: np.random.Generator | None) -> GyroState:
        """Biases at power-up: no rate random walk yet; the Gauss-Markov bias drawn from its
        stationary distribution (zero without a Generator)."""
        gm = np.zeros(3) if rng is None else rng.standard_normal(3) * self.gauss_markov_sigma_rad_s
        return GyroState(np.zeros(3), gm)

    def errors(self, n: int, rng: np.random.Generator | None, state: GyroState) -> tuple[np.ndarray, GyroState]:
        """Bias plus noise of ``n`` consecutive samples, ``(n, 3)`` rad/s, and the state after them."""
        if n == 1:  # one sample per tick in the loop: the same arithmetic in the same order, on floats
            err, state = self._one(rng, state)
            return np.array(err)[None, :], state
        out = np.broadcast_to(self.bias_rad_s, (n, 3)).copy()
        if rng is None:
            return out + state.rate_random_walk + state.gauss_markov, state
        w = rng.standard_normal((n, 3, 3))
        if self.arw_rad_sqrt_s > 0:
            out += w[:, 0, :] * self._white
        rrw = state.rate_random_walk
        if self.rrw_rad_s_sqrt_s > 0:
            # cumsum over [state, steps...] so chunks of any size give identical sums
            steps = np.vstack((rrw, w[:, 1, :] * self._walk))
            walk = np.cumsum(steps, axis=0)[1:]
            rrw = walk[-1].copy()
            out += walk
        else:
            out += rrw
        gm = np.asarray(state.gauss_markov, dtype=float)
        if self.bias_instability_rad_s > 0:
            # scipy.signal takes about half a second to import: only a batch of samples with bias instability
            # needs it, not a run's one sample per tick
            from scipy.signal import lfilter

            phi, c = self._gm
            # b_k = phi b_(k-1) + c w_k, the exact discretisation of the continuous process
            series, _ = lfilter([c], [1.0, -phi], w[:, 2, :], axis=0, zi=(phi * gm)[None, :])
            gm = series[-1].copy()
            out += series
        else:
            out += gm
        return out, GyroState(rrw, gm)

    def _one(self, rng: np.random.Generator | None, state: GyroState) -> tuple[tuple, GyroState]:
        """Bias plus noise of one sample (3 floats) and the state after it: the arithmetic of :meth:`errors` in the
        same order, from the same 9 draws, on floats."""
        bx, by, bz = self._bias_floats
        rx, ry, rz = map(float, state.rate_random_walk)  # floats, also from an array state
        gx, gy, gz = map(float, state.gauss_markov)
        if rng is None:
            return (bx + rx + gx, by + ry + gy, bz + rz + gz), state
        n0, n1, n2, n3, n4, n5, n6, n7, n8 = _draws.standard_normal(rng, 9)
        if self.arw_rad_sqrt_s > 0:
            white = self._white
            bx, by, bz = bx + n0 * white, by + n1 * white, bz + n2 * white
        if self.rrw_rad_s_sqrt_s > 0:
            walk = self._walk
            rx, ry, rz = rx + n3 * walk, ry + n4 * walk, rz + n5 * walk
        if self.bias_instability_rad_s > 0:
            phi, c = self._gm
            gx, gy, gz = c * n6 + phi * gx, c * n7 + phi * gy, c * n8 + phi * gz
        return (bx + rx + gx, by + ry + gy, bz + rz + gz), GyroState((rx, ry, rz), (gx, gy, gz))

    def measure(self, omega_BN_B, rng: np.random.Generator | None, state: GyroState | None = None):
        """Readings of consecutive samples: ``(omega_S, saturated, state)``.

        ``omega_BN_B``: ``(3,)`` or ``(n, 3)`` true body rates (rad/s) at the samples' measurement
        times (output time minus ``delay_s``); ``omega_S`` has the same shape, ``saturated`` is a
        bool array of that shape (the axis was clipped at ``range_rad_s``). ``state`` defaults to
        :meth:`initial_state`; pass the returned one to the next call.
        """
        w = np.asarray(omega_BN_B, dtype=float)
        if w.shape[-1:] != (3,) or w.ndim > 2 or not np.all(np.isfinite(w)):
            raise ValueError(f"gyro omega_BN_B must be finite rates of shape (3,) or (n, 3); got shape {w.shape}.")
        if w.ndim == 1:
            y1, saturated1, state = self.measure_one(w.tolist(), rng, state)
            return np.array(y1), np.array(saturated1), state
        if state is None:
            state = self.initial_state(rng)
        w2 = np.atleast_2d(w)
        err, state = self.errors(len(w2), rng, state)
        y = w2 @ self._input_T + err
        saturated = np.abs(y) > self.range_rad_s
        y = np.clip(y, -self.range_rad_s, self.range_rad_s)
        if self.lsb_rad_s > 0:
            y = np.round(y / self.lsb_rad_s) * self.lsb_rad_s
        return y, saturated, state

    def measure_one(self, omega_BN_B, rng: np.random.Generator | None, state: GyroState | None = None):
        """One reading, ``(omega_S, saturated, state)`` as 3 floats and 3 bools: what :meth:`measure` gives for
        one sample, bit for bit (the loop measures one sample per tick, on floats).

        ``omega_BN_B``: 3 finite floats, the true body rate (rad/s) at the measurement time."""
        wx, wy, wz = omega_BN_B
        if not (math.isfinite(wx) and math.isfinite(wy) and math.isfinite(wz)):
            raise ValueError(f"gyro omega_BN_B must be finite rates; got {omega_BN_B!r}.")
        if state is None:
            state = self.initial_state(rng)
        (ex, ey, ez), state = self._one(rng, state)
        # The input matrix stays one numpy product: BLAS may fuse its multiplies and adds, and one sample must
        # read exactly as it does in a batch.
        mx, my, mz = (np.array((wx, wy, wz)) @ self._input_T).tolist()
        x, y, z = mx + ex, my + ey, mz + ez
        r = self.range_rad_s
        saturated = (abs(x) > r, abs(y) > r, abs(z) > r)
        x, y, z = min(max(x, -r), r), min(max(y, -r), r), min(max(z, -r), r)
        lsb = self.lsb_rad_s
        if lsb > 0:
            x, y, z = round(x / lsb) * lsb, round(y / lsb) * lsb, round(z / lsb) * lsb
        return (x, y, z), saturated, state


class DelayLine:
    """The history of a sampled signal, read back at an earlier time by linear interpolation.

    ``push(t_s, x)`` appends a sample (times increasing); ``at(t_s)`` interpolates between the two
    samples around ``t_s`` (the oldest kept sample before the history starts). Keeps what covers
    ``span_s`` behind the newest sample. Pure: no clock; the caller passes sim times.
    """

    def __init__(self, span_s: float) -> None:
        if not (math.isfinite(span_s) and span_s >= 0):
            raise ValueError(f"DelayLine span_s = {span_s!r} must be a finite number >= 0.")
        self.span_s = float(span_s)
        self._t: list[float] = []
        self._x: list[tuple] = []

    def push(self, t_s: float, x) -> None:
        if self._t and not t_s > self._t[-1]:
            raise ValueError(f"DelayLine.push: t_s = {t_s!r} must be after the last sample at {self._t[-1]!r}.")
        self._t.append(float(t_s))
        self._x.append(tuple(map(float, x)))
        cut = 0
        while cut + 1 < len(self._t) and self._t[cut + 1] <= t_s - self.span_s:
            cut += 1
        if cut:
            del self._t[:cut], self._x[:cut]

    def at(self, t_s: float) -> tuple:
        """The signal at ``t_s``, a tuple of floats."""
        if not self._t:
            raise ValueError("DelayLine.at: no sample has been pushed yet.")
        t = self._t
        if t_s <= t[0]:
            return self._x[0]
        if t_s >= t[-1]:
            return self._x[-1]
        i = bisect_left(t, t_s)
        f = (t_s - t[i - 1]) / (t[i] - t[i - 1])
        return tuple([a + f * (b - a) for a, b in zip(self._x[i - 1], self._x[i], strict=True)])
