"""Emulator: the stand *being* the serial star tracker, on any port (URL, pty, open serial object).

It serves the ICD (``fixtures/devices/star_tracker.toml``) through the same codec as the host
driver and knows no physics: the stand hands it ``measurement_source(t_s) -> TrackerTruth``, the
TRUE attitude of the tracker frame T (+z boresight) relative to GCRS at sim time ``t_s``, the rate
``omega_TN_T`` and the Sun/Moon/Earth directions in tracker axes with their angular radii. The
source is called with exposure times, which lie at most one service step before the current
service time (answer with the current state or interpolate).

Behaviour (times are sim seconds passed to :meth:`StarTrackerEmulator.service`; the emulator
reads no clock there; :meth:`StarTrackerEmulator.run` is the stand-alone wall-clock loop):

- Power-up at the first service time in mode BOOT; with ``auto_boot`` (default) the application
  starts at once, otherwise on the BOOT action; it is ready ``boot_time_s`` later, in
  LOST_IN_SPACE. A BOOT action while running reboots (mode BOOT, stable count 0).
- Exposures every ``output_interval_s`` from the time the application is ready; the solution of an
  exposure (mid-exposure time ``t_e``) is computed from ``measurement_source(t_e)`` and becomes
  available ``output_delay_s`` later. Its time stamp is ``t_e`` in the DEVICE clock:
  ``clock_offset_s + t_e * (1 + clock_drift_ppm 1e-6)`` until a SET_TIME action sets it
  (then ``T_set + (t_e - t_set) * (1 + drift)``, and ``time_synced`` is set).
- Measured attitude: ``q_meas = q_TN (x) dq`` (Hamilton, so ``dcm(q_meas) = dcm(dq) dcm(q_TN)``)
  where ``dq`` is the rotation vector ``bias + (s_c n1, s_c n2, s_r n3)`` in tracker axes, ``n``
  standard normal from the emulator's Generator, ``s_c``/``s_r`` the cross-boresight and roll sigmas.
- Flags per exposure: a body is in the field when the angle from the boresight to its centre
  minus its angular radius is below its exclusion half-angle; the Sun blinds the detector (no
  star matched); ``rate_too_high`` when ``|omega_TN_T|`` exceeds the rate limit. Stars centroided:
  ``truth.stars_in_field`` or Poisson(``mean_stars``); matched: Binomial(centroided,
  ``match_probability``). An exposure is good when no body is in the field, the rate is within the
  limit and at least ``min_stars_matched`` stars matched.
- State machine: a good exposure adds one to ``stable_count``, a bad one zeroes it. LOST_IN_SPACE
  turns to TRACKING when ``stable_count`` reaches the configured count; TRACKING falls back to
  LOST_IN_SPACE after ``track_loss_count`` bad exposures in a row. ``valid`` = good and TRACKING.
- Requests: REQUEST_TELEMETRY(SOLUTION) returns the newest available solution (NACK NOT_READY
  before the first one); STATUS any time. SUBSCRIBE publishes SOLUTION/STATUS every period
  (0 = each new solution). Parameters from the ICD table are set and read by SET/GET_PARAM.
- Frames with bad CRC, another address, unknown id, wrong length, bad escapes or oversize are
  counted, never raised; frames for another address are ignored silently (a shared bus).
- Never blocks the caller's thread: each :meth:`StarTrackerEmulator.service` reads at most
  ``max_read_bytes`` (a flood waits for the next call), and replies go through a transmit queue of
  at most ``max_tx_bytes`` written only as far as the port takes them at once
  (:func:`drivers.serial_port.write_available`). A frame that does not fit in the queue is dropped
  whole and counted (``tx_dropped``), as a real device's UART buffer overflows when nobody reads
  the line; ``sent`` counts frames written completely.

Faults (attributes, neutral by default, set at any time; they act from the next exposure):

- ``blinded``: every exposure sees the Sun in the field (flag ``sun_in_field``, no star matched, not valid);
- ``lost``: no star is identified: the solution carries no attitude (the identity quaternion), no star
  matched, mode LOST_IN_SPACE at once, not valid; once cleared the tracker reacquires as from lost in space;
- ``misid_rad``: a rotation vector (rad, tracker axes) composed onto the measured attitude, which keeps its
  flags (misidentified stars: off by ``|misid_rad|``, still valid when the exposure is good);
- ``solution_delay_s``: each solution becomes available this much later than ``output_delay_s`` (late);
- ``slow_factor``: a whole number >= 1: exposures ``slow_factor`` times the output interval apart (a lower
  rate), the grid anchored at the last exposure.

Clock faults and reboot: :mod:`drivers.device_faults`. A reboot is a power cycle: off (deaf and silent) for
``boot_s``, then a power-up as above (mode BOOT for ``boot_time_s`` with ``auto_boot``), the parameters and
subscriptions back to their power-up values (the ICD: a subscription lasts until UNSUBSCRIBE or a reboot, so the
host must subscribe again), solution counter and STATUS counters from 0, the clock restarted at
``clock_offset_s`` and not synchronised.

``counters``: ``bytes_received``, ``frames_received`` (good, for this address), ``sent``,
``rejected_crc``, ``rejected_address``, ``rejected_unknown_id``, ``rejected_length``,
``rejected_other`` (short, bad escape, oversize, bad value), ``commands_nacked``, ``solutions``,
``exposures_skipped``, ``published``, ``tx_dropped``. Each frame rejected counts once, in one ``rejected_*``
counter; :attr:`StarTrackerEmulator.rejected_frames` is their sum without ``rejected_address`` (frames for
another device are not bad), and ``last_rejected`` says why the latest one was dropped.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

import compiled_paths
from drivers.device_faults import DeviceFaults
from drivers.errors import DriverError, EncodeError
from drivers.framing import SlipDecoder, escape
from drivers.serial_port import SerialServer, is_port_error, open_port, port_name, write_available
from drivers.star_tracker.codec import (
    DEVICE_TO_HOST,
    HOST_TO_DEVICE,
    Ack,
    Action,
    FrameRejected,
    GetParam,
    Message,
    Nack,
    ParamValue,
    RequestTelemetry,
    SetParam,
    Solution,
    StarTrackerCodec,
    Status,
    Subscribe,
    Unsubscribe,
)
from drivers.star_tracker.measurement import (
    ARCSEC,
    PARAM_FROM_CONFIG,
    EmulatorConfig,
    MeasurementSource,
    TrackerTruth,
    checked_truth,
    hamilton,
    in_field,
    small_rotation,
)

_draws = compiled_paths.load("numpy_draws")  # the Generator's draws without its Python-facing layers

__all__ = ["EmulatorConfig", "MeasurementSource", "StarTrackerEmulator", "TrackerTruth"]

_EPS_S = 1e-9
_U64_MAX = 0xFFFF_FFFF_FFFF_FFFF


class StarTrackerEmulator(DeviceFaults, SerialServer):
    """The star tracker, emulated on ``port`` (see the module docstring for the behaviour).

    Args:
        port: URL/path (opened with pyserial and closed by :meth:`close`) or an open port object
            (``serial.Serial``, :class:`~drivers.serial_port.FdPort`; the caller keeps it).
        measurement_source: ``measurement_source(t_s) -> TrackerTruth``.
        config: :class:`EmulatorConfig`.
        rng: a ``numpy.random.Generator`` or a seed.
        codec: a :class:`StarTrackerCodec` (default: the ICD in ``fixtures/``).
        baudrate: for URL ports.
        max_read_bytes: most bytes read per :meth:`service`.
        max_tx_bytes: most bytes waiting to be written; a reply that does not fit is dropped.
    """

    def __init__(
        self,
        port: Any,
        measurement_source: MeasurementSource,
        config: EmulatorConfig | None = None,
        rng: np.random.Generator | int = 0,
        codec: StarTrackerCodec | None = None,
        *,
        baudrate: int = 115200,
        name: str = "star tracker emulator",
        max_read_bytes: int = 4096,
        max_tx_bytes: int = 4096,
    ) -> None:
        self._closed = True
        for arg, v in (("max_read_bytes", max_read_bytes), ("max_tx_bytes", max_tx_bytes)):
            if not (isinstance(v, int) and v >= 256):
                raise ValueError(f"{name}: {arg} = {v!r} is not allowed; allowed: an int >= 256.")
        self.max_read_bytes = max_read_bytes
        self.max_tx_bytes = max_tx_bytes
        self._tx: deque[bytes] = deque()  # whole frames (the head possibly part-written) waiting for the port
        self._tx_bytes = 0
        self.port = None
        self._owns_port = False
        self.name = name
        self.config = cfg = config if config is not None else EmulatorConfig()
        self.codec = codec = codec if codec is not None else StarTrackerCodec()
        self.source = measurement_source
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.address = codec.default_address if cfg.address is None else cfg.address
        #: Current parameter values, SI, keyed by the ICD's parameter attr.
        self.params: dict[str, float] = {}
        for ps in codec.params.values():
            if ps.attr not in PARAM_FROM_CONFIG:
                raise ValueError(f"star tracker ICD parameter {ps.name} ({ps.attr}) has no emulator setting.")
            cname, factor = PARAM_FROM_CONFIG[ps.attr]
            value_si = float(getattr(cfg, cname)) * factor
            allowed = ps.check_wire(value_si / ps.scale if not ps.integer else round(value_si / ps.scale, 9))
            if allowed is not None:
                raise ValueError(
                    f"EmulatorConfig.{cname} = {getattr(cfg, cname)!r} is outside the ICD parameter {ps.name}: "
                    f"allowed {allowed}."
                )
            self.params[ps.attr] = value_si
        self._params0 = dict(self.params)  # what a power-up starts from
        self._bias = tuple(float(b) * ARCSEC for b in cfg.bias_arcsec)
        # What each exposure reads of the (frozen) config, looked up once: the noise sigmas (rad), the sigmas a
        # solution reports when the truth does not give its own, the star draws' parameters, the temperature.
        self._noise_rad = (cfg.noise_cross_arcsec * ARCSEC, cfg.noise_roll_arcsec * ARCSEC)
        self._reported_sigma = self._noise_rad if cfg.reported_sigma else (0.0, 0.0)
        self._mean_stars = cfg.mean_stars
        self._match_probability = cfg.match_probability
        self._temperature_C = cfg.temperature_C
        self._clock_rate = 1.0 + cfg.clock_drift_ppm * 1e-6  # device seconds per sim second
        self._make_solution = codec.messages["SOLUTION"].make
        self._decoder = SlipDecoder(codec.max_body)
        self.counters: dict[str, int] = {
            "bytes_received": 0, "frames_received": 0, "sent": 0, "rejected_crc": 0, "rejected_address": 0,
            "rejected_unknown_id": 0, "rejected_length": 0, "rejected_other": 0, "commands_nacked": 0,
            "solutions": 0, "exposures_skipped": 0, "published": 0, "tx_dropped": 0,
        }
        self._dev = {"frames_received": 0, "frames_sent": 0, "rejected_crc": 0, "rejected_other": 0,
                     "commands_nacked": 0, "solutions": 0}
        #: Why the latest rejected frame was dropped (a sentence naming the frame), or None.
        self.last_rejected: str | None = None
        #: Reply silently dropped while True (a device that went quiet; for tests and fault injection).
        self.silent = False
        self.mode = "BOOT"
        self.stable_count = 0
        self._bad_run = 0
        self._t_on: float | None = None
        self._t_ready: float | None = None
        self._k_exposure = 0
        self._pending: deque[tuple[float, Solution]] = deque()
        self.latest_solution: Solution | None = None
        self._seq = 0
        self._clock_ref: tuple[float, float] | None = None  # (sim t, device s) after SET_TIME
        self.time_synced = False
        self._subs: dict[int, list[float]] = {}  # telemetry id -> [period_s, next_due_s]
        self._new_solution = False
        self._now = 0.0
        #: Faults (module docstring); _faulted says whether any of blinded, lost, misid is set, so an exposure
        #: without one tests a single attribute.
        self._blinded = self._lost = self._faulted = False
        self._misid_rad = (0.0, 0.0, 0.0)
        self._misid_q: tuple[float, float, float, float] | None = None
        self._solution_delay_s = 0.0
        self._output_delay_s = cfg.output_delay_s
        self._slow_factor = 1
        self._interval_s = self.params["output_interval_s"]  # between exposures: the parameter x slow_factor
        # A short write timeout: only ports without a descriptor (loop://) use the port's own write.
        self.port, self._owns_port = open_port(port, baudrate=baudrate, timeout=0.0, name=name, write_timeout=0.05)
        self._closed = False
        try:  # a configuration the ICD cannot carry is refused now, not at the first STATUS
            codec.encode(self.status(0.0), self.address)
        except EncodeError as exc:
            self.close()
            raise ValueError(f"EmulatorConfig gives a value the star tracker ICD does not allow: {exc}") from None

    def __repr__(self) -> str:
        return f"StarTrackerEmulator({port_name(self.port)!r}, mode={self.mode!r}, counters={self.counters})"

    # -- device clock ---------------------------------------------------------------------------

    def device_time_s(self, t_s: float) -> float:
        """The device clock at sim time ``t_s``, s (with any clock fault)."""
        rate = self._clock_rate
        if self._clock_ref is None:
            s = self.config.clock_offset_s + t_s * rate
        else:
            t_set, dev_set = self._clock_ref
            s = dev_set + (t_s - t_set) * rate
        if self._clock_fault is not None:
            s += self._clock_fault.offset_s(t_s)
        return s

    def sim_time_s(self, time_us: int) -> float:
        """The sim time at which the device clock read ``time_us`` (the inverse of :meth:`device_time_s`)."""
        rate = self._clock_rate
        if self._clock_fault is not None:  # the clock is affine in sim time: invert it about now
            t_a = self._now
            return t_a + (time_us * 1e-6 - self.device_time_s(t_a)) / (rate + self._clock_fault.drift)
        if self._clock_ref is None:
            return (time_us * 1e-6 - self.config.clock_offset_s) / rate
        t_set, dev_set = self._clock_ref
        return t_set + (time_us * 1e-6 - dev_set) / rate

    def device_time_us(self, t_s: float) -> int:
        us = round(self.device_time_s(t_s) * 1e6)
        # clipped to the u64 field as min(max(us, 0), ...) would: comparisons, not two builtin calls per solution
        return 0 if us < 0 else _U64_MAX if us > _U64_MAX else us

    # -- service --------------------------------------------------------------------------------

    def service(self, t_s: float) -> None:
        """Non-blocking: read and answer requests, run exposures due by ``t_s``, publish what is due."""
        if self._closed:
            raise DriverError(f"{self.name}: closed; create a new one.")
        self._now = t_s
        if self._t_on is None:
            if self.booting(t_s):  # rebooting (drivers.device_faults): off until the boot ends
                self._drop_input()
                return
            self._t_on = t_s
            if self.config.auto_boot:
                self._start_boot(t_s)
        if self._tx:  # what the line did not take at the last call
            self._flush()
        self._advance(t_s)
        self._receive(t_s)
        self._publish(t_s)

    def _start_boot(self, t_s: float) -> None:
        self.mode = "BOOT"
        self.stable_count = 0
        self._bad_run = 0
        self._t_ready = t_s + self.config.boot_time_s
        self._k_exposure = 0
        self._pending.clear()
        self.latest_solution = None

    def _advance(self, t_s: float) -> None:
        if self._t_ready is None:
            return
        if self.mode == "BOOT":
            if t_s + _EPS_S < self._t_ready:
                return
            self.mode = "LOST_IN_SPACE"
        interval = self._interval_s
        since = t_s - self._t_ready + _EPS_S
        if since >= self._k_exposure * interval:
            last = math.floor(since / interval)
            if last > self._k_exposure:
                self.counters["exposures_skipped"] += last - self._k_exposure
            t_e = self._t_ready + last * interval
            sol = self.expose(t_e)
            self._pending.append((t_e + self._output_delay_s, sol))
            self._k_exposure = last + 1
        while self._pending and self._pending[0][0] <= t_s + _EPS_S:
            self.latest_solution = self._pending.popleft()[1]
            self._new_solution = True

    def expose(self, t_e: float) -> Solution:
        """Take one exposure at mid-exposure time ``t_e``: the solution and the state-machine step."""
        p = self.params
        truth = self.source(t_e)
        q, rate = checked_truth(truth, t_e)
        sigma_cross, sigma_roll = truth.sigma_cross_rad, truth.sigma_roll_rad
        sun = in_field(truth.sun_T, truth.sun_radius_rad, p["sun_exclusion_rad"])
        moon = in_field(truth.moon_T, truth.moon_radius_rad, p["moon_exclusion_rad"])
        earth = in_field(truth.earth_T, truth.earth_radius_rad, p["earth_exclusion_rad"])
        rate_high = rate > p["rate_limit_rad_s"]
        faulted = self._faulted
        if faulted and self._blinded:
            sun = True
        rng = self.rng
        n_stars = truth.stars_in_field
        if n_stars is None:
            n_stars = _draws.poisson(rng, self._mean_stars)
        n_stars = int(n_stars)
        n_stars = 0 if n_stars < 0 else 255 if n_stars > 255 else n_stars  # min(max(n, 0), 255) without the calls
        if sun or (faulted and self._lost):
            matched = 0  # the Sun blinds the detector; a lost tracker identifies no star
        elif truth.stars_matched is not None:
            matched = min(max(int(truth.stars_matched), 0), n_stars)
        else:
            matched = _draws.binomial(rng, n_stars, self._match_probability)
        good = not (sun or moon or earth or rate_high) and matched >= p["min_stars_matched"]
        mode = self.mode
        if good:
            self.stable_count += 1
            self._bad_run = 0
            if mode == "LOST_IN_SPACE" and self.stable_count >= p["stable_count"]:
                mode = "TRACKING"
        else:
            self.stable_count = 0
            self._bad_run += 1
            if mode == "TRACKING" and self._bad_run >= p["track_loss_count"]:
                mode = "LOST_IN_SPACE"
        if faulted and self._lost:
            mode = "LOST_IN_SPACE"
        self.mode = mode
        sc, sr = self._noise_rad
        n1, n2, n3 = _draws.standard_normal(rng, 3)
        bx, by, bz = self._bias
        qm = hamilton(q, small_rotation((bx + sc * n1, by + sc * n2, bz + sr * n3)))
        if faulted:
            qm = self._faulty_attitude(qm)
        if qm[0] < 0:
            qm = (-qm[0], -qm[1], -qm[2], -qm[3])
        self.counters["solutions"] += 1
        self._dev["solutions"] += 1
        seq = self._seq
        self._seq = (seq + 1) & 0xFFFF
        reported_cross, reported_roll = self._reported_sigma
        return self._make_solution({  # Solution(**these), with fewer calls (drivers.frozen_build)
            "time_us": self.device_time_us(t_e),
            "q_TN": qm,
            "sigma_cross_rad": reported_cross if sigma_cross is None else sigma_cross,
            "sigma_roll_rad": reported_roll if sigma_roll is None else sigma_roll,
            "stars_centroided": n_stars,
            "stars_matched": matched,
            "mode": mode,
            "valid": good and mode == "TRACKING",
            "sun_in_field": sun,
            "moon_in_field": moon,
            "earth_in_field": earth,
            "rate_too_high": rate_high,
            "time_synced": self.time_synced,
            "stable_count": self.stable_count,
            "temperature_C": self._temperature_C,
            "seq": seq,
        })

    # -- faults (module docstring) ---------------------------------------------------------------

    def _refresh_faults(self) -> None:
        self._faulted = self._blinded or self._lost or self._misid_q is not None

    @property
    def blinded(self) -> bool:
        """Every exposure sees the Sun in the field."""
        return self._blinded

    @blinded.setter
    def blinded(self, value: bool) -> None:
        self._blinded = bool(value)
        self._refresh_faults()

    @property
    def lost(self) -> bool:
        """No star is identified: no attitude, mode LOST_IN_SPACE."""
        return self._lost

    @lost.setter
    def lost(self, value: bool) -> None:
        self._lost = bool(value)
        self._refresh_faults()

    @property
    def misid_rad(self) -> tuple[float, float, float]:
        """Rotation vector (rad, tracker axes) composed onto the measured attitude, flags kept."""
        return self._misid_rad

    @misid_rad.setter
    def misid_rad(self, v) -> None:
        try:
            r = tuple(float(x) for x in v)
        except (TypeError, ValueError):
            r = ()
        if len(r) != 3 or not all(math.isfinite(x) for x in r) or math.sqrt(sum(x * x for x in r)) > math.pi:
            raise ValueError(f"{self.name}: misid_rad = {v!r} is not allowed; give a rotation vector of 3 numbers "
                             "(rad, tracker axes) of at most pi rad.")
        self._misid_rad = r  # type: ignore[assignment]
        self._misid_q = small_rotation(r) if any(r) else None
        self._refresh_faults()

    @property
    def solution_delay_s(self) -> float:
        """Extra time from an exposure to its solution being available, s (on top of ``output_delay_s``)."""
        return self._solution_delay_s

    @solution_delay_s.setter
    def solution_delay_s(self, value: float) -> None:
        if isinstance(value, bool) or not (isinstance(value, (int, float)) and 0.0 <= value <= 3600.0):
            raise ValueError(f"{self.name}: solution_delay_s = {value!r} is not allowed; give seconds from 0 to 3600.")
        self._solution_delay_s = float(value)
        self._output_delay_s = self.config.output_delay_s + self._solution_delay_s

    @property
    def slow_factor(self) -> int:
        """Exposures this many output intervals apart (1 nominal)."""
        return self._slow_factor

    @slow_factor.setter
    def slow_factor(self, value: int) -> None:
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 1000:
            raise ValueError(f"{self.name}: slow_factor = {value!r} is not allowed; give a whole number from 1 to "
                             "1000 (exposures stay on the output interval's grid).")
        self._regrid()
        self._slow_factor = value
        self._interval_s = self.params["output_interval_s"] * value

    def _regrid(self) -> None:
        """Anchor the exposure grid at the last exposure before its interval changes."""
        if self._t_ready is not None and self._k_exposure > 0:
            self._t_ready += (self._k_exposure - 1) * self._interval_s
            self._k_exposure = 1

    def _faulty_attitude(self, qm: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        if self._lost:
            return (1.0, 0.0, 0.0, 0.0)  # no star identified: no attitude
        if self._misid_q is not None:
            return hamilton(qm, self._misid_q)
        return qm

    # -- reboot (drivers.device_faults) ---------------------------------------------------------

    def _reboot(self, t_s: float, t_up: float) -> None:
        self._drop_input()  # what the host sent and the device had not taken is lost, and what it had queued
        self._decoder.reset()
        self._tx.clear()
        self._tx_bytes = 0
        self._t_on = self._t_ready = None
        self._start_boot(t_up)
        self._t_ready = None
        self._seq = 0
        self._clock_ref = (t_up, self.config.clock_offset_s)  # restarted, not synchronised
        self.time_synced = False
        self._subs.clear()
        self._new_solution = False
        self.params = dict(self._params0)
        self._interval_s = self.params["output_interval_s"] * self._slow_factor
        for k in self._dev:
            self._dev[k] = 0

    def _drop_input(self) -> None:
        """A device that is off takes nothing from the line: what waits there is read and lost, counted in
        ``bytes_lost_in_boot`` and, whole frames, in ``rejected_while_off`` (so every frame the host sent is
        accounted for)."""
        lost = frames = 0
        for _ in range(64):  # bounded: a flooding host cannot hold the caller here
            data = self._read_available()
            if not data:
                break
            lost += len(data)
            frames += len(self._decoder.feed(data))
        self._lost_in_boot("bytes_lost_in_boot", lost)
        self._lost_in_boot("rejected_while_off", frames)

    # -- receive --------------------------------------------------------------------------------

    def _read_available(self) -> bytes:
        port = self.port
        try:
            n = port.in_waiting
            return port.read(min(n, self.max_read_bytes)) if n else b""
        except Exception as exc:
            if is_port_error(exc):  # an OS error, a closed port, pyserial's SerialException
                raise DriverError(f"{self.name}: cannot read from {port_name(port)}: {exc}") from exc
            raise

    def _receive(self, t_s: float) -> int:
        data = self._read_available()
        if not data:
            return 0
        self.counters["bytes_received"] += len(data)
        dec = self._decoder
        before = dec.counters["oversize"] + dec.counters["bad_escape"]
        bodies = dec.feed(data)
        slip_bad = dec.counters["oversize"] + dec.counters["bad_escape"] - before
        if slip_bad:
            self.counters["rejected_other"] += slip_bad
            self._dev["rejected_other"] += slip_bad
            self.last_rejected = (f"{slip_bad} SLIP frame(s) with a bad escape or longer than "
                                  f"{self._decoder.max_body} bytes")
        for body in bodies:
            self._handle(body, t_s)
        return len(bodies)

    def _handle(self, body: bytes, t_s: float) -> None:
        try:
            msg = self.codec.decode_body(body, self.address, HOST_TO_DEVICE)
        except FrameRejected as exc:
            kind = exc.kind
            if kind == "address":
                self.counters["rejected_address"] += 1
                return
            self.last_rejected = str(exc)
            if kind == "crc":
                self.counters["rejected_crc"] += 1
                self._dev["rejected_crc"] += 1
                return
            key = {"unknown_id": "rejected_unknown_id", "direction": "rejected_unknown_id",
                   "length": "rejected_length"}.get(kind, "rejected_other")
            self.counters[key] += 1
            self._dev["rejected_other"] += 1
            if kind in ("unknown_id", "direction", "length", "value") and len(body) >= 4:
                error = {"length": "BAD_LENGTH", "value": "VALUE_OUT_OF_RANGE"}.get(kind, "UNKNOWN_MESSAGE")
                if kind == "value" and self._unknown_action(body):
                    error = "UNKNOWN_ACTION"  # the ICD's own error for an action not in its table
                self._nack(body[1], error)
            return
        self.counters["frames_received"] += 1
        self._dev["frames_received"] += 1
        reply = self._apply(msg, t_s)
        if reply is not None:
            self._send(reply)

    def _unknown_action(self, body: bytes) -> bool:
        """An ACTION frame whose action byte is past the ICD's action table (decoding refuses it as a value)."""
        return body[1] == self.codec.messages["ACTION"].id and body[2] >= len(self.codec.enums["action"])

    @property
    def rejected_frames(self) -> int:
        """Frames from the host dropped as undecodable or invalid, each counted once (not those for another
        address)."""
        c = self.counters
        return c["rejected_crc"] + c["rejected_unknown_id"] + c["rejected_length"] + c["rejected_other"]

    def _nack(self, command_id: int, error: str) -> None:
        self.counters["commands_nacked"] += 1
        self._dev["commands_nacked"] += 1
        self._send(Nack(command_id, error))

    def _apply(self, msg: Message, t_s: float) -> Message | None:
        handler = _HANDLERS.get(type(msg))
        if handler is None:  # pragma: no cover - decode_body only lets commands through
            return None
        return handler(self, msg, t_s)

    def _on_request(self, msg: RequestTelemetry, t_s: float) -> Message | None:
        cid = self.codec.messages["REQUEST_TELEMETRY"].id
        if msg.telemetry_id == self.codec.status_id:
            return self.status(t_s)
        if msg.telemetry_id == self.codec.solution_id:
            if self.latest_solution is None:
                return self._refuse(cid, "NOT_READY")
            return self.latest_solution
        return self._refuse(cid, "UNKNOWN_TELEMETRY")

    def _on_set_param(self, msg: SetParam, t_s: float) -> Message | None:
        cid = self.codec.messages["SET_PARAM"].id
        ps = self.codec.params_by_id.get(msg.param_id)
        if ps is None:
            return self._refuse(cid, "UNKNOWN_PARAMETER")
        if ps.check_wire(msg.value) is not None:
            return self._refuse(cid, "VALUE_OUT_OF_RANGE")
        if ps.attr == "output_interval_s":
            self._regrid()  # a new exposure grid, anchored at the last exposure
        self.params[ps.attr] = msg.value * ps.scale
        self._interval_s = self.params["output_interval_s"] * self._slow_factor
        return Ack(cid)

    def _on_get_param(self, msg: GetParam, t_s: float) -> Message | None:
        ps = self.codec.params_by_id.get(msg.param_id)
        if ps is None:
            return self._refuse(self.codec.messages["GET_PARAM"].id, "UNKNOWN_PARAMETER")
        return ParamValue(ps.id, self.params[ps.attr] / ps.scale)

    def _on_action(self, msg: Action, t_s: float) -> Message | None:
        cid = self.codec.messages["ACTION"].id
        if msg.action == "BOOT":
            self._start_boot(t_s)
        elif msg.action == "SET_TIME":
            self._clock_ref = (t_s, msg.argument * 1e-6)
            self.time_synced = True
            self._clock_set(t_s)
        elif msg.action == "RESET_COUNTERS":
            for k in self._dev:
                self._dev[k] = 0
        else:
            return self._refuse(cid, "UNKNOWN_ACTION")
        return Ack(cid)

    def _on_subscribe(self, msg: Subscribe | Unsubscribe, t_s: float) -> Message | None:
        name = "SUBSCRIBE" if isinstance(msg, Subscribe) else "UNSUBSCRIBE"
        cid = self.codec.messages[name].id
        if msg.telemetry_id not in self.codec.telemetry_ids:
            return self._refuse(cid, "UNKNOWN_TELEMETRY")
        if isinstance(msg, Subscribe):
            self._subs[msg.telemetry_id] = [msg.period_s, t_s + msg.period_s]
        else:
            self._subs.pop(msg.telemetry_id, None)
        return Ack(cid)

    def _refuse(self, command_id: int, error: str) -> Nack:
        self.counters["commands_nacked"] += 1
        self._dev["commands_nacked"] += 1
        return Nack(command_id, error)

    # -- publish --------------------------------------------------------------------------------

    def _publish(self, t_s: float) -> None:
        new = self._new_solution
        self._new_solution = False
        for tid, sub in self._subs.items():
            period, due = sub
            if period <= 0.0:
                fire = new
            else:
                fire = t_s + _EPS_S >= due
                if fire:
                    sub[1] = due + period * max(1, math.floor((t_s + _EPS_S - due) / period) + 1)
            if not fire:
                continue
            if tid == self.codec.solution_id:
                if self.latest_solution is None:
                    continue
                self._send(self.latest_solution)
            else:
                self._send(self.status(t_s))
            self.counters["published"] += 1

    def status(self, t_s: float) -> Status:
        """The STATUS the device reports at ``t_s`` (counters wrapped at their field width)."""
        d = self._dev
        return Status(
            time_us=self.device_time_us(t_s),
            uptime_s=min(max(t_s - (self._t_on or 0.0), 0.0), 0xFFFF_FFFF * 1e-3),
            mode=self.mode,
            time_synced=self.time_synced,
            subscribed_solution=self.codec.solution_id in self._subs,
            subscribed_status=self.codec.status_id in self._subs,
            frames_received=d["frames_received"] & 0xFFFF_FFFF,
            frames_sent=d["frames_sent"] & 0xFFFF_FFFF,
            rejected_crc=d["rejected_crc"] & 0xFFFF,
            rejected_other=d["rejected_other"] & 0xFFFF,
            commands_nacked=d["commands_nacked"] & 0xFFFF,
            solutions=d["solutions"] & 0xFFFF_FFFF,
            temperature_C=self.config.temperature_C,
        )

    def _send(self, msg: Message) -> None:
        if self.silent:
            return
        body = self.codec.encode_body(msg, self.address)
        frame = escape(body)
        if self._tx_bytes + len(frame) > self.max_tx_bytes:
            self._flush()
            if self._tx_bytes + len(frame) > self.max_tx_bytes:
                self.counters["tx_dropped"] += 1
                return
        self._tx.append(frame)
        self._tx_bytes += len(frame)
        self._flush()
        if self._observers:  # what went on the line, decoded as a receiver decodes it (drivers.endpoint)
            sent = self.codec.decode_body(body, self.address, DEVICE_TO_HOST)
            for observer in self._observers:
                observer(sent)

    @property
    def tx_pending(self) -> int:
        """Bytes queued for the port and not yet written."""
        return self._tx_bytes

    def _flush(self) -> None:
        """Write queued frames as far as the port takes them now (never blocks)."""
        while self._tx:
            head = self._tx[0]
            try:
                n = write_available(self.port, head)
            except Exception as exc:
                raise DriverError(f"{self.name}: cannot write to {port_name(self.port)}: {exc}") from exc
            self._tx_bytes -= n
            if n < len(head):
                self._tx[0] = head[n:]
                return
            self._tx.popleft()
            self.counters["sent"] += 1
            self._dev["frames_sent"] += 1

    # -- stand-alone loop (SerialServer.run) -----------------------------------------------------

    def next_due_s(self) -> float | None:
        """Sim time of the next exposure or of the next solution waiting for its output delay, or None."""
        due = None
        if self._t_ready is not None:
            due = self._t_ready + self._k_exposure * self._interval_s
        if self._pending:
            due = self._pending[0][0] if due is None else min(due, self._pending[0][0])
        return due

    def _wants_write(self) -> bool:
        return bool(self._tx)


#: Command dataclass -> the emulator's handler of it.
_HANDLERS: dict[type, Callable[[StarTrackerEmulator, Any, float], Message | None]] = {
    RequestTelemetry: StarTrackerEmulator._on_request,
    SetParam: StarTrackerEmulator._on_set_param,
    GetParam: StarTrackerEmulator._on_get_param,
    Action: StarTrackerEmulator._on_action,
    Subscribe: StarTrackerEmulator._on_subscribe,
    Unsubscribe: StarTrackerEmulator._on_subscribe,
}
