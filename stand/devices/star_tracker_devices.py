"""The star tracker's devices, one per link, and what they share (scoring each solution against the truth, the
telemetry columns, the summary). The kind (``star_tracker``: the scenario table, what it needs, how it is
built) is in ``star_tracker``; a hardware tracker looking at the stand's star screen is ``star_screen_link``'s
``ScreenTracker``, built on :class:`HardwareTracker` here. The kind imports this module, never the reverse.
"""


from __future__ import annotations

import math
import operator
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.errors import DeviceTimeoutError
from drivers.framing import FrameObserver
from drivers.serial_port import wait_readable
from drivers.star_tracker.codec import Solution
from sim.rotations import hamilton_floats
from sim.truth import compose_floats
from stand.devices import (
    SETTLE_TIMEOUT_S,
    BuildContext,
    DeviceSpec,
    SerialDevice,
    line_faulted,
    take_in_arrived,
    taken_in,
)
from stand.devices.star_tracker_source import ARCSEC, measure_source


def _icd_flag_bits() -> dict[str, int]:
    """The SOLUTION message's flags byte as the tracker's ICD defines it: flag name -> the value of its bit."""
    from drivers.star_tracker.codec import load_icd

    solution = next(m for m in load_icd()["messages"] if m["name"] == "SOLUTION")
    flags = next(f for f in solution["fields"] if f["name"] == "flags")
    return {name: 1 << i for i, name in enumerate(flags["bits"])}


#: ``NAME.flags`` records the ICD's SOLUTION flags byte bit for bit (bit 0 valid, 1 Sun, 2 Moon, 3 Earth in the
#: field, 4 rate too high, 5 time synced), so a value read off the wire and one read off the telemetry agree.
ICD_FLAG_BITS = _icd_flag_bits()
#: The flags that say why a solution is not valid: counted in the summary, drawn by the plots and the view.
FLAG_BITS = {f: ICD_FLAG_BITS[f] for f in ("sun_in_field", "moon_in_field", "earth_in_field", "rate_too_high")}
#: (flag, its bit, whether the summary counts it) in the ICD's order: what scoring a solution walks.
_FLAG_ORDER = tuple((flag, bit, flag in FLAG_BITS) for flag, bit in ICD_FLAG_BITS.items())
#: A solution's flags in that order, read in one call.
_FLAGS_OF = operator.attrgetter(*ICD_FLAG_BITS)
#: A solution's flags in that order -> (the ICD's flags byte, the flags set that the summary counts): one look-up per
#: solution instead of a walk over the flags; at most one entry per combination of the flags (64), filled as they come.
_FLAGS_BYTE: dict[tuple, tuple[int, tuple[str, ...]]] = {}


def _flags_byte(flags: tuple) -> tuple[int, tuple[str, ...]]:
    """(the ICD's flags byte, the flags set that the summary counts) of a solution's flags in the ICD's order; kept in
    :data:`_FLAGS_BYTE`, where the scoring looks first."""
    bits, counted = 0, []
    for (flag, bit, counts), on in zip(_FLAG_ORDER, flags, strict=True):
        if on:
            bits |= bit
            if counts:
                counted.append(flag)
    known = (bits, tuple(counted))
    if len(_FLAGS_BYTE) < 1 << len(_FLAG_ORDER):  # bounded, whatever a flag holds
        _FLAGS_BYTE[flags] = known
    return known
MODES = {"BOOT": 0, "LOST_IN_SPACE": 1, "TRACKING": 2}
#: The telemetry fragment before the first solution arrives (widths of the columns).
NO_SOLUTION = (math.nan,) * 10
#: Solutions in a row a tracker may miss before it is reported silent.
SILENT_SOLUTIONS = 5


def attitude_error_arcsec(q_true, q_meas) -> tuple[float, float]:
    """(cross-boresight, roll) error of a measured tracker attitude, arcsec (boresight +z).

    The rotation from true to measured tracker axes, E = dcm(q_meas) dcm(q_true)^T, has the antisymmetric part
    vee(E - E^T) / 2 = sin(angle) axis = 2 w v for its quaternion (w, v) = q_true^-1 then q_meas: on floats."""
    tw, tx, ty, tz = q_true
    w, x, y, z = hamilton_floats((tw, -tx, -ty, -tz), tuple(q_meas))
    return math.hypot(2.0 * w * x, 2.0 * w * y) / ARCSEC, abs(2.0 * w * z) / ARCSEC


@dataclass(frozen=True)
class StarTrackerSpec(DeviceSpec):
    """A star tracker on a serial line, fed by truth plus noise (``source = "truth"``) or by image-based
    solutions (``source = "image"``)."""

    port: str = "pipe"  # emulated: "pipe" (in-process line) or "pty"; hardware/served: a pyserial URL or device path
    baudrate: int = 115200
    address: int | None = None
    source: str = "truth"
    emulator: dict = field(default_factory=dict)  # keyword arguments of the emulator's EmulatorConfig
    optics: Any = None  # star_screen.geometry.TrackerOptics for source = "image", else None
    camera: dict | None = None  # camera_noise keywords (read_noise_e, background_e) for source = "image"
    screen: dict | None = None  # a hardware tracker looking at the stand's star screen (star_screen_link)




class TrackerDevice(SerialDevice):
    """What every link shares: scoring solutions against the truth, the telemetry columns and the summary."""

    def __init__(self, spec: StarTrackerSpec, ctx: BuildContext):
        self.name, self.spec = spec.name, spec
        self.q_SB = tuple(float(x) for x in spec.q_SB)
        self.truth_at: dict[int, tuple] = {}  # exposure time (us of sim time) -> q_TN
        self.solutions = self.valid = 0
        self.flags = dict.fromkeys(FLAG_BITS, 0)
        self.errors: list[tuple] = []  # (t_s, cross, roll) of valid solutions
        self.last = NO_SOLUTION  # the newest solution as a telemetry row fragment (see columns())
        self.last_solution = None  # the newest decoded SOLUTION message, as the host got it
        self.image = None  # the ImageSolver of an image-source tracker
        cfg = spec.emulator
        self.silent_after_s = cfg["boot_time_s"] + cfg["output_delay_s"] + SILENT_SOLUTIONS * cfg["output_interval_s"]
        self.emulator = None
        self._seen = 0
        #: The link as the stand sees it beside the flight code (attached when the host is set); scoring and
        #: telemetry read only this.
        self.observer = FrameObserver()
        self._host = None

    def _new_solution(self, poll: bool = True):
        """The newest solution on the link since the last call, as the stand observes it beside the flight code
        (:class:`drivers.framing.FrameObserver` on the host's framing layer); ``take_solution`` stays theirs. The
        poll (unless the caller just polled) only moves what arrived on the line through the host's framing layer,
        as the flight code's next call would; nothing is read from the host. A served tracker has no host: its
        observer is on the emulator."""
        if poll and self._host is not None:
            self._host.poll()
        n = self.observer.count(Solution)
        if n == self._seen:
            return None
        self._seen = n
        return self.observer.latest(Solution)

    @property
    def host(self):
        """The flight code's host driver (emulated and hardware links), or None."""
        return self._host

    @host.setter
    def host(self, endpoint) -> None:
        # The observer is attached where every link sets its host, so it sees the line from the first frame on.
        self._host = endpoint
        if endpoint is not None:
            endpoint.add_observer(self.observer)

    def _score(self, sol, t_exp: float) -> None:
        self.last_solution = sol
        self.solutions += 1
        flags = _FLAGS_OF(sol)
        bits, counted = _FLAGS_BYTE.get(flags) or _flags_byte(flags)  # the ICD's flags byte; why it is not valid
        for flag in counted:
            self.flags[flag] += 1
        q_true = self.truth_at.pop(round(t_exp * 1e6), None)
        cross = roll = math.nan
        if q_true is not None:
            cross, roll = attitude_error_arcsec(q_true, sol.q_TN)
        if sol.valid:
            self.valid += 1
            self.errors.append((t_exp, cross, roll))
        self.last = (t_exp, *sol.q_TN, float(sol.valid), float(MODES.get(sol.mode, -1)), float(bits), cross, roll)
        # Keep the truth log short: exposures older than a few seconds will never be reported.
        if len(self.truth_at) > 256:
            for k in sorted(self.truth_at)[:-64]:
                del self.truth_at[k]

    def columns(self) -> list[tuple[str, int, str]]:
        """Telemetry of the newest solution the host received (repeated until the next): exposure time in sim
        time, q_TN, valid, mode (0 boot, 1 lost in space, 2 tracking), the ICD's flags byte (:data:`ICD_FLAG_BITS`),
        and its error against the truth at that exposure."""
        n = self.name
        return [(f"{n}.t_exposure_s", 1, "s"), (f"{n}.q_TN", 4, "1"), (f"{n}.valid", 1, "1"),
                (f"{n}.mode", 1, "1"), (f"{n}.flags", 1, "1"), (f"{n}.err_cross", 1, "arcsec"),
                (f"{n}.err_roll", 1, "arcsec")]

    def row(self) -> tuple:
        return self.last

    def activity(self) -> int:
        return self.solutions

    def summary(self) -> dict:
        err = np.array([e[1:] for e in self.errors if math.isfinite(e[1])]).reshape(-1, 2)
        out = {"solutions": self.solutions, "valid": self.valid,
               "availability": round(self.valid / self.solutions, 4) if self.solutions else 0.0,
               "flags_fired": dict(self.flags)}
        out.update(self.driver_counters())
        if self.image is not None:
            out["image"] = self.image.summary()
        if len(err):
            for i, axis in enumerate(("cross", "roll")):
                out[f"error_{axis}_arcsec"] = {p: round(float(np.percentile(err[:, i], q)), 3)
                                               for p, q in (("median", 50), ("p95", 95), ("max", 100))}
        return out


def _config(spec: StarTrackerSpec):
    from drivers.star_tracker.emulator import EmulatorConfig

    return EmulatorConfig(address=spec.address, **spec.emulator)


class EmulatedTracker(TrackerDevice):
    """Emulator and host on an in-process serial line (a pipe, or a pty pair: the kernel tty path a bench would
    use) without a second process; every exchange completes within the tick, so runs are repeatable."""

    def __init__(self, spec: StarTrackerSpec, ctx: BuildContext):
        from drivers.star_tracker.codec import Subscribe
        from drivers.star_tracker.emulator import StarTrackerEmulator
        from drivers.star_tracker.host import StarTrackerHost

        super().__init__(spec, ctx)
        self._commands_in = -1  # the host's sent count the emulator was last seen to have taken in
        measure = measure_source(spec, ctx, self)
        self.open_emulated(spec.port,
                           lambda end: StarTrackerEmulator(end, measure, _config(spec), ctx.rng,
                                                           name=f"{spec.name} emulator"),
                           lambda end: StarTrackerHost(end, spec.address, name=spec.name))
        try:
            # Not the blocking subscribe(): nothing services the emulator while the host would wait.
            self.host.send_command(Subscribe(self.host.codec.solution_id, 0.0))
        except BaseException:
            self.close()
            raise

    def _settle(self, done, port) -> None:
        """Wait (wall clock, bounded) until the other end has the frames written to it.

        A pty hands bytes over asynchronously: an as-fast-as-possible loop would otherwise see a frame one or
        many ticks late, a different number each run. Waiting for the exchange to complete makes every run take
        the same tick for every frame, as a paced bench would.
        """
        deadline = time.monotonic() + SETTLE_TIMEOUT_S
        while not done():
            left = deadline - time.monotonic()
            if left <= 0:
                raise DeviceTimeoutError(
                    f"{self.name}: a frame written to the serial line did not arrive within {SETTLE_TIMEOUT_S:g} s.",
                    device=self.name, awaited="frames written to the serial line", timeout_s=SETTLE_TIMEOUT_S)
            wait_readable(port, min(left, 0.01))
            if port is self.host.port:
                self.host.poll()
            else:
                return  # the emulator reads in service(); it only had to be readable

    def publish(self, t_s: float) -> None:
        emu, host = self.emulator, self._host
        faulted = line_faulted(emu)  # frames lost or held on purpose: take what arrived, wait for nothing
        sent = host.counters["sent"]
        if sent != self._commands_in and not faulted:  # the host sent commands since the emulator last had all
            if not taken_in(sent, emu.counters):
                self._settle(lambda: emu.port.in_waiting > 0, emu.port)
            else:
                self._commands_in = sent  # counts only grow: nothing to check until the host sends again
        emu.service(t_s)
        if faulted:  # duplicates and babble can put the host's count ahead of what the emulator sent
            take_in_arrived(host)
        else:
            host.poll()  # what a pipe line holds is there at once; settling then only checks the counts
            if not taken_in(emu.counters["sent"], host.counters):
                self._settle(lambda: taken_in(emu.counters["sent"], host.counters), host.port)
        sol = self._new_solution(poll=faulted)  # unfaulted, the host has taken in everything sent
        if sol is not None:
            self._score(sol, emu.sim_time_s(sol.time_us))


class HardwareTracker(TrackerDevice):
    """The host driver on a real port. At start the device clock is set to sim time 0 (SET_TIME) and the
    offset the device then reports is logged; solutions are scored against the truth at their time stamps."""

    def __init__(self, spec: StarTrackerSpec, ctx: BuildContext):
        from drivers.star_tracker.host import StarTrackerHost

        super().__init__(spec, ctx)
        self._truth = ctx.truth
        self._step_us = round(ctx.step_s * 1e6)
        self._speed = ctx.speed or 1.0
        self.host = StarTrackerHost(spec.port, spec.address, name=spec.name, baudrate=spec.baudrate)
        self.clock_offset_s = math.nan

    def start(self, events) -> None:
        host = self.host
        t_set = time.monotonic()
        host.set_time(0)
        status = host.request_status()
        # Device time runs in wall time; sim time runs `speed` times faster from the start of the run.
        self.clock_offset_s = status.time_us * 1e-6 - (time.monotonic() - t_set)
        host.subscribe("SOLUTION", 0.0)
        events.log("device_clock", f"{self.name}: device clock set to 0 at start; it then read "
                   f"{self.clock_offset_s * 1e3:+.3f} ms against the stand's clock", device=self.name,
                   offset_s=self.clock_offset_s)

    def publish(self, t_s: float) -> None:
        # The truth of every tick, to score solutions whose exposures fall on (or near) it.
        self.truth_at[round(t_s * 1e6)] = compose_floats(self.q_SB, self._truth.q)
        sol = self._new_solution()
        if sol is not None:
            t_exp = sol.time_us * 1e-6 * self._speed
            t_tick = round(t_exp * 1e6 / self._step_us) * self._step_us * 1e-6
            self._score(sol, t_tick)

    def columns(self):
        return [*super().columns(), (f"{self.name}.clock_offset_s", 1, "s")]

    def row(self):
        return (*self.last, self.clock_offset_s)

    def summary(self):
        return {**super().summary(), "clock_offset_s": self.clock_offset_s}


class ServedTracker(TrackerDevice):
    """The emulator on a real port, fed by the truth, for a flight computer outside (no host in the stand)."""

    def __init__(self, spec: StarTrackerSpec, ctx: BuildContext):
        from drivers.star_tracker.emulator import StarTrackerEmulator

        super().__init__(spec, ctx)
        self.serve(StarTrackerEmulator(spec.port, measure_source(spec, ctx, self), _config(spec), ctx.rng,
                                       name=f"{spec.name} emulator", baudrate=spec.baudrate))
        # What the flight computer outside was sent, as its decoder reads it, is what the stand scores.
        self.emulator.add_observer(self.observer)

    def publish(self, t_s: float) -> None:
        self.emulator.service(t_s)
        self.rejections.check(t_s)
        sol = self._new_solution()
        if sol is not None:  # the flight computer may have set the clock: the emulator inverts what it keeps
            self._score(sol, self.emulator.sim_time_s(sol.time_us))

    def activity(self) -> int:
        # Silence here means the flight computer stopped talking to the tracker.
        return self.emulator.counters["frames_received"]

    def row(self) -> tuple:
        return self.last
