"""A hardware star tracker that looks at the stand's star screen: the screen is driven every tick.

A tracker on a ``hardware`` link with ``screen = "window"`` gets a window on this PC that the stand
renders into every tick (``screen_display``, ``screen_size_px``, ``screen_fullscreen``; pygame-ce),
pre-distorted for the collimator its calibration found (``screen_collimator_focal_m``,
``screen_collimator_distortion`` = OpenCV's k1 k2 p1 p2 k3, ``screen_axis_px``).
With ``screen = "state"`` every tick the stand instead sends a display node (``stand display-node``
on a screen PC, or ``stand emulate star-tracker --source screen``, which is display node and camera
in one) the time-tagged state of the frame it must show (``star_screen.state_message``), over UDP::

    screen = "state"
    screen_port = "udp://127.0.0.1:5600"   # the display node's --bind / --screen-bind
    screen_latency_s = 0.02                # from sending a state to its frame being lit (wall time)
    screen_key_file = "/etc/stand/display.key"  # optional: sign with this shared key (a private file)

The states are signed (HMAC-SHA256, ``stand.display``'s one sender) when a shared key is configured, as a
display node started with ``--key-file`` or ``STAND_DISPLAY_KEY`` requires: ``screen_key_file`` (an absolute
path to a file only its owner can read), else the environment variable ``STAND_DISPLAY_KEY`` the node reads
too. A key file that cannot be read, that other users can read, or a key under 16 bytes is refused by the
scenario check, naming the key.

Latency is compensated by extrapolation: a state sent at wall time ``w`` is for the frame that will be
lit at ``w + screen_latency_s``, in sim time ``t_lit = speed * (w + latency - start)``, and stays lit
for one tick; it shows the attitude of the middle of that time, ``t_show = t_lit + step_s / 2`` (a
held frame is then as often ahead of the truth as behind it, by at most half a tick times the rate).
The attitude is the truth of the tick carried to ``t_show`` with the body rate
(``q_TN(t + dt) = q_TN (x) exp(omega_TN_T dt / 2)``, the attitude kinematics with the rate held over
``dt``, tens of milliseconds). The state's time tag is ``t_show``. Its rate (for the smear the screen
draws) is the rate at which the sky turns on the screen in wall time, ``speed * omega``.

Solutions are scored against the truth at their own exposure time, recovered from the device time
stamp (the device clock is set at start, its offset measured) and carried to the exact instant from
the tick before it with the rate, not rounded to a tick, so the error is the optical chain's and the
screen's timing, not the stand's sampling.

Recorded per run (summary ``screen``): frames sent, frames dropped (a state the message format
refuses, a socket error), frames late (sent more than a tick after the tick's wall-clock start, so the
screen showed the previous frame for a whole frame longer than planned), the latency used, the send
lateness (median, p95, max), the exposure-to-solution and frame-to-solution latency (median, p95;
from sending the frame that was lit at the exposure to the host decoding the solution, one clock).
Telemetry: ``NAME.screen_t_lit_s`` (time tag ``t_show`` of the newest frame) and ``NAME.screen_lead_s``
(``t_show - t`` of the tick).
"""

from __future__ import annotations

import bisect
import ipaddress
import math
import os
import time
from collections import deque

import numpy as np

from sim.rotations import hamilton_floats
from sim.truth import compose_floats, rotate_to_body
from stand.checks import pair
from stand.devices import LOCAL_HOSTS
from stand.devices.star_tracker_devices import HardwareTracker
from stand.display import StateSender, load_key

SCREEN_MODES = ("state", "window")
WINDOW_KEYS = ("screen_display", "screen_size_px", "screen_fullscreen", "screen_collimator_focal_m",
               "screen_collimator_distortion", "screen_axis_px")
STATE_KEYS = ("screen_port", "screen_key_file")
SCREEN_KEYS = ("screen", *STATE_KEYS, "screen_latency_s", *WINDOW_KEYS)
#: Frames kept for the frame-to-solution latency (a solution is never older than a few seconds).
_FRAMES_KEPT = 512


def parse_screen(t, link: str) -> dict | None:
    """The ``screen*`` keys of a star-tracker table: None without ``screen``, else ``{"mode", "latency_s", ...}``
    with ``host`` and ``port`` for ``state``, ``display``, ``size_px`` and ``fullscreen`` for ``window``. Only a
    hardware tracker looks at a screen."""
    if not t.has("screen"):
        for key in SCREEN_KEYS[1:]:
            if t.has(key):
                raise t.error(key, t.raw(key), "a setting of trackers with a screen; set screen = 'state' or "
                              "'window' too")
        return None
    mode = t.choice("screen", SCREEN_MODES)
    if link != "hardware":
        raise t.error("screen", mode, f"a screen only for link = 'hardware' (a real or emulated tracker outside looks "
                      f"at it); this tracker has link = {link!r}")
    out = {"mode": mode, "latency_s": float(t.number("screen_latency_s", 0.02, lo=0.0, hi=1.0))}
    other = WINDOW_KEYS if mode == "state" else STATE_KEYS
    for key in other:
        if t.has(key):
            raise t.error(key, t.raw(key), f"not a setting of screen = {mode!r}")
    if mode == "state":
        out["host"], out["port"] = _udp_url(t, t.text("screen_port"))
        key_file = _key_file(t)
        if key_file is not None:
            out["key_file"] = key_file
        return out
    out["display"] = int(t.number("screen_display", 0, lo=0, hi=15, integer=True))
    out["size_px"] = tuple(int(v) for v in pair(t, "screen_size_px", (1920, 1080), 64, 7680, True))
    out["fullscreen"] = t.flag("screen_fullscreen", True)
    # Pre-distortion: the bench's ChArUco calibration (star_screen.calibration.calibrate_screen) as numbers.
    w, h = out["size_px"]
    out["focal_m"] = float(t.number("screen_collimator_focal_m", 1.1, lo=0.05, hi=20.0))
    out["distortion"] = tuple(float(v) for v in t.vector("screen_collimator_distortion", 5, [0.0] * 5, lo=-10.0,
                                                         hi=10.0))
    out["axis_px"] = tuple(float(v) for v in t.vector("screen_axis_px", 2, [w / 2, h / 2], lo=0.0, hi=max(w, h)))
    try:
        window_bench(out)
    except ValueError as exc:
        raise t.error("screen_size_px", list(out["size_px"]), f"a screen the tracker's field fits on ({exc})") from None
    return out


def window_bench(scr: dict):
    """The bench a ``window`` screen is drawn for: the default bench at the window's size with the calibrated
    collimator (focal length, OpenCV distortion) and axis, so the frames are pre-distorted. ValueError when the
    tracker's field does not fit the screen."""
    import dataclasses

    from star_screen.geometry import BrownConrady, Collimator, default_bench

    w, h = scr["size_px"]
    bench = default_bench(w, h)
    bench = dataclasses.replace(bench, collimator=Collimator(scr["focal_m"], BrownConrady(*scr["distortion"])),
                                sx0=scr["axis_px"][0], sy0=scr["axis_px"][1])
    problems = bench.check_fits()
    if problems:
        raise ValueError("; ".join(problems))
    return bench


def describe_screen(scr: dict) -> str:
    """One phrase for ``stand check``: where the screen is and how far ahead its frames are drawn."""
    if scr["mode"] == "state":
        where = f"state every tick to the display node at udp://{scr['host']}:{scr['port']}"
        if scr.get("key_file"):
            where += f", signed with the key in {scr['key_file']}"
    else:
        w, h = scr["size_px"]
        where = (f"rendered by the stand every tick in a {'fullscreen ' if scr['fullscreen'] else ''}window on display "
                 f"{scr['display']}, {w} x {h}, pre-distorted for a collimator of {scr['focal_m']:g} m, distortion "
                 f"{list(scr['distortion'])}, axis at screen px {list(scr['axis_px'])}")
    return f"{where}, frames for {scr['latency_s'] * 1e3:g} ms ahead"


def _udp_url(t, url: str) -> tuple[str, int]:
    scheme, sep, rest = url.partition("://")
    host, _, port_text = rest.rpartition(":")
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if scheme != "udp" or not sep or not host or not 0 < port < 65536:
        raise t.error("screen_port", url, "udp://HOST:PORT of the display node, e.g. udp://127.0.0.1:5600")
    if host in LOCAL_HOSTS:
        return ("127.0.0.1" if host == "localhost" else host.strip("[]")), port
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        ip = None
    # A screen PC sits on the bench's own network: a scenario may name it, never a host beyond it.
    if ip is None or not (ip.is_private or ip.is_link_local) or ip.is_multicast:
        raise t.error("screen_port", url, "a display node on this machine (127.0.0.1) or on the bench's private "
                      "network (an address such as 192.168.x.x or 10.x.x.x), given as udp://ADDRESS:PORT")
    return str(ip), port


def _key_file(t) -> str | None:
    """``screen_key_file`` as an absolute path, its key checked now (so ``stand check`` names a bad one); without
    it, the environment's key (``STAND_DISPLAY_KEY``) is checked the same way."""
    if not t.has("screen_key_file"):
        try:
            load_key(None)
        except ValueError as exc:
            raise t.error("screen", "state", f"a state screen signed with a usable shared key ({exc})") from None
        return None
    raw = t.text("screen_key_file")
    path = os.path.expanduser(raw)
    allowed = "an absolute path to a file only its owner can read, holding a shared key of at least 16 bytes"
    if not os.path.isabs(path):
        raise t.error("screen_key_file", raw, allowed)
    try:
        load_key(path, option="screen_key_file")
    except ValueError as exc:
        raise t.error("screen_key_file", raw, f"{allowed} ({exc})") from None
    return path


def screen_key(scr: dict) -> bytes | None:
    """The shared key a ``state`` screen signs with: ``screen_key_file``'s, else ``STAND_DISPLAY_KEY``'s, else
    None (unsigned). ValueError in one sentence for a key that cannot be used."""
    return load_key(scr.get("key_file"), option="screen_key_file")


def extrapolate(q_TN, omega_TN_T, dt_s: float) -> tuple:
    """``q_TN (x) exp(omega_TN_T dt / 2)``: the attitude ``dt_s`` later with the rate held (float tuples)."""
    wx, wy, wz = omega_TN_T
    rate = math.sqrt(wx * wx + wy * wy + wz * wz)
    half = 0.5 * rate * dt_s
    if rate == 0.0 or half == 0.0:
        return tuple(q_TN)
    s = math.sin(half) / rate
    q = hamilton_floats(q_TN, (math.cos(half), wx * s, wy * s, wz * s))
    return q if q[0] >= 0.0 else tuple(-x for x in q)


class _StateStream:
    """The screen as a display node: stand.display's one state sender, one stream id per run, signed when a shared
    key is configured. ``send`` says whether the datagram left (a refused state or a socket error is counted)."""

    def __init__(self, host: str, port: int, epoch, key: bytes | None):
        self.sender = StateSender(host, port, scenario_epoch=epoch, key=key)
        self.where = f"udp://{host}:{port}"
        self.signed = key is not None

    def send(self, q_SN, sim_time_ns: int, v_N, omega_SN_S) -> bool:
        s = self.sender
        sent = s.sent
        s.send(q_SN, sim_time_ns, v_sc_gcrs_m_s=v_N, omega_SN_S=omega_SN_S)
        return s.sent > sent

    @property
    def sent(self) -> int:
        return self.sender.sent

    @property
    def refused(self) -> int:
        return self.sender.refused

    @property
    def send_errors(self) -> int:
        return self.sender.send_errors

    @property
    def last_error(self) -> str:
        return self.sender.last_error

    def close(self) -> None:
        self.sender.close()


class _LocalWindow:
    """The screen as a window on this PC: the stand renders each frame itself (default bench at the window's
    size, apparent places) and shows it, logging the clock right after the flip."""

    def __init__(self, scr: dict, epoch):
        from star_screen.render import Renderer
        from star_screen.window import ScreenWindow

        w, h = scr["size_px"]
        self.epoch = epoch
        self.renderer = Renderer(window_bench(scr), aberration=True)
        self.window = ScreenWindow((w, h), display=scr["display"], fullscreen=scr["fullscreen"],
                                   clock=time.monotonic_ns)
        self.where = f"window on display {scr['display']} ({w} x {h})"
        self.sent = self.refused = self.send_errors = 0
        self.last_error = ""
        self.show_ms: list[float] = []

    def send(self, q_SN, sim_time_ns: int, v_N, omega_SN_S) -> bool:
        from star_screen.render import SmearTooLong

        w0 = time.monotonic_ns()
        try:
            frame = self.renderer.render(q_SN, self.epoch.add_ns(sim_time_ns), v_sc_gcrs_m_s=v_N,
                                         omega_SN_S=omega_SN_S, time_tag_ns=sim_time_ns, detector=False, copy=False)
        except SmearTooLong as exc:  # a tumble faster than the screen can draw: the frame is dropped, counted
            self.refused += 1
            self.last_error = str(exc)
            return False
        rec = self.window.show(frame)
        self.show_ms.append((rec.clock - w0) * 1e-6)
        self.sent += 1
        return True

    def close(self) -> None:
        self.window.close()


def _rotation_q(v) -> tuple:
    """The unit quaternion (scalar first) of rotation vector ``v`` (rad)."""
    angle = math.sqrt(sum(x * x for x in v))
    if angle == 0.0:
        return (1.0, 0.0, 0.0, 0.0)
    s = math.sin(0.5 * angle) / angle
    return (math.cos(0.5 * angle), v[0] * s, v[1] * s, v[2] * s)


def _percentiles(values, scale: float = 1.0, digits: int = 4) -> dict:
    v = np.asarray(values, float) * scale
    if not len(v):
        return {}
    return {"median": round(float(np.median(v)), digits), "p95": round(float(np.percentile(v, 95)), digits),
            "max": round(float(v.max()), digits), "n": int(len(v))}


class ScreenTracker(HardwareTracker):
    """A hardware tracker whose screen the stand drives every tick (see the module docstring)."""

    #: A rotation (rad, tracker axes) applied to the sky the screen shows, set by a ``screen_wrong_attitude``
    #: fault: the real tracker sees a consistent sky of the wrong attitude and reports it as valid.
    screen_misid_rad: tuple | None = None

    def __init__(self, spec, ctx):
        super().__init__(spec, ctx)
        scr = spec.screen
        self.latency_s = scr["latency_s"]
        self._step_s = ctx.step_s
        self._omega_of = {}  # tick (us) -> omega_TN_T, to carry the truth to an exposure instant
        self._start = math.inf  # wall clock of sim time 0, the earliest tick start seen
        self._wall_set = math.nan
        self._frames: deque[tuple[float, float]] = deque(maxlen=_FRAMES_KEPT)  # (t_lit, wall sent)
        self._lateness: list[float] = []
        self.frames_late = 0
        self.frame_to_solution: list[float] = []
        self.exposure_to_solution: list[float] = []
        self.t_lit = self.lead = math.nan
        try:
            if scr["mode"] == "state":
                self.stream = _StateStream(scr["host"], scr["port"], ctx.epoch, screen_key(scr))
            else:
                self.stream = _LocalWindow(scr, ctx.epoch)
        except (OSError, ValueError, RuntimeError) as exc:
            self.close()
            from drivers.errors import ConnectError

            where = f"UDP socket to {scr['host']}:{scr['port']}" if scr["mode"] == "state" else "window"
            raise ConnectError(f"{self.name}: cannot open the screen's {where}: {exc}", where=where,
                               reason=str(exc)) from None

    def start(self, events) -> None:
        self._wall_set = time.monotonic()
        super().start(events)
        events.log("screen", f"{self.name}: screen ({self.stream.where}) driven every tick, each frame for "
                   f"{self.latency_s * 1e3:g} ms after the tick's start", device=self.name, latency_s=self.latency_s)

    def publish(self, t_s: float) -> None:
        now = time.monotonic()
        speed = self._speed
        late = now - (self._start + t_s / speed)
        if late < 0.0 or not math.isfinite(late):  # a tick started earlier than any before: a better origin
            self._start = now - t_s / speed
            late = 0.0
        truth = self._truth
        key = round(t_s * 1e6)
        q_TN = compose_floats(self.q_SB, truth.q)
        w_T = rotate_to_body(self.q_SB, truth.w)
        self.truth_at[key] = q_TN
        self._omega_of[key] = w_T
        self._send_frame(t_s, now, q_TN, w_T, late)
        sol = self._new_solution()
        if sol is not None:
            self._take(sol, time.monotonic())

    def _send_frame(self, t_s, now, q_TN, w_T, late) -> None:
        speed = self._speed
        t_lit = speed * (now + self.latency_s - self._start)
        # The frame stays on the panel for one tick: drawn for the middle of that, the held attitude is as often
        # ahead of the truth as behind it.
        t_show = t_lit + 0.5 * self._step_s
        q_show = extrapolate(q_TN, w_T, t_show - t_s)
        if self.screen_misid_rad is not None:
            q_show = compose_floats(_rotation_q(self.screen_misid_rad), q_show)
        self._lateness.append(late)
        if late > self._step_s / speed:
            self.frames_late += 1
        if self.stream.send(q_show, round(t_show * 1e9), self._truth.v_N, tuple(speed * w for w in w_T)):
            self._frames.append((t_lit, now))
            self.t_lit, self.lead = t_show, t_show - t_s

    def _take(self, sol, wall_rx: float) -> None:
        wall_exp = self._wall_set + sol.time_us * 1e-6 - (self.clock_offset_s if math.isfinite(
            self.clock_offset_s) else 0.0)
        t_exp = self._speed * (wall_exp - self._start)
        self.exposure_to_solution.append(wall_rx - wall_exp)
        lits = [f[0] for f in self._frames]
        i = bisect.bisect_right(lits, t_exp) - 1
        if i >= 0:
            self.frame_to_solution.append(wall_rx - self._frames[i][1])
        key = round(t_exp * 1e6)
        tick = math.floor(t_exp / self._step_s + 1e-9) * self._step_s
        k0 = round(tick * 1e6)
        if k0 in self.truth_at and k0 in self._omega_of:
            self.truth_at[key] = extrapolate(self.truth_at[k0], self._omega_of[k0], t_exp - tick)
        self._score(sol, t_exp)
        if len(self._omega_of) > 4096:
            for k in sorted(self._omega_of)[:-1024]:
                del self._omega_of[k]

    def columns(self):
        n = self.name
        return [*super().columns(), (f"{n}.screen_t_lit_s", 1, "s"), (f"{n}.screen_lead_s", 1, "s")]

    def row(self):
        return (*super().row(), self.t_lit, self.lead)

    def summary(self):
        s = self.stream
        screen = {"mode": self.spec.screen["mode"], "to": s.where,
                  "latency_s": self.latency_s, "frames_sent": s.sent, "frames_dropped": s.refused + s.send_errors,
                  "frames_late": self.frames_late, "send_lateness_ms": _percentiles(self._lateness, 1e3, 3),
                  "exposure_to_solution_s": _percentiles(self.exposure_to_solution),
                  "frame_to_solution_s": _percentiles(self.frame_to_solution)}
        if hasattr(s, "signed"):
            screen["signed"] = s.signed
        if getattr(s, "show_ms", None):
            screen["render_to_display_ms"] = _percentiles(s.show_ms, 1.0, 3)
        if s.last_error:
            screen["last_error"] = s.last_error
        return {**super().summary(), "screen": screen}

    def close(self) -> None:
        stream = getattr(self, "stream", None)
        if stream is not None:
            stream.close()
        super().close()
