"""Star trackers in the loop: an emulator on one end of a serial line, the host driver on the other.

The stand hands the emulator a measurement source (``TrackerTruth`` at an exposure time: the
tracker-frame attitude, its rate, and the Sun, Moon and Earth seen from the spacecraft) and reads
the solutions back through the real protocol (SLIP frames, CRC, the ICD of
``fixtures/devices/star_tracker.toml``). Each solution is compared with the truth at its
mid-exposure time, recovered from the device time stamp through the emulator's clock model, so the
summary reports what a flight computer would have received and how wrong it was.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from sim.constants import R_EARTH
from sim.environment import R_SUN
from sim.rotations import dcm
from sim.truth import compose_floats, rotate_to_body

ARCSEC = math.pi / 180.0 / 3600.0
R_MOON = 1.7374e6
#: The Earth's disk as a tracker sees it includes the bright atmosphere.
ATMOSPHERE_M = 100e3
FLAG_BITS = {"sun_in_field": 1, "moon_in_field": 2, "earth_in_field": 4, "rate_too_high": 8}
MODES = {"BOOT": 0, "LOST_IN_SPACE": 1, "TRACKING": 2}


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
    last: tuple | None = None  # the newest solution as a telemetry row fragment

    def sim_time_of(self, time_us: int) -> float:
        """Invert the device clock (offset and drift; the stand never sends SET_TIME in a run)."""
        cfg = self.emulator.config
        return (time_us * 1e-6 - cfg.clock_offset_s) / (1.0 + cfg.clock_drift_ppm * 1e-6)

    def step(self, t_s: float) -> None:
        self.emulator.service(t_s)
        sol = self.host.take_solution()
        if sol is None:
            return
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

    def summary(self) -> dict:
        err = np.array([e[1:] for e in self.errors if math.isfinite(e[1])]).reshape(-1, 2)
        out = {"solutions": self.solutions, "valid": self.valid,
               "availability": round(self.valid / self.solutions, 4) if self.solutions else 0.0,
               "flags_fired": dict(self.flags), "host_counters": dict(self.host.counters),
               "emulator_counters": dict(self.emulator.counters)}
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


def build_tracker(spec, truth, tracks: dict, rng: np.random.Generator) -> TrackerLink:
    """Emulator + host for one ``StarTrackerSpec``, wired to the truth model and the Sun/Moon tracks."""
    from drivers.serial_port import pty_pair
    from drivers.star_tracker.codec import Subscribe
    from drivers.star_tracker.emulator import EmulatorConfig, StarTrackerEmulator, TrackerTruth
    from drivers.star_tracker.host import StarTrackerHost

    q_SB = tuple(float(x) for x in spec.q_SB)
    link = TrackerLink(spec.name, None, None, q_SB)

    bodies: dict[int, dict] = {}  # Sun and Moon per whole second: from LEO they move < 5 arcsec/s

    def measure(t_s: float) -> TrackerTruth:
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
        return TrackerTruth(**out)

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
