"""Star trackers in the loop: an emulator on one end of a serial line, the host driver on the other.

The stand hands the emulator a measurement source (``TrackerTruth`` at an exposure time: the
tracker-frame attitude, its rate, and the Sun, Moon and Earth seen from the spacecraft) and reads
the solutions back through the real protocol (SLIP frames, CRC, the ICD of
``fixtures/devices/star_tracker.toml``). Each solution is compared with the truth at its
mid-exposure time, recovered from the device time stamp through the emulator's clock model, so the
summary reports what a flight computer would have received and how wrong it was.

Two sources feed the emulator. ``truth``: the true attitude, to which the emulator adds its
configured noise. ``image``: the star screen renders the tracker's detector image at the true
attitude, camera noise is added and ``star_screen.tracking`` solves it (``ImageSolver``); the
emulator is handed the solved attitude and the stars matched, with its own noise at 0. The Sun,
Moon and Earth (hence the exclusion flags), the rate flag, the state machine and the protocol are
the same for both.
"""

from __future__ import annotations

import math
import os
import select
import time
from dataclasses import dataclass, field

import numpy as np

from drivers.errors import DeviceTimeoutError
from sim.constants import R_EARTH
from sim.environment import R_SUN
from sim.rotations import axis_angle, compose, conjugate, dcm, quat_from_axis_angle
from sim.truth import compose_floats, rotate_to_body

ARCSEC = math.pi / 180.0 / 3600.0
#: Longest wall-clock wait for a frame to cross the in-process serial line before it counts as lost.
SETTLE_TIMEOUT_S = 1.0
R_MOON = 1.7374e6
#: The Earth's disk as a tracker sees it includes the bright atmosphere.
ATMOSPHERE_M = 100e3
FLAG_BITS = {"sun_in_field": 1, "moon_in_field": 2, "earth_in_field": 4, "rate_too_high": 8}
MODES = {"BOOT": 0, "LOST_IN_SPACE": 1, "TRACKING": 2}
#: The telemetry fragment before the first solution arrives (widths of TrackerLink.columns()).
NO_SOLUTION = (math.nan,) * 10


def attitude_error_arcsec(q_true, q_meas) -> tuple[float, float]:
    """(cross-boresight, roll) error of a measured tracker attitude, arcsec (boresight +z)."""
    E = dcm(q_meas) @ dcm(q_true).T  # small rotation from true to measured tracker axes
    theta = 0.5 * np.array([E[1, 2] - E[2, 1], E[2, 0] - E[0, 2], E[0, 1] - E[1, 0]])
    return math.hypot(theta[0], theta[1]) / ARCSEC, abs(theta[2]) / ARCSEC


@dataclass
class TrackerLink:
    name: str
    emulator: object
    host: object
    q_SB: tuple
    truth_at: dict = field(default_factory=dict)  # exposure time (us of sim time) -> q_TN
    slave_fd: int | None = None
    solutions: int = 0
    valid: int = 0
    flags: dict = field(default_factory=lambda: dict.fromkeys(FLAG_BITS, 0))
    errors: list = field(default_factory=list)  # (t_s, cross, roll) of valid solutions
    last: tuple = NO_SOLUTION  # the newest solution as a telemetry row fragment (see columns())
    last_solution: object | None = None  # the newest decoded SOLUTION message, as the host got it
    image: object | None = None  # the ImageSolver of an image-source tracker

    def sim_time_of(self, time_us: int) -> float:
        """Invert the device clock (offset and drift; the stand never sends SET_TIME in a run)."""
        cfg = self.emulator.config
        return (time_us * 1e-6 - cfg.clock_offset_s) / (1.0 + cfg.clock_drift_ppm * 1e-6)

    def _frames_in(self, counters: dict) -> int:
        return counters["frames_received"] + sum(v for k, v in counters.items() if k.startswith("rejected"))

    def _settle(self, done, port) -> None:
        """Wait (wall clock, bounded) until the other end has the frames written to it.

        A pty hands bytes over asynchronously: an as-fast-as-possible loop would otherwise see a
        frame one or many ticks late, a different number each run. Waiting for the exchange to
        complete makes every run take the same tick for every frame, as a paced bench would.
        """
        deadline = time.monotonic() + SETTLE_TIMEOUT_S
        while not done():
            left = deadline - time.monotonic()
            if left <= 0:
                raise DeviceTimeoutError(
                    f"{self.name}: a frame written to the serial line did not arrive within {SETTLE_TIMEOUT_S:g} s.",
                    device=self.name, awaited="frames written to the serial line", timeout_s=SETTLE_TIMEOUT_S)
            select.select([port.fileno()], [], [], min(left, 0.01))
            if port is self.host.port:
                self.host.poll()
            else:
                return  # the emulator reads in service(); it only had to be readable

    def step(self, t_s: float) -> None:
        emu, host = self.emulator, self.host
        if host.counters["sent"] > self._frames_in(emu.counters):
            self._settle(lambda: emu.port.in_waiting > 0, emu.port)
        emu.service(t_s)
        if emu.counters["sent"] > self._frames_in(host.counters):
            self._settle(lambda: self._frames_in(host.counters) >= emu.counters["sent"], host.port)
        sol = host.take_solution()
        if sol is None:
            return
        self.last_solution = sol
        self.solutions += 1
        for flag in FLAG_BITS:
            self.flags[flag] += bool(getattr(sol, flag))
        t_exp = self.sim_time_of(sol.time_us)
        q_true = self.truth_at.pop(round(t_exp * 1e6), None)
        cross = roll = math.nan
        if q_true is not None:
            cross, roll = attitude_error_arcsec(q_true, sol.q_TN)
        if sol.valid:
            self.valid += 1
            self.errors.append((t_exp, cross, roll))
        bits = sum(b for f, b in FLAG_BITS.items() if getattr(sol, f))
        self.last = (t_exp, *sol.q_TN, float(sol.valid), float(MODES.get(sol.mode, -1)), float(bits), cross, roll)
        # Keep the truth log short: exposures older than a few seconds will never be reported.
        if len(self.truth_at) > 256:
            for k in sorted(self.truth_at)[:-64]:
                del self.truth_at[k]

    def columns(self) -> list[tuple[str, int, str]]:
        """Telemetry of the newest solution the host received (repeated until the next): exposure
        time in sim time, q_TN, valid, mode (0 boot, 1 lost in space, 2 tracking), flag bits (1 Sun,
        2 Moon, 4 Earth, 8 rate), and its error against the truth at that exposure."""
        n = self.name
        return [(f"{n}.t_exposure_s", 1, "s"), (f"{n}.q_TN", 4, "1"), (f"{n}.valid", 1, "1"),
                (f"{n}.mode", 1, "1"), (f"{n}.flags", 1, "1"), (f"{n}.err_cross", 1, "arcsec"),
                (f"{n}.err_roll", 1, "arcsec")]

    def summary(self) -> dict:
        err = np.array([e[1:] for e in self.errors if math.isfinite(e[1])]).reshape(-1, 2)
        out = {"solutions": self.solutions, "valid": self.valid,
               "availability": round(self.valid / self.solutions, 4) if self.solutions else 0.0,
               "flags_fired": dict(self.flags), "host_counters": dict(self.host.counters),
               "emulator_counters": dict(self.emulator.counters)}
        if self.image is not None:
            out["image"] = self.image.summary()
        if len(err):
            for i, axis in enumerate(("cross", "roll")):
                out[f"error_{axis}_arcsec"] = {p: round(float(np.percentile(err[:, i], q)), 3)
                                               for p, q in (("median", 50), ("p95", 95), ("max", 100))}
        return out

    def close(self) -> None:
        self.host.close()
        self.emulator.close()
        if self.slave_fd is not None:
            os.close(self.slave_fd)
            self.slave_fd = None


class ImageSolver:
    """The image source of one tracker: render its detector image, add camera noise, solve it.

    Built once at compose time (renderer, catalog places, pattern database), so the first exposure
    costs what every other does. ``solve`` renders at the TRUE tracker attitude with orbital and
    annual aberration (``v_N``: the spacecraft's velocity) and the rate smear of the exposure, adds
    shot, background and read noise from its own seeded Generator, and solves the image against
    apparent places: tracking from the previous exposure's solution (propagated by the rotation
    between the two solutions before it, as a tracker's own rate estimate) when that one was valid,
    lost in space otherwise (and when tracking finds no match).
    """

    def __init__(self, optics, camera: dict, epoch, rng: np.random.Generator):
        from star_screen.geometry import default_bench
        from star_screen.render import Renderer
        from star_screen.tracking import StarTracker

        self.optics = optics
        self.camera = dict(camera)
        self.epoch = epoch
        self.rng = rng
        self.renderer = Renderer(default_bench(tracker=optics), aberration=True)
        self.tracker = StarTracker(catalog=self.renderer.catalog, mag_limit=optics.mag_limit, epoch=epoch)
        self.tracker.database(optics)  # the pattern database (about 1 s), now rather than on the first tick
        self.tracker.places(epoch, parallax=True)  # apparent places at the scenario epoch, cached
        self.exposure = self.tracker.sparse_exposure(optics, **self.camera)  # noise drawn where extraction looks
        self._last: tuple[float, np.ndarray] | None = None  # (t_s, q) of the previous exposure if valid
        self._before: tuple[float, np.ndarray] | None = None  # the valid one before it
        self.counts = {"frames": 0, "lis": 0, "tracking": 0, "failed": 0}
        self.frame_ms: list[float] = []

    def _prior(self, t_s: float):
        if self._last is None:
            return None
        t1, q1 = self._last
        if self._before is None:
            return q1
        t0, q0 = self._before
        axis, angle = axis_angle(compose(q1, conjugate(q0)))  # rotation of the tracker axes from t0 to t1
        return compose(quat_from_axis_angle(axis, float(angle) * (t_s - t1) / (t1 - t0)), q1)

    def solve(self, t_s: float, q_TN, omega_TN_T, v_N) -> dict:
        """TrackerTruth fields measured from the exposure at ``t_s``: the solved q_TN, stars centroided
        and matched, 1-sigma errors (rad); an identity attitude and 0 stars matched when the solve fails."""
        w0 = time.perf_counter()
        epoch = self.epoch + t_s
        v = np.asarray(v_N, dtype=float)
        _, lit, signal_e = self.renderer.detector_signal(q_TN, epoch, v_sc_gcrs_m_s=v, omega_SN_S=omega_TN_T)
        sol = self.tracker.solve_stars(self.exposure.stars(lit, signal_e, self.rng), self.optics, self._prior(t_s),
                                       observer_velocity_m_s=self.renderer.observer_velocity(epoch, v))
        self.counts["frames"] += 1
        self.frame_ms.append((time.perf_counter() - w0) * 1e3)
        seen = {"stars_in_field": int(sol.stars_centroided)}
        if not sol.valid:
            self.counts["failed"] += 1
            self._last = self._before = None
            return {"q_TN": (1.0, 0.0, 0.0, 0.0), "stars_matched": 0, **seen}
        self.counts[sol.mode] += 1
        self._before, self._last = self._last, (t_s, sol.q_SN)
        return {"q_TN": tuple(float(x) for x in sol.q_SN), "stars_matched": int(sol.stars_matched),
                "sigma_cross_rad": float(sol.sigma_cross_arcsec) * ARCSEC,
                "sigma_roll_rad": float(sol.sigma_roll_arcsec) * ARCSEC, **seen}

    def summary(self) -> dict:
        ms = np.asarray(self.frame_ms)
        out = dict(self.counts)
        if len(ms):
            out["frame_ms"] = {"median": round(float(np.median(ms)), 2), "p95": round(float(np.percentile(ms, 95)), 2),
                               "max": round(float(ms.max()), 2)}
        return out


def _sky_truth(spec, truth, tracks: dict, link: TrackerLink):
    """``fields(t_s)``: the TrackerTruth fields at an exposure (true q_TN, rate, Sun, Moon and Earth in
    tracker axes), logging the true attitude in ``link.truth_at``; shared by every source."""
    q_SB = link.q_SB
    bodies: dict[int, dict] = {}  # Sun and Moon per whole second: from LEO they move < 5 arcsec/s

    def fields(t_s: float) -> dict:
        if abs(t_s - truth.t_s) > 1e-6:
            raise ValueError(f"{spec.name}: exposure at t = {t_s:.6f} s but the truth is at {truth.t_s:.6f} s; "
                             "the output interval and boot time must be whole dynamics steps.")
        q_TN = compose_floats(q_SB, truth.q)
        link.truth_at[round(t_s * 1e6)] = q_TN
        rx, ry, rz = truth.r_N
        rn = math.sqrt(rx * rx + ry * ry + rz * rz)
        out = {"q_TN": q_TN, "omega_TN_T": rotate_to_body(q_SB, truth.w),
               "earth_T": rotate_to_body(q_TN, (-rx, -ry, -rz)),
               "earth_radius_rad": math.asin(min(1.0, (R_EARTH + ATMOSPHERE_M) / rn))}
        second = int(t_s)
        if second not in bodies:
            bodies.clear()
            bodies[second] = {b: tracks[b].position_gcrs(float(second)) for b in ("sun", "moon") if b in tracks}
        for body, radius in (("sun", R_SUN), ("moon", R_MOON)):
            if body in bodies[second]:
                bx, by, bz = bodies[second][body]
                d = (bx - rx, by - ry, bz - rz)
                out[f"{body}_T"] = rotate_to_body(q_TN, d)
                out[f"{body}_radius_rad"] = math.asin(radius / math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2))
        return out

    return fields


def build_tracker(spec, truth, tracks: dict, rng: np.random.Generator, epoch=None) -> TrackerLink:
    """Emulator + host for one ``StarTrackerSpec``, wired to the truth model and the Sun/Moon tracks.

    ``source = "truth"``: the emulator is handed the true attitude and adds its configured noise.
    ``source = "image"``: the attitude handed over is the one solved from the rendered, noisy
    detector image (``ImageSolver``; ``epoch`` is the scenario epoch, required), with the stars it
    matched (0 when the solve failed); the scenario set the emulator's own noise to 0. Either way the
    emulator's state machine, exclusion and rate flags and the serial protocol are the same, and
    ``link.truth_at`` keeps the true attitude that the solutions are scored against.
    """
    from drivers.serial_port import pty_pair
    from drivers.star_tracker.codec import Subscribe
    from drivers.star_tracker.emulator import EmulatorConfig, StarTrackerEmulator, TrackerTruth
    from drivers.star_tracker.host import StarTrackerHost

    q_SB = tuple(float(x) for x in spec.q_SB)
    link = TrackerLink(spec.name, None, None, q_SB)
    fields = _sky_truth(spec, truth, tracks, link)

    if spec.source == "image":
        if epoch is None:
            raise ValueError(f"{spec.name}: an image-source tracker needs the scenario epoch "
                             "(build_tracker(..., epoch=...)).")
        # The camera's own stream, spawned from the tracker's seed, so the emulator's draws are unchanged.
        link.image = solver = ImageSolver(spec.optics, spec.camera, epoch, rng.spawn(1)[0])

        def measure(t_s: float) -> TrackerTruth:
            out = fields(t_s)
            out.update(solver.solve(t_s, out["q_TN"], out["omega_TN_T"], truth.v_N))
            return TrackerTruth(**out)
    else:
        def measure(t_s: float) -> TrackerTruth:
            return TrackerTruth(**fields(t_s))

    config = EmulatorConfig(address=spec.address, **spec.emulator)
    # An in-process pty pair: the same kernel tty path a bench would use, without a second process.
    emulator_port, host_port, link.slave_fd = pty_pair()
    link.emulator = StarTrackerEmulator(emulator_port, measure, config, rng, name=f"{spec.name} emulator")
    try:
        link.host = StarTrackerHost(host_port, spec.address, name=spec.name)
        # Not the blocking subscribe(): nothing services the emulator while the host would wait.
        link.host.send_command(Subscribe(link.host.codec.solution_id, 0.0))
    except BaseException:
        link.emulator.close()
        os.close(link.slave_fd)
        raise
    return link
