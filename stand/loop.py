"""The multi-rate loop: one tick per dynamics step, the same for every device kind and link.

Order inside a tick at sim time t (docs/architecture.md, "One tick"):

1. wait for the tick's wall-clock deadline (paced runs only);
2. each device publishes what is due at t (``Device.publish``): an emulator samples the truth and sends
   through the real codec; a hardware link's host reads what the real device sent;
3. the controller, when due, reads its host drivers and sends commands back through the codec;
4. each device takes in what arrived (``Device.receive``);
5. a telemetry row is recorded when due; the device watch looks for silent devices once a second;
6. the truth model advances one step under what the actuators' effects (``Device.effects``: a dipole, a torque, a
   momentum exchange) read now, held (zero-order hold) over the step, torques re-evaluated inside every integrator
   stage.

A failure mid-run (a device fault, a plug-in exception or exit, flight code over its time budget, a full disk,
the operator) ends the run cleanly: the event is logged under the name of what failed (``device_exception`` with
the device's name, ``controller_exception``, ``controller_over_budget``, ``truth_exception``,
``writer_exception``, ``pacer_exception``, ``observer_exception``), the telemetry written so far stays readable,
and the summary's error names it. Only Ctrl-C (KeyboardInterrupt) and :class:`Stopped` mean the operator.
"""

from __future__ import annotations

import ctypes
import gc
import os
import signal
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field

from sim.time import seconds_to_ns

from . import controllers, devices
from .compose import Scene, ticks_per
from .logs import RunLog
from .pacing import OVERRUN_SHARE_LIMIT, Pacer, overrun_share
from .scenario import DEFAULT_BUDGET_S
from .telemetry import EventLog, Recorder

#: Where in a paced tick's wall-clock frame commands from devices in wall time are taken in (fraction of the tick).
FRAME_END = 0.8
#: Lines of a traceback kept in the event log.
TRACEBACK_LINES = 40


class Stopped(BaseException):
    """The operator stopped the run (SIGTERM, or the operator page; Ctrl-C arrives as KeyboardInterrupt).

    A BaseException, as KeyboardInterrupt is: the SIGTERM handler raises it wherever the main thread happens to be,
    and a fallback there that catches ``Exception`` (the orbit track's work ahead in a paced run's slack, a plug-in's
    own handler) would otherwise swallow it and the run would go on as if no signal had come."""


class OverBudget(BaseException):
    """Raised inside flight code that ran past its time budget, by the budget watchdog. A BaseException, so a
    plug-in's ``except Exception`` around its own work does not swallow it."""


class FlightExit(BaseException):
    """``os._exit`` called from the loop's thread while a run is on (see :class:`_ExitGuard`)."""

    def __init__(self, code):
        super().__init__(code)
        self.code = code


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


#: One-line meanings of the columns every run records (a kind's are in ``DeviceKind.column_meanings``).
MEANINGS = {"t_s": "simulation time since the scenario's epoch",
            "q_BN": "true attitude, body relative to inertial (GCRS), scalar first",
            "omega_BN_B": "true body rate relative to inertial, body axes", "r_BN_N": "true position, inertial",
            "v_BN_N": "true velocity, inertial", "b_true_B": "true magnetic field at the spacecraft, body axes"}


def column_meanings(scene: Scene) -> dict[str, str]:
    """Column name -> one-line meaning, for the telemetry's schema: the stand's own, what the controller's kind and a
    plug-in's ``column_meanings`` dict declare, and what each device's kind declares (a kind not found, or declaring
    nothing, leaves its columns without one)."""
    out = dict(MEANINGS)
    try:
        out.update(controllers.get(scene.scenario.controller.kind).column_meanings)
    except KeyError:
        pass
    # A plug-in may say what its own columns mean: a ``column_meanings`` dict beside its telemetry_columns().
    declared = getattr(scene.controller, "column_meanings", None)
    if isinstance(declared, dict):
        out.update({str(k): str(v) for k, v in declared.items()})
    for spec in scene.scenario.devices:
        try:
            declared = devices.get(spec.kind).column_meanings
        except KeyError:
            continue
        out.update({f"{spec.name}.{col}": text for col, text in declared.items()})
    return out


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

    def row(self, t_s: float, row: tuple) -> None:
        """A telemetry row was recorded (what the loop hands its row sinks)."""
        self.update(t_s)


#: Wall-clock period of the observer's control poll (pause, stop from the operator page).
POLL_S = 0.25


def _obey(command, observer, events: EventLog, pacer: Pacer, t: float, clock, sleep, faults=None) -> None:
    """Act on the observer's ``"pause"`` or ``"stop"``: a pause holds the loop (polling, bounded sleeps) until the
    observer says otherwise, then moves the pacer's start by the pause so a paced run does not race to catch up.
    Fault commands (``("fault", payload)``) go to the run's fault schedule first, also while paused."""
    command = _live_faults(command, observer, faults)
    if command == "pause":
        events.log("paused", f"paused from the operator page at t = {t:.3f} s", t_s=t)
        t0 = clock()
        while command == "pause":
            sleep(0.05)
            command = _live_faults(observer.poll_control(), observer, faults)
        if pacer.start is not None:
            pacer.start += clock() - t0
        if command != "stop":
            events.log("resumed", f"resumed after {clock() - t0:.1f} s of wall time", t_s=t)
    if command == "stop":
        raise Stopped("stop from the operator page")


def _live_faults(command, observer, faults):
    """Hand each ``("fault", payload)`` from the observer to the fault schedule (``scene.faults``; it applies them
    at its next tick), give the answer back (``observer.answer_fault``), and return the next other command.
    ``payload``: ``{"id", "action": "inject", "fault": table}`` or ``{"id", "action": "clear", "name"}``."""
    while type(command) is tuple:
        payload = command[1]
        answer = {"id": payload.get("id"), "ok": False, "status": 409}
        if faults is None:
            answer["error"] = "this run has no fault schedule: it was started without live injection"
        else:
            try:
                if payload["action"] == "inject":
                    answer.update(ok=True, name=faults.inject(payload["fault"]))
                else:
                    _clear(faults, payload["name"])
                    answer.update(ok=True, name=payload["name"])
            except _UnknownFault as exc:
                answer.update(status=404, error=str(exc))
            except ValueError as exc:  # a ScenarioError: the table, in one sentence
                answer.update(status=400, error=str(exc))
        observer.answer_fault(answer)
        command = observer.poll_control()
    return command


class _UnknownFault(LookupError):
    """A live ``clear`` of a fault the schedule does not know (its KeyError, as one sentence)."""


def _clear(faults, name: str) -> None:
    try:
        faults.clear(name)
    except KeyError:
        raise _UnknownFault(f"no fault named {name!r} was injected in this run") from None


class _ExitGuard:
    """``os._exit`` from the loop's thread raises :class:`FlightExit` for the duration of a run.

    Why: ``os._exit`` ends the process at once, skipping every ``finally``: no summary, buses left open, and the
    exit code the plug-in chose (0 reads as a pass to a script or a CI job). A run must end "aborted" with its
    record instead, as for any exception in flight code. Only calls from the loop's own thread are caught: other
    threads of the process (a campaign's executor, a Dask worker) keep the real function. Not covered: a name
    bound before the run (``from os import _exit``), ``posix._exit``, ``os.abort``, signals sent to the process.
    """

    def __init__(self):
        self.real = os._exit
        self.ident = threading.get_ident()

    def _exit(self, code):
        if threading.get_ident() == self.ident:
            raise FlightExit(code)
        self.real(code)

    def __enter__(self):
        os._exit = self._exit
        return self

    def __exit__(self, *exc):
        if os._exit == self._exit:  # bound methods compare equal, never identical
            os._exit = self.real


#: How often the budget watchdog looks at the running call: a tenth of the budget, within these bounds (s).
WATCH_PERIOD_S = (0.005, 0.25)


class _Watchdog:
    """Interrupts a call into flight code (``update``, ``telemetry``) that runs past ``controller.budget_s``.

    The loop writes a token into ``busy[0]`` before each call (the tick index for ``update``, its complement for
    the telemetry row) and None after: two list stores per call, no clock read, no system call. Arming a timer
    instead (``setitimer`` before and after each call) measured 4 to 9 us per call on the shared 2-core machine
    this was written on, against about 25 us for a whole tick of the default scenario; the two stores, under 0.1 us.
    A thread looks at the token every tenth of the budget; a call holding the same token for the budget is
    interrupted: on the main thread by SIGALRM sent to it (its handler raises :class:`OverBudget`; a sleep, a
    blocking socket read or a Python loop are interrupted), on any other thread by an asynchronous exception
    (``PyThreadState_SetAsyncExc``: a Python loop is interrupted, a blocking system call only once it returns).
    Either way a call is stopped once it has been seen running for ``budget_s``: between ``budget_s`` and
    ``budget_s`` plus one look after it began. A call that swallows the exception is interrupted again every
    ``budget_s``, and the run ends aborted all the same (``_finish``)."""

    def __init__(self, budget_s: float):
        self.budget_s = budget_s
        self.period_s = min(max(budget_s / 10.0, WATCH_PERIOD_S[0]), WATCH_PERIOD_S[1])
        self.busy: list = [None]
        self.over: tuple | None = None  # (token, seconds it had run) of the call that ran over
        self.active = False
        self._done = threading.Event()
        self._thread: threading.Thread | None = None
        self._ident = threading.get_ident()
        # Signals are delivered to the main thread only (and SIGALRM is POSIX): elsewhere the asynchronous exception.
        self._main = threading.current_thread() is threading.main_thread() and hasattr(signal, "pthread_kill")
        self._old_handler = None
        self._async_sent = False

    def start(self) -> None:
        if self._main:
            self._old_handler = signal.signal(signal.SIGALRM, self._alarm)
        self.active = True
        self._thread = threading.Thread(target=self._watch, name="stand-flight-budget", daemon=True)
        self._thread.start()

    def _alarm(self, signum, frame):
        if self.active:
            raise OverBudget()

    def _watch(self) -> None:
        seen, since, fired = None, 0.0, None
        while not self._done.wait(self.period_s):
            token, now = self.busy[0], time.monotonic()
            if token is None or token != seen:
                seen, since, fired = token, now, None
            elif now - since >= self.budget_s and (fired is None or now - fired >= self.budget_s):
                self.over, fired = (token, now - since), now
                self._interrupt()

    def _interrupt(self) -> None:
        if not self.active:
            return
        if self._main:
            signal.pthread_kill(self._ident, signal.SIGALRM)
        else:
            ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(self._ident), ctypes.py_object(OverBudget))
            self._async_sent = True

    def stop(self) -> None:
        """Called first when the run ends: no interrupt reaches the code after it."""
        self.active = False  # the SIGALRM handler now ignores a signal still on its way
        for _ in range(3):  # an asynchronous exception already sent may land here, once
            try:
                self._done.set()
                if self._thread is not None:
                    self._thread.join()
                if self._async_sent:
                    # One sent but not raised yet is raised here, where it is caught: the loop's backward jumps
                    # look for it. Clearing it instead (SetAsyncExc with NULL) leaves CPython 3.11's eval breaker
                    # set for the whole interpreter, as the flag is only taken back when an exception is raised,
                    # and a profiled or traced call made later in the process then never returns.
                    self._async_sent = False
                    for _ in range(64):
                        pass
                break
            except OverBudget:
                continue
        if self._main and self._thread is not None:
            # A SIGALRM sent just before the watchdog stopped must not reach the default action (the end of the
            # process) once the old handler is back: block it, take it if pending, restore, unblock.
            mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGALRM})
            try:
                if signal.SIGALRM in signal.sigpending():
                    signal.sigwait({signal.SIGALRM})
                # None: a handler not set from Python, which cannot be put back; the default is what Python sets.
                signal.signal(signal.SIGALRM, signal.SIG_DFL if self._old_handler is None else self._old_handler)
            finally:
                signal.pthread_sigmask(signal.SIG_SETMASK, mask)

    def text(self) -> str:
        token, took_s = self.over
        call = "update" if token >= 0 else "telemetry"
        return (f"the controller's {call} was still running after {took_s:.2f} s, over its budget of "
                f"controller.budget_s = {self.budget_s:g} s, and was interrupted")


# What the loop was doing when something raised (``_Flight.stage``), and the word the error uses for it.
PUBLISH, CONTROL, RECEIVE, ROW, WRITER, OBSERVER, TRUTH, CHORES, START = range(9)
STAGE_WORDS = ("publish", "update", "receive", "telemetry row", "record", "feed", "effect", "activity", "start")


class _Flight:
    """One run's objects and the loop's schedule, bound once; ``k``, ``stage`` and ``fn`` say where it was."""

    def __init__(self, scene: Scene, out_dir, speed, duration_s, progress: bool, clock, sleep, observer):
        sc = self.sc = scene.scenario
        self.truth, self.controller, self.observer = scene.truth, scene.controller, observer
        self.faults = getattr(scene, "faults", None)  # the fault schedule, None in a run that takes no faults
        self.columns = columns(scene)
        self.clock, self.sleep = clock, sleep
        self.duration_s = sc.duration_s if duration_s is None else duration_s
        self.n_steps = seconds_to_ns(self.duration_s) // self.truth.step_ns
        self.events = EventLog(out_dir)
        self.recorder = Recorder(out_dir, self.columns, column_meanings(scene))
        # Collects garbage and computes the orbit track's next chunk in slack time.
        self.pacer = Pacer(speed, sc.step_s, clock=clock, sleep=sleep, collector=gc,
                           ahead=[self.truth.track.work_ahead])
        self.bar = Progress(self.n_steps * sc.step_s, progress)
        self.devs = list(scene.devices.values())
        self.watches = [DeviceWatch(d, self.events) for d in self.devs if d.silent_after_s is not None]
        self.watch_every = ticks_per(1.0, sc.step_s)
        self.poll_every = ticks_per(1.0 / POLL_S, sc.step_s)
        self.next_poll = 0.0
        budget_s = sc.controller.params.get("budget_s", DEFAULT_BUDGET_S)
        self.watchdog = _Watchdog(budget_s) if self.controller is not None else None
        self.k, self.stage, self.fn = 0, START, None
        self.status, self.error, self.wall0, self.wall_s = "completed", None, clock(), 0.0
        self.run_log = RunLog(out_dir)  # RUN/stand.log, beside events.jsonl; closed by _finish
        # Who is who when something raises: the object whose method failed -> (event kind, name in the error).
        self.known = {id(d): ("device_exception", d) for d in self.devs}
        self.known.update({id(w): ("device_exception", w.device) for w in self.watches})
        self.known.update({id(obj): (kind, name) for obj, kind, name in (
            (self.controller, "controller_exception", "the controller"),
            (self.truth, "truth_exception", "the truth model (dynamics)"),
            (self.faults, "fault_exception", "the fault schedule"),
            (self.recorder, "writer_exception", "the telemetry writer"),
            (self.events, "writer_exception", "the event log"),
            (self.pacer, "pacer_exception", "the pacer"),
            (observer, "observer_exception", "the operator page's feed"),
            (self.bar, "observer_exception", "the progress line")) if obj is not None})

    def _own(self, fn, owner):
        """``fn``, noted as ``owner``'s for the error that names what failed."""
        self.known[id(fn)] = self.known[id(owner)]
        return fn

    def plan(self):
        """What the tick calls, bound to locals once (the tick runs tens of thousands of times per orbit)."""
        sc, pacer, truth, own = self.sc, self.pacer, self.truth, self._own
        publishers, receivers, effects, parts = [], [], [], ([own(truth.b_B, truth)] if truth.has_field else [])
        for d in self.devs:
            # A device that keeps the base class's do-nothing step (a sensor's receive, an actuator's publish, a
            # device with no columns' row) is not called for it: nothing is skipped but a call that does nothing.
            if _overrides(d.publish, devices.Device.publish):
                publishers.append((own(d.publish, d), d.every_ticks))
            if _overrides(d.receive, devices.Device.receive):
                receivers.append(own(d.receive, d))
            if _overrides(d.row, devices.Device.row):
                parts.append(own(d.row, d))
            for effect in d.effects():  # what an actuator does to the truth, read by the truth's step
                own(effect.read, d)
                effects.append(effect)
        if self.faults is not None:  # faults start and clear before the devices publish (none: nothing here)
            publishers.insert(0, (own(self.faults.tick, self.faults), 1))
        if pacer.factor is not None:
            publishers.insert(0, (pacer.wait, 1))  # first: the tick's wall-clock deadline
        if pacer.factor is not None and sc.wall_time_links:
            # Frame-based scheduling when devices live in wall time (hardware and served links): measurements go
            # out at the start of a tick's wall-clock frame, actuator commands are taken in near its end, so a
            # flight computer outside that answers within the frame acts in the same tick, as the in-process
            # controller does. Holding is the first "receiver", so an afap tick pays nothing for it.
            hold, frame_end_s = pacer.hold, FRAME_END * sc.step_s
            receivers.insert(0, own(lambda t: hold(t + frame_end_s), pacer))
        # The truth reads every effect once per step, after the receivers (sim.truth.TruthModel.effector).
        step = truth.effector(effects)
        ctl_update = ctl_row = None
        if self.controller is not None:
            ctl_update = own(self.controller.update, self.controller)
            ctl_row = getattr(self.controller, "telemetry", None)
        if ctl_row is not None:
            parts.append(own(ctl_row, self.controller))  # last: the flight code's (the budget covers the row)
        sinks = ([own(self.observer.record, self.observer)] if self.observer is not None else []) + (
            [self.bar.row] if self.bar.enabled else [])
        if self.faults is not None and self.faults.bind_columns(self.columns):
            sinks.append(own(self.faults.row, self.faults))  # faults that wait for a mode or a column
        ctl_every = ticks_per(sc.controller.rate_hz, sc.step_s) if ctl_update is not None else 0
        busy = self.watchdog.busy if self.watchdog is not None else [None]
        return (publishers, receivers, step, parts, sinks, ctl_update, ctl_every, busy,
                ticks_per(sc.record_rate_hz, sc.step_s))


def _overrides(method, base_function) -> bool:
    """Whether the bound ``method`` is anything but ``base_function`` (a device's own step, or one set on the
    instance), so the tick calls it."""
    return getattr(method, "__func__", None) is not base_function


def _start(f: _Flight) -> None:
    f.stage = START
    if f.faults is not None:
        f.faults.start(f.events)
    for d in f.devs:
        f.fn = d
        d.start(f.events)
    f.fn = None


def _fly(f: _Flight) -> None:
    """The ticks, from ``f.k`` to the end (docs/architecture.md, "One tick"). Nothing here calls more per tick
    than the tick needs: ``stage`` (a local) and the loop variables say where an exception came from."""
    publishers, receivers, step, parts, sinks, ctl_update, ctl_every, busy, rec_every = f.plan()
    truth, truth_row, record, n_steps = f.truth, f.truth.state_row, f.recorder.record, f.n_steps
    k, next_chore, stage = f.k, 0, START
    publish = receive = part = sink = None
    try:
        while True:
            t = truth.t_ns / 1e9
            stage = PUBLISH
            for publish, every in publishers:
                if every == 1 or k % every == 0:
                    publish(t)
            if ctl_update is not None and k % ctl_every == 0 and k < n_steps:
                stage = CONTROL
                busy[0] = k
                ctl_update(t)
                busy[0] = None
            stage = RECEIVE
            for receive in receivers:
                receive(t)
            if k % rec_every == 0 or k == n_steps:
                stage = TRUTH
                values = truth_row(t)  # t_s, q_BN, omega_BN_B, r_BN_N, v_BN_N: the first columns (columns())
                stage = ROW
                busy[0] = ~k
                for part in parts:
                    values += part()  # one list grown in place, not a tuple copied once per part
                busy[0] = None
                row = tuple(values)
                stage = WRITER
                record(row)
                stage = OBSERVER
                for sink in sinks:
                    sink(t, row)
            if k >= next_chore:
                stage = CHORES
                next_chore = _chores(f, k, t)
                if k >= n_steps:
                    break
            stage = TRUTH
            step()
            k += 1
    except BaseException:
        busy[0] = None
        f.k, f.stage = k, stage
        f.fn = (publish, ctl_update, receive, part, record, sink)[stage] if stage <= OBSERVER else None
        raise
    f.k = k


def _chores(f: _Flight, k: int, t: float) -> int:
    """The observer's control poll (at most every ``POLL_S`` of wall time) and the device watch (once a second of
    sim time), when due; returns the next tick either is due, or the last tick."""
    observer, nxt = f.observer, f.n_steps
    if observer is not None:
        if k % f.poll_every == 0 and f.clock() >= f.next_poll:
            f.next_poll = f.clock() + POLL_S
            command = observer.poll_control()
            if command is not None:
                _obey(command, observer, f.events, f.pacer, t, f.clock, f.sleep, f.faults)
        nxt = min(nxt, (k // f.poll_every + 1) * f.poll_every)
    if f.watches:
        if k % f.watch_every == 0:
            for w in f.watches:
                w.check(t)
        nxt = min(nxt, (k // f.watch_every + 1) * f.watch_every)
    return nxt


def _culprit(f: _Flight, exc: BaseException) -> tuple[str, str, dict]:
    """(event kind, who in words, event fields) of what raised: the owner of what the loop was calling, else the
    first known object among the traceback's frames (a callback, a wheel's torque inside the step), else what the
    stage implies."""
    hit = f.known.get(id(f.fn)) or f.known.get(id(getattr(f.fn, "__self__", None)))
    tb = exc.__traceback__
    while hit is None and tb is not None:
        hit = f.known.get(id(tb.tb_frame.f_locals.get("self")))
        if hit is None and tb.tb_next is not None:  # an effect's reader (a plain function) the truth's step called
            read = tb.tb_frame.f_locals.get("read")
            if getattr(getattr(read, "__func__", read), "__code__", None) is tb.tb_next.tb_frame.f_code:
                hit = f.known.get(id(read))
        tb = tb.tb_next
    if hit is None:
        default = {CONTROL: f.controller, TRUTH: f.truth, WRITER: f.recorder, OBSERVER: f.observer}.get(f.stage)
        hit = f.known.get(id(default), ("loop_exception", "the stand's loop"))
    kind, who = hit
    if kind == "device_exception":
        return kind, f"device {who.name} ({STAGE_WORDS[f.stage]})", {"device": who.name}
    if kind == "controller_exception":
        return kind, f"the controller ({'telemetry' if f.stage == ROW else 'update'})", {}
    return kind, who, {}


def _fault(f: _Flight, exc: BaseException) -> None:
    """End the run aborted, the event logged under what failed, with the traceback."""
    t = f.truth.t_s
    if isinstance(exc, OverBudget) and f.watchdog is not None and f.watchdog.over is not None:
        kind, text, fields = "controller_over_budget", f.watchdog.text(), {}
    else:
        kind, who, fields = _culprit(f, exc)
        if isinstance(exc, FlightExit):
            what = f"called os._exit({exc.code!r})"
        else:
            what = f"raised {type(exc).__name__}" + (f": {exc}" if str(exc) else "")
        text = f"{who} {what}"
    f.status, f.error = "aborted", f"at t = {t:.3f} s {text}"
    lines = traceback.format_exception(type(exc), exc, exc.__traceback__)
    f.events.log(kind, f.error, t_s=t, **fields, traceback="".join(lines).splitlines()[-TRACEBACK_LINES:])


def _finish(f: _Flight) -> dict:
    """Close the telemetry, log how the run ended; the devices' counters."""
    f.wall_s = f.clock() - f.wall0
    gc.unfreeze()
    f.pacer.end()  # the collector's thresholds back
    try:
        f.recorder.close()
    except Exception as exc:  # the last rows could not be written (a TelemetryError, one sentence)
        f.status, f.error = "aborted", f.error or str(exc)
    if f.watchdog is not None and f.watchdog.over is not None and f.status == "completed":
        # Flight code swallowed every interrupt and finished late: over budget all the same.
        f.status, f.error = "aborted", f"{f.watchdog.text()} (it caught the interrupt)"
        f.events.log("controller_over_budget", f.error)
    f.bar.update(f.truth.t_s, force=True)
    counters = {}
    for d in f.devs:
        try:
            counters[d.name] = d.summary()
        except Exception as exc:  # a summary must not hide how the run ended
            counters[d.name] = {"summary_error": str(exc)}
    for w in f.watches:
        counters[w.name]["silences"] = w.silences
    if f.error:
        f.events.log(f.status, f.error)
    share = overrun_share({"ticks": f.k, **f.pacer.stats()})
    if share is not None and share > OVERRUN_SHARE_LIMIT:
        f.events.log("overruns", f"{f.pacer.overruns} of {f.k} ticks ({100 * share:.1f} %) started more than a tick "
                     f"period late (more than {100 * OVERRUN_SHARE_LIMIT:g} %): the wall-time links did not see the "
                     "timing the scenario asks for", overruns=f.pacer.overruns, ticks=f.k)
    f.events.log("end", f.status, ticks=f.k, wall_time_s=f.wall_s)
    f.events.close()
    f.run_log.close()
    return counters


def _show_devices(observer, scene: Scene) -> None:
    """Hand the scene's devices to an observer that shows more than rows (the live page asks an image tracker for a
    frame at its own rate, ``stand.view.frames``); once per run, nothing per tick."""
    watch = getattr(observer, "watch_devices", None)
    if watch is not None:
        watch(scene.devices)


def run(scene: Scene, out_dir, *, speed: float | None = None, duration_s: float | None = None,
        progress: bool = False, clock=time.monotonic, sleep=time.sleep, observer=None) -> RunResult:
    """Run the scene, recording into ``out_dir``. Returns how it went; never leaves a bus open.

    Whatever ends the run (the end, a device fault, a plug-in exception or ``sys.exit``/``os._exit``, flight code
    over its time budget, a full disk, the operator), the telemetry written so far stays readable and the event
    log says what happened and what failed. Only KeyboardInterrupt and :class:`Stopped` (the operator) end it
    "stopped"; anything else raised ends it "aborted".

    ``observer`` (the operator page's live feed, optional): ``observer.record(t_s, row)`` is called with every
    telemetry row and must only keep it (no I/O, no waiting); ``observer.poll_control()`` is called at most every
    ``POLL_S`` of wall time and returns None, ``"pause"``, ``"stop"`` or ``("fault", payload)``, a command for the
    scene's fault schedule whose answer goes back through ``observer.answer_fault(answer)`` (``_live_faults``).
    """
    f = _Flight(scene, out_dir, speed, duration_s, progress, clock, sleep, observer)
    _show_devices(observer, scene)
    f.events.log("start", f"scenario {f.sc.name} for {f.duration_s:g} s", speed=speed)
    # What exists now (the libraries, the scene) lives as long as the run: kept out of the collector, a full
    # collection no longer walks that whole heap every few thousand ticks (up to 60 ms each; unfrozen at the end).
    gc.freeze()
    watchdog = f.watchdog
    try:  # from here on whatever ends the run (a device's start included) leaves a readable record
        with _ExitGuard():
            _start(f)
            f.wall0 = clock()
            f.pacer.begin()
            if watchdog is not None:
                watchdog.start()
            _fly(f)
    except KeyboardInterrupt:
        f.status, f.error = "stopped", f"stopped by the operator (Ctrl-C) at t = {f.truth.t_s:.3f} s"
    except Stopped as exc:
        f.status, f.error = "stopped", f"stopped by the operator ({exc}) at t = {f.truth.t_s:.3f} s"
    except BaseException as exc:  # SystemExit, GeneratorExit and the like from flight code included
        _fault(f, exc)
    finally:
        if watchdog is not None:
            watchdog.stop()
        counters = _finish(f)
    timing = {"ticks": f.k, **f.pacer.stats()}
    return RunResult(f.status, f.k * f.sc.step_s, f.wall_s, f.k, timing, f.error, counters)
