"""``stand bench cage``: the Helmholtz cage over Modbus.

1. **Update rate** (wall time): the cage emulator running its coils on the wall clock behind a
   pymodbus TCP server on 127.0.0.1, the host driver on pymodbus's client. One control tick is two
   requests: the command (function 16: polarity, three set points, heartbeat) and the field read
   (function 4: 16 registers). Rows: one read's round trip, one tick, and the tick rate the link
   sustains. The same over Modbus RTU on a socat pty pair (115200 baud configured; a pty does not
   throttle to the baud rate, so the wire time of a real line is added in a note).
2. **Field following** (sim time, through the same Modbus TCP path): the host commands a simulated
   LEO field profile at a 10 Hz control rate through the calibration it measured first
   (``drivers.cage.calibration``); the emulator is stepped in sim time, so the figures do not depend
   on this machine's load. Profile: a 500 km circular orbit at 97.4 deg in the centred-dipole field
   (``sim.environment``), seen in body axes of a spacecraft tumbling at a constant rate; the cage
   field at the test position (noiseless, from the emulator) is compared with the profile every
   10 ms after the first second. Rows: RMS and peak error (nT), the lag that best aligns the two,
   and the same figures when the host commands the profile half a control period plus one coil
   time constant ahead (lead compensation), plus the polarity flips the profile needed.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from sim.constants import MU_EARTH, OMEGA_EARTH, R_EARTH
from sim.environment import dipole_field_itrs
from sim.frames import rotation_z
from sim.orbit import elements_to_state
from sim.rotations import dcm, quat_from_axis_angle

CONTROL_PERIOD_S = 0.1
EVAL_PERIOD_S = 0.01


class LeoProfile:
    """Field (T) in body axes along a circular LEO, tumbling at ``rate_deg_s`` about ``axis``."""

    def __init__(self, rate_deg_s: float, axis=(0.3, -0.5, 0.8), altitude_m: float = 500e3,
                 inclination_deg: float = 97.4) -> None:
        self.a = R_EARTH + altitude_m
        self.i = math.radians(inclination_deg)
        self.rate = math.radians(rate_deg_s)
        self.axis = np.asarray(axis, dtype=float)
        self.n = math.sqrt(MU_EARTH / self.a**3)

    def __call__(self, t_s) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        r_N, _ = elements_to_state(e=0.0, i=self.i, raan=0.3, argp=0.0, a=self.a, M=self.n * t)
        rot = rotation_z(OMEGA_EARTH * t)  # ITRS from GCRS, Earth rotation alone (enough for a profile)
        r_itrs = np.einsum("nij,nj->ni", rot, r_N)
        b_N = np.einsum("nji,nj->ni", rot, dipole_field_itrs(r_itrs))
        dcm_BN = dcm(quat_from_axis_angle(self.axis, self.rate * t))
        b_B = np.einsum("nij,nj->ni", dcm_BN, b_N)
        return b_B if np.ndim(t_s) else b_B[0]


def _pct(x, q) -> float:
    return float(np.percentile(np.asarray(x), q))


def _tick_times(host, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Round trips (s) of ``n`` field reads and of ``n`` ticks (command + read)."""
    reads, ticks = [], []
    for k in range(n):
        t0 = time.perf_counter()
        host.take_field()
        reads.append(time.perf_counter() - t0)
        c = 0.5 + 0.1 * math.sin(k / 50.0)
        t0 = time.perf_counter()
        host.command_currents((c, -c, 0.2))
        host.take_field()
        ticks.append(time.perf_counter() - t0)
    return np.array(reads), np.array(ticks)


def _link_rows(name: str, reads: np.ndarray, ticks: np.ndarray, note: str, anchor: str | None = None) -> list[dict]:
    med = float(np.median(ticks))
    rows = [
        {"name": f"cage.{name}.read16.median", "value": round(float(np.median(reads)) * 1e3, 3), "unit": "ms",
         "note": note},
        {"name": f"cage.{name}.read16.p99", "value": round(_pct(reads, 99) * 1e3, 3), "unit": "ms"},
        {"name": f"cage.{name}.tick.median", "value": round(med * 1e3, 3), "unit": "ms",
         "note": "one control tick: write polarity + set points + heartbeat, read field + currents + flags"},
        {"name": f"cage.{name}.tick.p99", "value": round(_pct(ticks, 99) * 1e3, 3), "unit": "ms"},
        {"name": f"cage.{name}.update_rate", "value": round(1.0 / med, 1), "unit": "Hz",
         "limit": ">= 10 (the control rate)", "pass": 1.0 / med >= 10.0},
    ]
    if anchor:
        rows[-1]["anchor"] = anchor
    return rows


def _bench_tcp(n: int) -> list[dict]:
    from drivers.cage.emulator import CageEmulator
    from drivers.cage.host import CageHost

    with CageEmulator() as emu:  # wall time
        _, port = emu.serve_tcp("127.0.0.1", 0)
        with CageHost.open(f"tcp://127.0.0.1:{port}") as host:
            host.enable()
            reads, ticks = _tick_times(host, n)
            host.safe_off()
    return _link_rows("tcp", reads, ticks, f"Modbus TCP on 127.0.0.1, wall-time emulator, {n} of each",
                      anchor="100 Hz control thread of the TU Delft cage toolkit")


def _bench_rtu(n: int) -> list[dict]:
    from drivers.cage.emulator import CageEmulator
    from drivers.cage.host import CageHost

    if shutil.which("socat") is None:
        return [{"name": "cage.rtu", "value": "skipped", "unit": "", "note": "socat is not installed"}]
    with tempfile.TemporaryDirectory() as tmp:
        a, b = Path(tmp) / "dev", Path(tmp) / "host"
        socat = subprocess.Popen(["socat", f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            deadline = time.monotonic() + 5.0
            while not (a.exists() and b.exists()) and time.monotonic() < deadline:
                time.sleep(0.02)
            with CageEmulator() as emu:
                emu.serve_rtu(str(a), baudrate=115200)
                with CageHost.open(str(b), baudrate=115200, timeout_s=1.0) as host:
                    host.enable()
                    reads, ticks = _tick_times(host, n)
                    host.safe_off()
        finally:
            socat.terminate()
            socat.wait(5)
    # RTU bytes per tick: read request 8, reply 37; write request 19, reply 8; 10 bit times per byte at 8N1
    wire_ms = (8 + 37 + 19 + 8) * 10 / 115200 * 1e3
    return _link_rows("rtu", reads, ticks, f"Modbus RTU over a socat pty pair, {n} of each; a real 115200-baud "
                      f"line adds {wire_ms:.1f} ms of wire time per tick (a pty does not throttle)")


def _follow(rate_deg_s: float, duration_s: float, lead_s: float, seed: int = 0):
    """Run the 10 Hz loop in sim time; returns (t, b_cage, b_profile, commanded flips)."""
    from drivers.cage.calibration import run_calibration
    from drivers.cage.emulator import CageEmulator
    from drivers.cage.host import CageHost

    profile = LeoProfile(rate_deg_s)
    emu = CageEmulator(clock=None, rng=seed)
    _, port = emu.serve_tcp("127.0.0.1", 0)
    clock = [0.0]

    def wait(seconds: float) -> None:
        clock[0] += seconds
        emu.step(clock[0])

    ts, cage, flips = [], [], 0
    try:
        with CageHost.open(f"tcp://127.0.0.1:{port}") as host:
            host.enable()
            host.calibration = run_calibration(host, wait=wait, settle_s=0.3, samples=5)
            t0 = clock[0]
            sub = round(CONTROL_PERIOD_S / EVAL_PERIOD_S)
            last_sign = None
            for k in range(round(duration_s / CONTROL_PERIOD_S)):
                tk = k * CONTROL_PERIOD_S
                host.take_field()  # what a controller reads each tick (the figures use the noiseless field)
                currents = host.command_field(profile(tk + lead_s))
                sign = tuple(np.sign(currents))
                if last_sign is not None:
                    flips += sum(1 for a, b in zip(sign, last_sign, strict=True) if a != b)
                last_sign = sign
                for j in range(1, sub + 1):
                    wait(EVAL_PERIOD_S)
                    ts.append(tk + j * EVAL_PERIOD_S)
                    cage.append(emu.cage_field_T())
                assert abs(clock[0] - t0 - (k + 1) * CONTROL_PERIOD_S) < 1e-6
            host.safe_off()
    finally:
        emu.close()
    t = np.array(ts)
    return t, np.array(cage), profile, flips


def _errors(t: np.ndarray, cage: np.ndarray, profile) -> tuple[float, float, float, float]:
    keep = t >= 1.0
    t, cage = t[keep], cage[keep]
    err = np.linalg.norm(cage - profile(t), axis=1)
    lags = np.arange(0.0, 0.301, 0.001)
    rms_at = [float(np.sqrt(np.mean(np.sum((cage - profile(t - lag)) ** 2, axis=1)))) for lag in lags]
    best = int(np.argmin(rms_at))
    return float(np.sqrt(np.mean(err**2))), float(err.max()), float(lags[best]), rms_at[best]


def bench_cage(quick: bool = False, plot_path: str | None = None) -> list[dict]:
    from drivers.cage.model import CageConfig

    rows = _bench_tcp(300 if quick else 2000)
    rows += _bench_rtu(50 if quick else 300)
    cfg = CageConfig()
    tau = max(L / R for L, R in zip(cfg.inductance_H, cfg.resistance_ohm, strict=True))
    lead = CONTROL_PERIOD_S / 2 + tau
    duration = 30.0 if quick else 300.0
    for rate in (0.5, 5.0):
        name = f"cage.follow.tumble_{rate:g}deg_s"
        t, cage, profile, flips = _follow(rate, duration, 0.0)
        rms, peak, lag, rms_lag = _errors(t, cage, profile)
        t2, cage2, _, _ = _follow(rate, duration, lead)
        rms2, peak2, lag2, _ = _errors(t2, cage2, profile)
        span = np.ptp(profile(t), axis=0).max() * 1e9
        rows += [
            {"name": f"{name}.rms", "value": round(rms * 1e9, 2), "unit": "nT",
             "note": f"10 Hz control, {duration:g} s sim time, profile spans {span:.0f} nT, {flips} polarity flips"},
            {"name": f"{name}.peak", "value": round(peak * 1e9, 2), "unit": "nT"},
            {"name": f"{name}.lag", "value": round(lag * 1e3, 1), "unit": "ms",
             "note": f"RMS {rms_lag * 1e9:.2f} nT once shifted by it"},
            {"name": f"{name}.lead.rms", "value": round(rms2 * 1e9, 2), "unit": "nT",
             "note": f"commanding {lead * 1e3:.0f} ms ahead (half a period + L/R)"},
            {"name": f"{name}.lead.peak", "value": round(peak2 * 1e9, 2), "unit": "nT"},
            {"name": f"{name}.lead.lag", "value": round(lag2 * 1e3, 1), "unit": "ms"},
        ]
        if plot_path is not None and rate == 5.0:
            _plot(Path(plot_path), t, cage, cage2, profile)
            rows.append({"name": "cage.plot", "value": str(Path(plot_path).resolve()), "unit": "",
                         "note": "commanded profile, cage field and error, tumbling at 5 deg/s"})
    return rows


def _plot(path: Path, t, cage, cage_lead, profile) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keep = (t >= 1.0) & (t <= 61.0)
    t, cage, cage_lead = t[keep], cage[keep], cage_lead[keep]
    b = profile(t)
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for i, c in enumerate("xyz"):
        ax1.plot(t, b[:, i] * 1e6, color=f"C{i}", lw=1, label=f"profile {c}")
        ax1.plot(t, cage[:, i] * 1e6, color=f"C{i}", lw=0.8, ls="--")
    ax1.set_ylabel("field, uT (dashed: cage)")
    ax1.legend(loc="upper right", fontsize=8)
    ax2.plot(t, np.linalg.norm(cage - b, axis=1) * 1e9, lw=0.7, label="as commanded")
    ax2.plot(t, np.linalg.norm(cage_lead - b, axis=1) * 1e9, lw=0.7, label="commanded ahead")
    ax2.set_ylabel("|error|, nT")
    ax2.set_xlabel("sim time, s")
    ax2.legend(loc="upper right", fontsize=8)
    fig.suptitle("Cage following a LEO field profile at 10 Hz over Modbus TCP (tumbling 5 deg/s)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
