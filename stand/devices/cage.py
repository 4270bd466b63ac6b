"""Helmholtz cage: a stimulator that reproduces the simulated magnetic field around a magnetometer on the bench
(``drivers.cage``: Modbus register map ``fixtures/devices/cage.toml``).

The board under test sits still in the lab, so the cage makes the field the spacecraft would see in body axes
(cage axes = body axes). At its command rate the stand asks the cage, through the host driver and the real
Modbus protocol, for the truth's field (optionally ``lead_s`` ahead, extrapolated, to make up for the coils' lag);
a magnetometer whose scenario table says ``field_source = "NAME"`` reads the cage's field, not the truth.

Links: ``emulated`` (the cage emulator served over Modbus TCP on 127.0.0.1, stepped in sim time: coil L/R
dynamics, supply slew and current limits, polarity relays, interlocks, lab field) and ``hardware`` (a real cage
at ``url``, with its calibration file: coil constants and lab field from ``stand``'s calibration routine).

A real cage switches itself off when its heartbeat stops for ``heartbeat_timeout_s`` (0.5 s on the nominal bench),
which an operator's pause or a stalled loop would otherwise cause: on a hardware link a keepalive thread, apart from
the loop, writes a heartbeat whenever the loop has not commanded the cage for a quarter of that timeout. Every
command tick reads the cage's status back; a cage found off is logged (``cage_trip``), switched on again
(``cage_reenabled``) or, when it refuses, ends the run as aborted; the summary counts both.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from stand.checks import rate, ticks_per
from stand.devices import BuildContext, Device, DeviceKind, DeviceSpec, check_serial_url
from stand.devices.serving import ServeOption, Serving, banner, report, serve_until_stopped, stop_on_sigterm

NT = 1e-9
#: The following error is scored after the cage has come up from zero to the first field (its supplies slew).
SETTLE_S = 2.0
#: The keepalive writes a heartbeat once the loop has been silent for this fraction of the cage's heartbeat timeout
#: (and looks that often): three chances before the cage would trip.
KEEPALIVE_FRACTION = 0.25


@dataclass(frozen=True)
class CageSpec(DeviceSpec):
    url: str = ""
    calibration: str | None = None
    rate_hz: float = 10.0
    lead_s: float = 0.0
    lab_field_T: tuple | None = None
    current_limit_A: float | None = None
    slew_limit_A_s: float | None = None


class CageKind(DeviceKind):
    name = "cage"
    senses = ("magnetic_field",)
    column_meanings = {"b_cmd_B": "the field commanded to the cage, body axes",
                       "b_cage_B": "the field the cage produced, read back, body axes",
                       "currents": "the three axes' coil currents read back",
                       "interlocks": "the number of interlocks engaged"}
    plot_files = {"cage_{name}.png": "the cage's field against the simulated field, currents and interlocks"}
    links = ("emulated", "hardware")
    provides = ("magnetic_field",)
    metrics = {
        "cage_following_rms_nT": "RMS of the cage field's difference from the simulated field after start-up (nT)",
        "cage_following_peak_nT": "largest difference of the cage field from the simulated field after start-up (nT)",
    }

    def parse(self, t, base: DeviceSpec, step_s: float) -> CageSpec:
        url = ""
        calibration = None
        if base.link == "hardware":
            url = t.text("url")
            if not url.startswith("tcp://"):
                check_serial_url(t, "url", url)
            calibration = t.text("calibration")
        lab = t.vector("lab_field_uT", 3, lo=-1000.0, hi=1000.0) * 1e-6 if t.has("lab_field_uT") else None
        spec = CageSpec(
            **base.__dict__, url=url, calibration=calibration, rate_hz=rate(t, "rate_hz", step_s, 10.0),
            lead_s=t.number("lead_s", 0.0, lo=0.0, hi=1.0),
            lab_field_T=tuple(lab) if lab is not None else None,
            current_limit_A=t.number("current_limit_A", lo=0.01, hi=100.0) if t.has("current_limit_A") else None,
            slew_limit_A_s=t.number("slew_limit_A_s", lo=0.01, hi=1e4) if t.has("slew_limit_A_s") else None,
        )
        t.check_unknown()
        return spec

    def needs(self, spec) -> dict[str, str]:
        return {"magnetic_field": f"the field cage {spec.name} reproduces"}

    def network_peers(self, spec) -> list[tuple[str, str]]:
        if spec.link == "hardware" and spec.url.startswith("tcp://"):
            from drivers.cage.host import parse_url

            try:
                return [("url", parse_url(spec.url)[1])]
            except ValueError:
                return [("url", spec.url)]  # refused as not a host on this machine; the driver would refuse it too
        return []

    def describe(self, spec) -> str:
        lead = f", commanded {spec.lead_s:g} s ahead" if spec.lead_s else ""
        if spec.link == "hardware":
            return f"Helmholtz cage at {spec.url} (calibration {spec.calibration}), field at {spec.rate_hz:g} Hz{lead}"
        return (f"Helmholtz cage emulated on Modbus TCP 127.0.0.1 (coil L/R, slew and current limits, relays, "
                f"interlocks), commanded to the simulated body-axes field at {spec.rate_hz:g} Hz{lead}")

    def fault_taps(self, spec: CageSpec) -> dict:
        # The emulated cage's coil pairs; a real cage is the stand's own equipment, not a device under test.
        # A field step is what the cage shows the magnetometer in it, on every link.
        return {"cage": {}, "stimulus": {}} if spec.link != "hardware" else {"stimulus": {}}

    def build(self, spec: CageSpec, ctx: BuildContext) -> Device:
        return Cage(spec, ctx)

    def metric(self, metric, at_s, tel, names):
        if not names:
            return math.nan
        err = _error_nT(tel, names[0])
        if err is None or not len(err):
            return math.nan
        return float(np.sqrt(np.mean(err**2))) if metric.endswith("rms_nT") else float(err.max())

    def plots(self, tel, name, out_dir, criteria) -> list[str]:
        return [_plot(tel, name, out_dir)]


def _error_nT(tel, name: str):
    if f"{name}.b_cage_B" not in tel or "b_true_B" not in tel:
        return None
    ok = np.all(np.isfinite(tel[f"{name}.b_cage_B"]), axis=1) & (tel["t_s"] >= SETTLE_S)
    return np.linalg.norm(tel[f"{name}.b_cage_B"][ok] - tel["b_true_B"][ok], axis=1) / NT


class Cage(Device):
    #: A field added to what the cage reproduces (body axes, T), set by a ``cage_field_step`` fault: the real
    #: magnetometer in the cage sees a bias the flight code must cope with.
    field_step_B_T: tuple | None = None
    def __init__(self, spec: CageSpec, ctx: BuildContext):
        from drivers.cage.calibration import CageCalibration
        from drivers.cage.host import CageHost
        self.name, self.spec = spec.name, spec
        self.truth = ctx.truth
        self.command_every = ticks_per(spec.rate_hz, ctx.step_s)
        self.step_s = ctx.step_s
        self.emulator = None
        self._k = 0
        self._b_cmd = (math.nan,) * 3
        self._prev_target = None
        self._err2_sum, self._err_peak, self._n = 0.0, 0.0, 0
        self._lags: list[tuple] = []  # (truth b_B, cage b_B) per tick, to estimate the lag at the end
        # pymodbus's client is not thread-safe: the loop and the keepalive take turns on it
        self._io = threading.Lock()
        self._events = None
        self._last_command_s = time.monotonic()
        self._keepalive: threading.Thread | None = None
        self._stop_keepalive = threading.Event()
        self.trips = self.reenabled = self.keepalive_heartbeats = self.keepalive_errors = 0
        if spec.link == "hardware":
            self.host = CageHost.open(spec.url, calibration=CageCalibration.load(spec.calibration))
        else:
            from drivers.cage.emulator import CageEmulator
            from drivers.cage.model import CageConfig

            overrides = {k: v for k, v in (("lab_field_T", spec.lab_field_T), ("current_limit_A", spec.current_limit_A),
                                           ("slew_limit_A_s", spec.slew_limit_A_s)) if v is not None}
            self.emulator = CageEmulator(CageConfig(**overrides), rng=ctx.rng, clock=None, name=f"{spec.name} emulator")
            try:
                _, port = self.emulator.serve_tcp("127.0.0.1", 0)
                self.host = CageHost.open(f"tcp://127.0.0.1:{port}",
                                          calibration=CageCalibration.from_config(self.emulator.config))
            except BaseException:
                self.emulator.close()
                raise
        try:
            status = self.host.enable()
            if spec.link == "hardware":
                self._start_keepalive(float(status.limits["heartbeat_timeout_s"]))
        except BaseException:
            self.close()
            raise

    # -- the heartbeat while the loop is not commanding (paused, stalled) -----------------------------------------

    def _start_keepalive(self, timeout_s: float) -> None:
        period_s = max(timeout_s, 1e-3) * KEEPALIVE_FRACTION
        self._keepalive = threading.Thread(target=self._keep_alive, args=(period_s,), daemon=True,
                                           name=f"cage-keepalive {self.name}")
        self._keepalive.start()

    def _keep_alive(self, period_s: float) -> None:
        from drivers.errors import DriverError

        while not self._stop_keepalive.wait(period_s):
            if time.monotonic() - self._last_command_s < period_s:
                continue  # the loop is commanding: every command carries a heartbeat
            with self._io:
                try:
                    self.host.heartbeat()
                    self.keepalive_heartbeats += 1
                    self._last_command_s = time.monotonic()
                except DriverError:
                    self.keepalive_errors += 1  # the loop's next command meets the same fault and reports it

    def _log(self, kind: str, message: str, **fields) -> None:
        if self._events is not None:
            self._events.log(kind, message, **fields)

    def _switched_off(self, t_s: float) -> None:
        """The cage is off although the stand switched it on: log why, switch it on again, or end the run."""
        from drivers.errors import DriverError

        self.trips += 1
        st = self.host.status()
        why = ", ".join(sorted(st.interlocks)) or f"none engaged now (last: {st.last_interlock})"
        counted = {k: st.values[k] for k in ("heartbeat_trips", "over_temperature_trips")}
        self._log("cage_trip", f"{self.name}: the cage switched its outputs off by t = {t_s:.3f} s; interlocks: "
                  f"{why}; its trip counters: {counted}", t_s=t_s, interlocks=sorted(st.interlocks), **counted)
        try:
            self.host.enable()
        except DriverError as exc:
            self._log("cage_reenable_failed", f"{self.name}: {exc}", t_s=t_s)
            raise DriverError(f"{self.name}: the cage switched its outputs off by t = {t_s:.3f} s ({why}) and "
                              f"refused to switch them on again: {exc}") from None
        self.reenabled += 1
        self._log("cage_reenabled", f"{self.name}: outputs switched on again at t = {t_s:.3f} s", t_s=t_s)

    def start(self, events) -> None:
        self._events = events

    def stimulus_field_B(self) -> tuple[float, float, float]:
        """The field at the test position now (T, body axes = cage axes): what a magnetometer in the cage sees."""
        if self.emulator is not None:
            return tuple(float(x) for x in self.emulator.cage_field_T())
        with self._io:
            return self.host.take_field().b_T

    def columns(self):
        n = self.name
        return [(f"{n}.b_cmd_B", 3, "T"), (f"{n}.b_cage_B", 3, "T"), (f"{n}.currents", 3, "A"),
                (f"{n}.interlocks", 1, "1")]

    def publish(self, t_s: float) -> None:
        if self.emulator is not None:
            self.emulator.step(t_s)
        if self._k % self.command_every == 0:
            target = self.truth.b_B()
            if self.spec.lead_s and self._prev_target is not None:
                # Linear extrapolation over the lead: the coils' L/R lag and the hold of the command period.
                dt = self.command_every * self.step_s
                target = tuple(b + (b - p) * self.spec.lead_s / dt for b, p in zip(target, self._prev_target,
                                                                                  strict=True))
            self._prev_target = self.truth.b_B()
            if self.field_step_B_T is not None:  # a stimulus fault: the cage shows a field the truth does not have
                target = tuple(b + s for b, s in zip(target, self.field_step_B_T, strict=True))
            with self._io:
                self.host.command_field(target)
                self._last_command_s = time.monotonic()
                # emulated: the model says it without a request (a run at full speed makes ~10 commands a sim s)
                on = self.emulator.model.output_on if self.emulator is not None else self.host.take_field().output_on
                if not on:
                    self._switched_off(t_s)
            self._b_cmd = tuple(target)
        self._k += 1
        if t_s >= SETTLE_S:
            cage = self.stimulus_field_B()
            true = self.truth.b_B()
            e = math.dist(cage, true)
            self._err2_sum += e * e
            self._err_peak = max(self._err_peak, e)
            self._n += 1
            self._lags.append((*true, *cage))

    def row(self):
        with self._io:
            f = self.host.take_field()
        return (*self._b_cmd, *self.stimulus_field_B(), *f.currents_A, float(len(f.interlocks)))

    def activity(self) -> int:
        return self.host.counters.get("received", 0)

    def summary(self) -> dict:
        out = {"host": dict(self.host.counters), "trips": self.trips, "reenabled": self.reenabled}
        if self.spec.link == "hardware":
            out["keepalive"] = {"heartbeats": self.keepalive_heartbeats, "errors": self.keepalive_errors}
        if self.emulator is not None:
            out["emulator"] = dict(self.emulator.counters)
        if self._n:
            out["following_error_nT"] = {"rms": round(math.sqrt(self._err2_sum / self._n) / NT, 3),
                                         "peak": round(self._err_peak / NT, 3), "lag_s": self._lag_s()}
        return out

    def _lag_s(self) -> float:
        """The shift of the cage field behind the simulated one that fits best (whole ticks up to 1 s)."""
        a = np.asarray(self._lags)
        if len(a) < 20:
            return math.nan
        true, cage = a[:, :3], a[:, 3:]
        best = min(range(min(int(1.0 / self.step_s), len(a) // 2)),
                   key=lambda k: float(np.mean(np.sum((cage[k:] - true[: len(a) - k]) ** 2, axis=1))))
        return round(best * self.step_s, 6)

    def close(self) -> None:
        self._stop_keepalive.set()
        if self._keepalive is not None:
            self._keepalive.join(5.0)
        host = getattr(self, "host", None)
        if host is not None:
            try:
                with self._io:
                    host.safe_off()
            except Exception:  # a cage that stopped answering is already off (its heartbeat watchdog)
                pass
            host.close()
        if self.emulator is not None:
            self.emulator.close()


def _plot(tel, name: str, out_dir) -> str:
    from matplotlib.figure import Figure

    t = tel["t_s"]
    fig = Figure(figsize=(9, 6.5), layout="constrained")
    axes = fig.subplots(4, 1, sharex=True)
    cage, true = tel[f"{name}.b_cage_B"] / 1e-6, tel["b_true_B"] / 1e-6
    for i, ax in enumerate(axes[:3]):
        ax.plot(t, true[:, i], color="0.2", lw=2.2, alpha=0.35, label="simulated field")
        ax.plot(t, cage[:, i], color="tab:blue", lw=0.8, label=f"made by the cage ({name}) at the test position")
        ax.set_ylabel(f"B {'xyz'[i]} body (uT)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    err = np.linalg.norm(tel[f"{name}.b_cage_B"] - tel["b_true_B"], axis=1) / NT
    axes[3].semilogy(t, np.maximum(err, 1e-3), color="tab:red", lw=0.8)
    axes[3].axvline(SETTLE_S, color="0.5", ls=":", lw=0.8)
    axes[3].set_ylabel("|difference| (nT)")
    settled = err[t >= SETTLE_S]
    if len(settled):
        rms = float(np.sqrt(np.mean(settled**2)))
        axes[3].axhline(rms, color="0.3", ls="--", lw=0.8, label=f"RMS after start-up {rms:.0f} nT")
        axes[3].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    axes[3].set_xlabel("t (s)")
    axes[3].grid(alpha=0.3)
    axes[0].set_title(f"Helmholtz cage ({name}): the field it makes against the simulated one")
    fname = f"cage_{name}.png"
    fig.savefig(f"{out_dir}/{fname}", dpi=110)
    return fname


KIND = CageKind()


# -- how `stand emulate cage` serves it ----------------------------------------------------------------------------

def _serve(args, fail) -> int:
    """The Helmholtz cage controller on Modbus TCP or RTU, its coils running in wall time with the nominal bench
    configuration (``drivers.cage.emulator``, register map ``docs/cage_register_map.md``)."""
    import signal
    import threading

    from drivers.cage.emulator import MAX_REQUEST_RATE_HZ, CageEmulator
    from drivers.cage.host import parse_url
    from drivers.errors import DriverError

    try:
        kind, host, port = parse_url(args.port)
    except ValueError as exc:
        return fail(str(exc))
    emu = CageEmulator(rng=args.seed, max_request_rate_hz=MAX_REQUEST_RATE_HZ)  # serves outside clients: limited
    old = stop_on_sigterm()  # from before the banner: a SIGTERM any time after it stops cleanly
    status = 0
    try:
        try:
            if kind == "tcp":
                emu.serve_tcp(host, port)
            else:
                emu.serve_rtu(host, baudrate=args.baud)
        except DriverError as exc:
            emu.close()
            return fail(str(exc))
        with emu:
            banner("cage", emu.where, args.duration)
            status = serve_until_stopped(emu, args.duration)
    except KeyboardInterrupt:
        emu.close()
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)
    report(args, t_s=round(emu.t_s, 3), counters=emu.counters)
    if threading.current_thread() is threading.main_thread():
        signal.alarm(0)  # stopped cleanly: a caller in the same process (a test) lives on
    return status


def _serving():
    return Serving(
        summary="The Helmholtz cage controller on Modbus TCP or RTU, its coils running in wall time (open loop only).",
        port_help="tcp://127.0.0.1:PORT (Modbus TCP) or a serial port (Modbus RTU)",
        serve=_serve,
        options=(ServeOption("--baud", "Modbus RTU baud rate (default 115200)", 115200, int),
                 ServeOption("--seed", "noise seed (default 0)", 0, int)),
    )


KIND.serving = _serving()
