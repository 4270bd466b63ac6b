"""The multi-rate loop: one tick per dynamics step.

Order inside a tick at sim time t (docs/architecture.md, "One tick"):

1. wait for the tick's wall-clock deadline (paced runs only);
2. each device emulator publishes what is due at t (magnetometer samples of the truth at t,
   status, heartbeat) through the real codec onto its bus;
3. the controller, when due, reads its host drivers and sends commands back through the codec;
4. the emulators take in those commands, which become the actuator output held (zero-order
   hold) over the step;
5. a telemetry row is recorded when due;
6. the truth model advances one step, torques re-evaluated inside every RK4 stage.

A failure mid-run (a device that stops answering, a step the dynamics outgrew) ends the run
cleanly: the event is logged, the telemetry written so far stays readable, and the summary says
what happened.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field

from drivers.errors import DriverError
from sim.time import seconds_to_ns

from .compose import Scene, ticks_per
from .pacing import Pacer
from .telemetry import EventLog, Recorder

NAN3 = (math.nan, math.nan, math.nan)
#: A device whose magnetometer has sent nothing for this many sample periods is reported silent.
SILENT_PERIODS = 5


class DeviceWatch:
    """Notices a device that stops answering (and comes back), once per change, for the event log.

    It reads the host driver's sample counter once per second of sim time; the run goes on either
    way (the controller holds, the board's watchdog switches the coils off).
    """

    def __init__(self, name: str, host, period_s: float, events: EventLog):
        self.name, self.host, self.events = name, host, events
        self.limit_s = SILENT_PERIODS * period_s
        self.count = 0
        self.last_change_s = 0.0
        self.silent = False
        self.silences = 0

    def check(self, t_s: float) -> None:
        n = self.host.counters.get("samples", 0)
        if n != self.count:
            self.count, self.last_change_s = n, t_s
            if self.silent:
                self.silent = False
                self.events.log("device_recovered", f"{self.name}: samples again at t = {t_s:.3f} s", t_s=t_s)
        elif not self.silent and t_s - self.last_change_s > self.limit_s:
            self.silent = True
            self.silences += 1
            self.events.log("device_silent", f"{self.name}: no magnetometer sample since t = "
                            f"{self.last_change_s:.3f} s (expected every {self.limit_s / SILENT_PERIODS:g} s)",
                            t_s=t_s)


def columns(scene: Scene) -> list[tuple[str, int, str]]:
    cols = [("t_s", 1, "s"), ("q_BN", 4, "1"), ("omega_BN_B", 3, "rad/s"), ("r_BN_N", 3, "m"),
            ("v_BN_N", 3, "m/s")]
    if scene.truth.has_field:
        cols.append(("b_true_B", 3, "T"))
    for name in scene.emulators:
        cols += [(f"{name}.mag_S", 3, "T"), (f"{name}.mag_coil_active", 1, "1"),
                 (f"{name}.dipole_B", 3, "A m^2")]
    if scene.controller is not None and hasattr(scene.controller, "last_command"):
        cols.append(("dipole_cmd_B", 3, "A m^2"))
    for link in scene.sun_sensors.values():
        cols += link.columns()
    for link in scene.trackers.values():
        cols += link.columns()
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


def run(scene: Scene, out_dir, *, speed: float | None = None, duration_s: float | None = None,
        progress: bool = False, clock=time.monotonic, sleep=time.sleep) -> RunResult:
    """Run the scene, recording into ``out_dir``. Returns how it went; never leaves a bus open."""
    sc = scene.scenario
    truth = scene.truth
    duration = sc.duration_s if duration_s is None else duration_s
    n_steps = seconds_to_ns(duration) // truth.step_ns
    events = EventLog(out_dir)
    recorder = Recorder(out_dir, columns(scene))
    pacer = Pacer(speed, sc.step_s, clock=clock, sleep=sleep)
    bar = Progress(n_steps * sc.step_s, progress)
    emulators = list(scene.emulators.values())
    trackers = list(scene.trackers.values())
    sun_sensors = [(link, ticks_per(link.spec.rate_hz, sc.step_s)) for link in scene.sun_sensors.values()]
    hosts = list(scene.hosts.values())
    controller = scene.controller
    ctl_every = ticks_per(sc.controller.rate_hz, sc.step_s) if controller is not None else 0
    rec_every = ticks_per(sc.record_rate_hz, sc.step_s)
    has_field = truth.has_field
    record_cmd = controller is not None and hasattr(controller, "last_command")
    watches = [DeviceWatch(d.name, scene.hosts[d.name], 1.0 / d.sample_rate_hz, events)
               for d in sc.devices if d.name in scene.hosts]  # CAN boards
    watch_every = ticks_per(1.0, sc.step_s)
    status, error = "completed", None
    events.log("start", f"scenario {sc.name} for {duration:g} s", speed=speed)
    # The tick below runs tens of thousands of times per orbit: what it calls is bound to locals
    # once here, and the dipoles travel as tuples of floats (no arrays, no float() per tick).
    wait = pacer.wait if pacer.factor is not None else None
    step = truth.step
    ctl_update = controller.update if controller is not None else None
    show = bar.update if progress else None
    record = recorder.record
    wall0 = clock()
    pacer.begin()
    k = 0
    try:
        while True:
            t = truth.t_ns / 1e9
            if wait is not None:
                wait(t)
            for emu in emulators:
                emu.publish(t)
            for link in trackers:
                link.step(t)
            for sensor, every in sun_sensors:
                if k % every == 0:
                    sensor.step(t)
            if ctl_update is not None and k % ctl_every == 0 and k < n_steps:
                ctl_update(t)
            dx = dy = dz = 0.0
            held = []
            for emu in emulators:
                emu.receive(t)
                m = emu.dipole_xyz_at(t)
                held.append(m)
                dx, dy, dz = dx + m[0], dy + m[1], dz + m[2]
            if k % rec_every == 0 or k == n_steps:
                row = (t, *truth.q, *truth.w, *truth.r_N, *truth.v_N)
                if has_field:
                    row += truth.b_B()
                for host, m in zip(hosts, held, strict=True):
                    host.poll()  # log every sample that crossed the bus, not only those the ADCS took
                    s = host.latest_sample
                    row += (*s.b_T, float(s.coil_active), *m) if s else (*NAN3, math.nan, *m)
                if record_cmd:
                    row += tuple(controller.last_command)
                for sensor, _ in sun_sensors:
                    row += sensor.last
                for link in trackers:
                    row += link.last
                record(row)
                if show is not None:
                    show(t)
            if k % watch_every == 0:
                for w in watches:
                    w.host.poll()
                    w.check(t)
            if k >= n_steps:
                break
            step((dx, dy, dz))
            k += 1
    except KeyboardInterrupt:
        status, error = "stopped", f"stopped by the operator at t = {truth.t_s:.3f} s"
    except (DriverError, ValueError, FloatingPointError) as exc:
        status, error = "aborted", f"at t = {truth.t_s:.3f} s: {exc}"
    finally:
        wall = clock() - wall0
        recorder.close()
        bar.update(truth.t_s, force=True)
        counters = {name: dict(h.counters) for name, h in scene.hosts.items()}
        counters.update({f"{name}.emulator": dict(e.counters) for name, e in scene.emulators.items()})
        for w in watches:
            counters[w.name]["silences"] = w.silences
        for name, link in scene.trackers.items():
            counters[name] = link.summary()
        for name, sensor in scene.sun_sensors.items():
            counters[name] = sensor.summary()
        if error:
            events.log(status, error)
        events.log("end", status, ticks=k, wall_time_s=wall)
        events.close()
    timing = {"ticks": k, **pacer.stats()}
    return RunResult(status, k * sc.step_s, wall, k, timing, error, counters)
