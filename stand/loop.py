"""The multi-rate loop: one tick per dynamics step, the same for every device kind and link.

Order inside a tick at sim time t (docs/architecture.md, "One tick"):

1. wait for the tick's wall-clock deadline (paced runs only);
2. each device publishes what is due at t (``Device.publish``): an emulator samples the truth and sends
   through the real codec; a hardware link's host reads what the real device sent;
3. the controller, when due, reads its host drivers and sends commands back through the codec;
4. each device takes in what arrived (``Device.receive``); actuators' outputs (the dipole) are held
   (zero-order hold) over the step;
5. a telemetry row is recorded when due; the device watch looks for silent devices once a second;
6. the truth model advances one step, torques re-evaluated inside every integrator stage.

A failure mid-run (a device fault, a plug-in exception, a full disk, the operator) ends the run cleanly: the
event is logged, the telemetry written so far stays readable, and the summary says what happened.
"""

from __future__ import annotations

import gc
import sys
import time
import traceback
from dataclasses import dataclass, field

from drivers.errors import DriverError
from sim.time import seconds_to_ns

from .compose import Scene, ticks_per
from .pacing import Pacer
from .telemetry import EventLog, Recorder, TelemetryError

#: Where in a paced tick's wall-clock frame commands from devices in wall time are taken in (fraction of the tick).
FRAME_END = 0.8
#: Lines of a plug-in's traceback kept in the event log.
TRACEBACK_LINES = 40


class Stopped(Exception):
    """The operator stopped the run (SIGTERM; Ctrl-C arrives as KeyboardInterrupt)."""


class DeviceWatch:
    """Notices a device whose measurements stop reaching the stand (and come back), once per change, for the
    event log, whatever its kind: it reads ``Device.activity()`` once per second of sim time. The run goes on
    either way (the controller holds, the actuators' own watchdogs switch them off)."""

    def __init__(self, device, events: EventLog):
        self.device, self.events = device, events
        self.name = device.name
        self.limit_s = device.silent_after_s
        self.count = 0
        self.last_change_s = 0.0
        self.silent = False
        self.silences = 0

    def check(self, t_s: float) -> None:
        n = self.device.activity()
        if n != self.count:
            self.count, self.last_change_s = n, t_s
            if self.silent:
                self.silent = False
                self.events.log("device_recovered", f"{self.name}: heard from again at t = {t_s:.3f} s",
                                t_s=t_s, device=self.name)
        elif not self.silent and t_s - self.last_change_s > self.limit_s:
            self.silent = True
            self.silences += 1
            self.events.log("device_silent", f"{self.name}: nothing received since t = {self.last_change_s:.3f} s "
                            f"(silent after {self.limit_s:g} s)", t_s=t_s, device=self.name)


def columns(scene: Scene) -> list[tuple[str, int, str]]:
    cols = [("t_s", 1, "s"), ("q_BN", 4, "1"), ("omega_BN_B", 3, "rad/s"), ("r_BN_N", 3, "m"),
            ("v_BN_N", 3, "m/s")]
    if scene.truth.has_field:
        cols.append(("b_true_B", 3, "T"))
    for d in scene.devices.values():
        cols += d.columns()
    if hasattr(scene.controller, "telemetry_columns"):
        cols += list(scene.controller.telemetry_columns())
    names = [c[0] for c in cols]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise ValueError(f"telemetry columns {dup} are recorded twice: a plug-in's telemetry_columns() must not "
                         "reuse the names of the stand's columns.")
    return cols


@dataclass
class RunResult:
    status: str  # "completed", "aborted" (an error), "stopped" (operator)
    sim_duration_s: float
    wall_time_s: float
    ticks: int
    timing: dict
    error: str | None = None
    counters: dict = field(default_factory=dict)


class Progress:
    """One status line on stderr, refreshed at most twice a second."""

    def __init__(self, total_s: float, enabled: bool, stream=sys.stderr):
        self.total = total_s
        self.enabled = enabled
        self.stream = stream
        self._next = 0.0
        self._start = time.monotonic()

    def update(self, t_s: float, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now < self._next and not force:
            return
        self._next = now + 0.5
        frac = min(1.0, t_s / self.total) if self.total else 1.0
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        rate = t_s / max(now - self._start, 1e-9)
        self.stream.write(f"\r[{bar}] {100 * frac:5.1f}%  sim {t_s:9.1f}/{self.total:.1f} s  x{rate:8.1f} real time")
        if force:
            self.stream.write("\n")
        self.stream.flush()


#: Wall-clock period of the observer's control poll (pause, stop from the operator page).
POLL_S = 0.25


def _obey(command: str, observer, events: EventLog, pacer: Pacer, t: float, clock, sleep) -> None:
    """Act on the observer's ``"pause"`` or ``"stop"``: a pause holds the loop (polling, bounded sleeps) until the
    observer says otherwise, then moves the pacer's start by the pause so a paced run does not race to catch up."""
    if command == "pause":
        events.log("paused", f"paused from the operator page at t = {t:.3f} s", t_s=t)
        t0 = clock()
        while command == "pause":
            sleep(0.05)
            command = observer.poll_control()
        if pacer.start is not None:
            pacer.start += clock() - t0
        if command != "stop":
            events.log("resumed", f"resumed after {clock() - t0:.1f} s of wall time", t_s=t)
    if command == "stop":
        raise Stopped("stop from the operator page")


def run(scene: Scene, out_dir, *, speed: float | None = None, duration_s: float | None = None,
        progress: bool = False, clock=time.monotonic, sleep=time.sleep, observer=None) -> RunResult:
    """Run the scene, recording into ``out_dir``. Returns how it went; never leaves a bus open.

    Whatever ends the run (the end, a device fault, a plug-in exception, a full disk, the operator), the
    telemetry written so far stays readable and the event log says what happened.

    ``observer`` (the operator page's live feed, optional): ``observer.record(t_s, row)`` is called with every
    telemetry row and must only keep it (no I/O, no waiting); ``observer.poll_control()`` is called at most every
    ``POLL_S`` of wall time and returns None, ``"pause"`` or ``"stop"``.
    """
    sc = scene.scenario
    truth = scene.truth
    duration = sc.duration_s if duration_s is None else duration_s
    n_steps = seconds_to_ns(duration) // truth.step_ns
    events = EventLog(out_dir)
    recorder = Recorder(out_dir, columns(scene))
    pacer = Pacer(speed, sc.step_s, clock=clock, sleep=sleep)
    bar = Progress(n_steps * sc.step_s, progress)
    devs = list(scene.devices.values())
    publishers = [(d.publish, d.every_ticks) for d in devs]
    receivers = [d.receive for d in devs]
    givers = [d.dipole_B for d in devs if d.gives_dipole]
    wheelers = [d.wheel_torque_Nm for d in sorted((d for d in devs if d.gives_wheel_torque),
                                                  key=lambda d: d.wheel_index)] or None
    rows = [d.row for d in devs]
    controller = scene.controller
    ctl_every = ticks_per(sc.controller.rate_hz, sc.step_s) if controller is not None else 0
    rec_every = ticks_per(sc.record_rate_hz, sc.step_s)
    has_field = truth.has_field
    ctl_row = getattr(controller, "telemetry", None)
    watches = [DeviceWatch(d, events) for d in devs if d.silent_after_s is not None]
    watch_every = ticks_per(1.0, sc.step_s)
    status, error = "completed", None
    events.log("start", f"scenario {sc.name} for {duration:g} s", speed=speed)
    # The tick below runs tens of thousands of times per orbit: what it calls is bound to locals once here, and
    # the dipoles travel as tuples of floats (no arrays, no float() per tick).
    wait = pacer.wait if pacer.factor is not None else None
    # Frame-based scheduling when devices live in wall time (hardware and served links): measurements go out at
    # the start of a tick's wall-clock frame, actuator commands are taken in near its end, so a flight computer
    # outside that answers within the frame acts in the same tick, as the in-process controller does.
    hold = pacer.hold if (pacer.factor is not None and sc.wall_time_links) else None
    frame_end_s = FRAME_END * sc.step_s
    step = truth.step
    ctl_update = controller.update if controller is not None else None
    show = bar.update if progress else None
    record = recorder.record
    observe = observer.record if observer is not None else None
    poll_every = ticks_per(1.0 / POLL_S, sc.step_s)
    next_poll = 0.0
    k = 0
    wall0 = clock()
    # What exists now (the libraries, the scene) lives as long as the run: kept out of the collector, a full
    # collection no longer walks that whole heap every few thousand ticks (up to 60 ms each; unfrozen at the end).
    gc.freeze()
    try:  # from here on whatever ends the run (a device's start included) leaves a readable record
        for d in devs:
            d.start(events)
        wall0 = clock()
        pacer.begin()
        while True:
            t = truth.t_ns / 1e9
            if wait is not None:
                wait(t)
            for publish, every in publishers:
                if every == 1 or k % every == 0:
                    publish(t)
            if ctl_update is not None and k % ctl_every == 0 and k < n_steps:
                ctl_update(t)
            if hold is not None:
                hold(t + frame_end_s)
            dx = dy = dz = 0.0
            for receive in receivers:
                receive(t)
            for dipole in givers:
                m = dipole()
                dx, dy, dz = dx + m[0], dy + m[1], dz + m[2]
            if k % rec_every == 0 or k == n_steps:
                row = (t, *truth.q, *truth.w, *truth.r_N, *truth.v_N)
                if has_field:
                    row += truth.b_B()
                for device_row in rows:
                    row += device_row()
                if ctl_row is not None:
                    row += tuple(ctl_row())
                record(row)
                if observe is not None:
                    observe(t, row)
                if show is not None:
                    show(t)
            if observe is not None and k % poll_every == 0 and clock() >= next_poll:
                next_poll = clock() + POLL_S
                command = observer.poll_control()
                if command is not None:
                    _obey(command, observer, events, pacer, t, clock, sleep)
            if k % watch_every == 0:
                for w in watches:
                    w.check(t)
            if k >= n_steps:
                break
            if wheelers is None:
                step((dx, dy, dz))
            else:
                step((dx, dy, dz), tuple([torque() for torque in wheelers]))
            k += 1
    except KeyboardInterrupt:
        status, error = "stopped", f"stopped by the operator (Ctrl-C) at t = {truth.t_s:.3f} s"
    except Stopped as exc:
        status, error = "stopped", f"stopped by the operator ({exc}) at t = {truth.t_s:.3f} s"
    except TelemetryError as exc:
        status, error = "aborted", f"at t = {truth.t_s:.3f} s: {exc}"
    except (DriverError, ValueError, FloatingPointError, OSError) as exc:
        status, error = "aborted", f"at t = {truth.t_s:.3f} s: {exc}"
    except Exception as exc:  # the controller (a plug-in) raised: the run ends, its record stays
        status, error = "aborted", f"at t = {truth.t_s:.3f} s the controller raised {type(exc).__name__}: {exc}"
        events.log("controller_exception", error, t_s=truth.t_s,
                   traceback=traceback.format_exc().splitlines()[-TRACEBACK_LINES:])
    finally:
        wall = clock() - wall0
        gc.unfreeze()
        try:
            recorder.close()
        except TelemetryError as exc:
            status, error = "aborted", error or str(exc)
        bar.update(truth.t_s, force=True)
        counters = {}
        for d in devs:
            try:
                counters[d.name] = d.summary()
            except Exception as exc:  # a summary must not hide how the run ended
                counters[d.name] = {"summary_error": str(exc)}
        for w in watches:
            counters[w.name]["silences"] = w.silences
        if error:
            events.log(status, error)
        events.log("end", status, ticks=k, wall_time_s=wall)
        events.close()
    timing = {"ticks": k, **pacer.stats()}
    return RunResult(status, k * sc.step_s, wall, k, timing, error, counters)
