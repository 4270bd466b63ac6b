"""What the operator page shows, computed from a run folder (replay) or from the rows a live run hands over.

``view.json`` (:mod:`stand.view.meta`: :func:`write_view_json`, :func:`load_meta`) holds what the page needs
from the scenario: the epoch, the Earth-rotation model, and for every device its kind, mount and the layers its
kind declares.

:func:`derive` turns telemetry columns into the page's samples: the telemetry itself plus the Sun and Moon
directions from the spacecraft (with their angular radii), the Earth's visible fraction of the Sun, the
Earth-fixed attitude ``q_EN`` and the sub-satellite point. :func:`project` is the panorama's projection, the
same formulas as the page's ``view.js``; tests and the PNG export use it to say where the page must draw.

Panorama convention: a direction ``u`` in the chosen frame has longitude ``atan2(u_y, u_x)`` and latitude
``asin(u_z)``; the map is seen from inside the sphere, so longitude grows to the left (looking along +x with +z
up, +y is on the left) and +z is up.
"""

from __future__ import annotations

import base64
import collections
import json
import math
import threading
import time
from pathlib import Path

import numpy as np

from sim.constants import R_EARTH
from sim.environment import R_SUN, shadow_fraction
from sim.ephemeris import EphemerisTrack
from sim.frames import EarthRotation
from sim.rotations import quat_from_dcm
from sim.time import Epoch
from stand.adcs import metrics
from stand.faults import FAULT_TYPES
from stand.telemetry import load

# The run's view description lives in .meta; the page's modules and benches take it from here as before.
from .frames import encode_png, taps
from .meta import VIEW_FILE, RunFileError, describe, dumps, load_meta, write_view_json  # noqa: F401

R_MOON = 1.7374e6
#: Most samples a replay sends the page for the whole run (the slider's resolution is duration / this).
MAX_SAMPLES = 6000
PROJECTIONS = ("equirectangular", "hammer")
#: Most samples a live run's server keeps for pages that open mid-run: the newest ``LIVE_RECENT_SAMPLES`` as the
#: feed sent them, the older ones thinned evenly in time (a long paced run would otherwise grow without end).
LIVE_MAX_SAMPLES = 2 * MAX_SAMPLES
LIVE_RECENT_SAMPLES = 2000
#: Most telemetry rows the live feed holds between two sends (ten a second); when the sender cannot keep up, or
#: the page's server is gone, the oldest are dropped from the view (never from the telemetry on disk).
LIVE_MAX_PENDING_ROWS = 100_000
#: A pause from the page is released (the run resumes, with an event in the log) when the page's server has been
#: silent this long (it says it is alive every second) ...
SERVER_SILENT_S = 15.0
#: ... or when no page has been open for this long during the pause.
UNATTENDED_PAUSE_S = 600.0
#: Longest wait of a fault command from the page (``POST /api/faults``) for the run's answer: the run takes it at
#: its next control poll (every 0.25 s of wall time, every 0.05 s while paused) and the feed sends the answer at
#: its next push (ten a second), so a run that is alive answers within about half a second.
FAULT_ANSWER_S = 10.0
#: Frames of each image tracker the live server keeps for ``GET /api/frame?device=NAME&seq=N`` (two seconds' worth at
#: ``stand.view.frames.FRAME_HZ``): a page asks for the frame it was told of, which a newer one may follow meanwhile.
RECENT_FRAMES = 4


# --------------------------------------------------------------------------------------------------- geometry

class Sky:
    """The slow sky of a run: Sun and Moon tracks and the Earth's rotation, built once per run."""

    def __init__(self, meta: dict):
        self.epoch = Epoch.from_iso(meta["epoch"])
        er = meta.get("earth_rotation", {})
        # UT1 - UTC and polar motion are left at 0: at most 13.5 arcsec on the drawn Earth.
        self.rotation = EarthRotation(self.epoch, er.get("model", "iau2006"), er.get("era0_rad", 0.0))
        self.sun = EphemerisTrack(self.epoch, "sun")
        self.moon = EphemerisTrack(self.epoch, "moon")
        self._lock = threading.Lock()  # the tracks cache nodes; the live sender and the server share them
        self.adcs = AdcsView(meta)

    def derive(self, cols: dict) -> dict:
        """Telemetry columns (``t_s`` (n,), ``r_BN_N`` (n, 3), ...) plus what the page draws from them."""
        t = np.asarray(cols["t_s"], dtype=float)
        r = np.asarray(cols["r_BN_N"], dtype=float).reshape(-1, 3)
        out = dict(cols)
        with self._lock:
            r_sun = self.sun.position_gcrs(t).reshape(-1, 3)
            r_moon = self.moon.position_gcrs(t).reshape(-1, 3)
            C = self.rotation.dcm_itrs_gcrs(t).reshape(-1, 3, 3)
        for body, pos, radius in (("sun", r_sun, R_SUN), ("moon", r_moon, R_MOON)):
            d = pos - r
            n = np.linalg.norm(d, axis=-1, keepdims=True)
            out[f"{body}_N"] = d / n
            out[f"{body}_radius_rad"] = np.arcsin(radius / n[:, 0])
        rn = np.linalg.norm(r, axis=-1)
        out["earth_radius_rad"] = np.arcsin(np.minimum(1.0, R_EARTH / rn))
        # A row without a finite position (a run that diverged) is drawn as "no value", not a crash of the server.
        known = np.all(np.isfinite(r), axis=-1)
        out["sun_fraction"] = np.full(len(t), np.nan)
        if known.any():
            out["sun_fraction"][known] = shadow_fraction(r[known], r_sun[known])
        out["q_EN"] = quat_from_dcm(C) if len(t) else np.zeros((0, 4))
        r_E = np.einsum("nij,nj->ni", C, r)
        out["lat_deg"] = np.degrees(np.arcsin(r_E[:, 2] / rn)) if len(t) else np.zeros(0)
        out["lon_deg"] = np.degrees(np.arctan2(r_E[:, 1], r_E[:, 0])) if len(t) else np.zeros(0)
        out.update(self.adcs.derive(out))
        return out


class AdcsView:
    """What the page draws of the controller and the momentum, from the telemetry and ``view.json``:

    - ``pointing_error_arcsec``: the angle from the true attitude to the controller's commanded one
      (``adcs_q_RN``), ``knowledge_error_arcsec``: to its estimate (``adcs_q_BN_est``), as the verdict scores them
      (:mod:`stand.adcs.metrics`);
    - a device's declared error columns (a tracker's ``err_cross``, ``err_roll``) as ``NAME.COLUMN.valid_only``:
      NaN where its ``NAME.valid`` says the solution is not valid (a tracker's error during a tumble means nothing);
    - ``h_wheels_B`` (N m s): the wheels' momentum from their recorded speeds and their datasheets' spin axes and
      rotor inertias; ``h_total_B``: the body's ``I omega`` plus that; ``torque_wheels_B`` (N m): the torque the
      wheels put on the body (minus their net motor torques along their axes); ``torque_mtq_B``: the coils'
      ``m x B`` from their recorded dipole and the true field.
    """

    def __init__(self, meta: dict):
        devices = meta.get("devices", [])
        self.errors = [(d["name"], c) for d in devices for c in d.get("error_columns", ())]
        self.wheels = []
        for d in devices:
            sheet = d.get("datasheet") or {}
            axis, inertia = sheet.get("spin_axis_B"), sheet.get("inertia_kg_m2")
            if axis is not None and isinstance(inertia, int | float):
                a = np.asarray(axis, dtype=float)
                self.wheels.append((d["name"], a / np.linalg.norm(a), float(inertia)))
        I_B = (meta.get("spacecraft") or {}).get("inertia_kg_m2")
        self.inertia = np.asarray(I_B, dtype=float).reshape(3, 3) if I_B is not None else None
        self.dipoles = [f"{d['name']}.{p['column']}" for d in devices for p in d.get("plots", ())
                        if p.get("unit") == "A m²"]

    def derive(self, cols: dict) -> dict:
        out = {}
        n = len(np.asarray(cols["t_s"]))
        with np.errstate(invalid="ignore", divide="ignore"):
            for name, col in (("pointing_error_arcsec", metrics.REFERENCE),
                              ("knowledge_error_arcsec", metrics.ESTIMATE)):
                if col in cols:
                    e = metrics.error_angles_B(np.asarray(cols["q_BN"], float), np.asarray(cols[col], float))
                    out[name] = np.linalg.norm(e, axis=1) / metrics.ARCSEC
        for dev, c in self.errors:
            if f"{dev}.{c}" in cols and f"{dev}.valid" in cols:
                ok = np.asarray(cols[f"{dev}.valid"], float) >= 0.5
                out[f"{dev}.{c}.valid_only"] = np.where(ok, np.asarray(cols[f"{dev}.{c}"], float), np.nan)
        self._momentum(cols, out, n)
        return out

    def _momentum(self, cols: dict, out: dict, n: int) -> None:
        wheels = [w for w in self.wheels if f"{w[0]}.speed_rad_s" in cols]
        if wheels:
            h = sum(np.outer(np.asarray(cols[f"{w}.speed_rad_s"], float) * J, a) for w, a, J in wheels)
            out["h_wheels_B"] = h
            torque = [np.outer(np.asarray(cols[f"{w}.net_torque_Nm"], float), a) for w, a, _ in wheels
                      if f"{w}.net_torque_Nm" in cols]
            if torque:
                out["torque_wheels_B"] = -sum(torque)
        if self.inertia is not None and "omega_BN_B" in cols:
            out["h_total_B"] = np.asarray(cols["omega_BN_B"], float).reshape(n, 3) @ self.inertia.T \
                + out.get("h_wheels_B", 0.0)
        dipole = next((c for c in self.dipoles if c in cols), None)
        if dipole is not None and "b_true_B" in cols:
            out["torque_mtq_B"] = np.cross(np.asarray(cols[dipole], float).reshape(n, 3),
                                           np.asarray(cols["b_true_B"], float).reshape(n, 3))


def decimate(t: np.ndarray, max_samples: int = MAX_SAMPLES) -> np.ndarray:
    """Indices of at most about ``max_samples`` rows evenly spread in time, first and last kept."""
    n = len(t)
    if n <= max_samples:
        return np.arange(n)
    dt = (t[-1] - t[0]) / (max_samples - 1)
    idx = np.unique(np.searchsorted(t, t[0] + dt * np.arange(max_samples), side="left"))
    idx = idx[idx < n]
    return np.unique(np.append(idx, n - 1))


def encode(samples: dict) -> dict:
    """Columns as ``{name: {"shape": [n, w], "f32": base64}}`` (time in float64): a tenth of JSON's size."""
    out = {}
    for name, v in samples.items():
        a = np.asarray(v)
        if a.dtype.kind not in "fiub":
            continue
        dtype = "<f8" if name == "t_s" else "<f4"
        a2 = a.reshape(len(a), -1) if a.ndim else a.reshape(1, 1)
        out[name] = {"shape": list(a2.shape), "dtype": "f8" if dtype == "<f8" else "f4",
                     "data": base64.b64encode(np.ascontiguousarray(a2, dtype=dtype).tobytes()).decode("ascii")}
    return out


def replay_samples(run_dir, meta: dict, max_samples: int = MAX_SAMPLES, sky: Sky | None = None) -> dict:
    """The whole run, decimated, with everything derived."""
    tel = load(run_dir)
    idx = decimate(tel["t_s"], max_samples)
    cols = {k: np.asarray(v)[idx] for k, v in tel.items()}
    return (sky or Sky(meta)).derive(cols)


def read_events(run_dir) -> list[dict]:
    path = Path(run_dir) / "events.jsonl"
    out = []
    if path.is_file():
        for line in path.read_text(errors="replace").splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue  # a line cut by a crash
    return out


def column_meaning(run_dir, name: str) -> str | None:
    """A telemetry column's meaning as the run's ``telemetry/schema.json`` gives it (the controller's mode names), or
    None."""
    try:
        columns = json.loads((Path(run_dir) / "telemetry" / "schema.json").read_text())["columns"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return next((c.get("meaning") for c in columns if isinstance(c, dict) and c.get("name") == name), None)


def star_table(meta: dict, mag_limit: float | None = None) -> dict:
    """Catalog stars (brightest first) at the run's epoch: right ascension, declination (rad), Hp magnitude."""
    from star_screen.catalog import Catalog, unit_to_radec

    cat = Catalog.load(mag_limit=mag_limit)
    places = cat.places(Epoch.from_iso(meta["epoch"]), parallax=False)
    ra, dec = unit_to_radec(places.u_N)
    return {"count": len(cat), "hp_limit": cat.hp_limit,
            "stars": encode({"ra_dec_mag": np.stack((ra, dec, places.mag.astype(float)), axis=-1)})["ra_dec_mag"]}


# --------------------------------------------------------------------------------------------------- projection

def lon_lat(u) -> tuple[np.ndarray, np.ndarray]:
    u = np.asarray(u, dtype=float)
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    return np.arctan2(u[..., 1], u[..., 0]), np.arcsin(np.clip(u[..., 2], -1.0, 1.0))


def project(u, kind: str, width: float, height: float) -> np.ndarray:
    """Pixel ``(x, y)`` of directions ``u`` (..., 3) on a ``width`` x ``height`` panorama (``view.js``'s
    ``project``). Equirectangular fills the box (longitude +180 at the left edge); Hammer-Aitoff's ellipse is
    inscribed in it."""
    lon, lat = lon_lat(u)
    if kind == "equirectangular":
        x = width / 2 - lon / (2 * math.pi) * width
        y = height / 2 - lat / math.pi * height
    elif kind == "hammer":
        d = np.sqrt(1.0 + np.cos(lat) * np.cos(lon / 2))
        hx = 2 * math.sqrt(2) * np.cos(lat) * np.sin(lon / 2) / d  # in [-2 sqrt 2, 2 sqrt 2]
        hy = math.sqrt(2) * np.sin(lat) / d  # in [-sqrt 2, sqrt 2]
        x = width / 2 - hx / (2 * math.sqrt(2)) * width / 2
        y = height / 2 - hy / math.sqrt(2) * height / 2
    else:
        raise ValueError(f"projection {kind!r} is not one of {', '.join(PROJECTIONS)}.")
    return np.stack((x, y), axis=-1)


# --------------------------------------------------------------------------------------------------- live feed

def split_rows(rows, columns: list[dict]) -> dict:
    """Flat telemetry rows -> columns, as ``stand.telemetry.load`` returns them."""
    arr = np.asarray(rows, dtype=float)
    out, col = {}, 0
    for c in columns:
        w = int(c["width"])
        out[c["name"]] = arr[:, col] if w == 1 else arr[:, col:col + w]
        col += w
    return out


class LiveFeed:
    """The loop's observer during ``stand run --view``: the loop's side of the live page.

    The loop calls :meth:`record` for every telemetry row (it appends a reference to the row to a bounded deque
    and returns: no copy, no lock, no numpy) and :meth:`poll_control` a few times per second. A sender thread
    wakes ``push_hz`` times a second, takes the rows appended since (so the deque holds at most one period's rows,
    and never more than ``max_pending`` when the sender falls behind or is gone), keeps those at least
    ``duration / max_samples`` apart (and the newest), and hands them as one array to
    ``link.send(("rows", array))``; ``link.receive()`` returns what came from the page's server since the last
    call: control commands (``"pause"``, ``"stop"``, None) and, every second, ``{"pages": n}``, the number of
    pages open. Deriving the sky, encoding and serving happen at the other end of the link (:class:`LiveSource`,
    in the server's own process for ``stand run --view``), so they never hold this process's interpreter lock.

    A pause from the page never outlives the page: :meth:`poll_control` releases it (the run resumes, and a
    ``view_lost`` or ``pause_unattended`` event says why in ``events_path``) when the server is gone (its pipe
    broke, or it has been silent for ``server_silent_s``) or when no page has been open for
    ``unattended_pause_s`` of the pause.

    Fault commands from the page (``("fault", {"id", "action", ...})``, :meth:`LiveSource.fault`) queue here;
    :meth:`poll_control` hands them to the loop one at a time, before any pause or stop, as ``("fault", payload)``;
    the loop hands each to the run's fault schedule and gives the answer back with :meth:`answer_fault`, which the
    sender thread sends at its next push as ``("fault", answer)``.

    The frames of image trackers (:meth:`watch_devices`, :mod:`stand.view.frames`) are asked for by the sender thread
    while the server says a page is open, at most ``frames.FRAME_HZ`` a second, and sent as ``("frame", (header,
    pixels))``; the loop's side pays nothing for them per tick.
    """

    def __init__(self, link, meta: dict, push_hz: float = 10.0, max_samples: int = MAX_SAMPLES, *,
                 max_pending: int = LIVE_MAX_PENDING_ROWS, events_path=None, clock=time.monotonic,
                 server_silent_s: float = SERVER_SILENT_S, unattended_pause_s: float = UNATTENDED_PAUSE_S):
        self.link = link
        self.rows: collections.deque = collections.deque(maxlen=max_pending)
        self.push_period_s = 1.0 / push_hz
        self.spacing_s = max(meta["duration_s"] / max_samples, 1.0 / meta.get("record_rate_hz", 10.0))
        self.events_path = Path(events_path) if events_path is not None else None
        self.clock = clock
        self.server_silent_s, self.unattended_pause_s = server_silent_s, unattended_pause_s
        self._control: str | None = None
        self._faults: collections.deque = collections.deque()  # fault commands for the loop (sender -> loop)
        self._answers: collections.deque = collections.deque()  # the loop's answers (loop -> sender)
        self._next_t = -math.inf
        now = clock()
        self._heard_s = now  # when the server last said it is alive
        self._page_seen_s = now  # when a page was last open
        self._paused_s = now  # when the current pause began
        self._tell: str | None = None  # a status for the server, sent by the sender thread
        self._lost_logged = False
        self.pages = 0  # pages open, as the server last said
        self.taps: list = []  # image trackers' frame taps (watch_devices)
        self.frames_sent = 0
        self.pushes = 0
        self.rows_taken = 0  # rows the sender took from the deque (all the loop recorded, unless some were dropped)
        self.cpu_s = 0.0
        self.error: str | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- the loop's side (hot path: keep it to an append) -------------------------------------------------
    def record(self, t_s: float, row: tuple) -> None:
        self.rows.append(row)

    def poll_control(self) -> str | tuple | None:
        if self._faults:
            return "fault", self._faults.popleft()
        command = self._control
        if command != "pause" and self.error is None:
            return command
        return self._check(command)

    def watch_devices(self, devices: dict) -> None:
        """The run's devices (``stand.loop.run`` hands them over once): the image trackers' frames are shown
        (:mod:`stand.view.frames`), asked for by the sender thread while a page is open."""
        self.taps = taps(devices)

    def answer_fault(self, answer: dict) -> None:
        """The run's answer to a fault command (from the loop's thread); sent at the next push."""
        self._answers.append(answer)

    def _check(self, command: str | None) -> str | None:
        """The page's command, unless the page that paused the run is gone (then the run resumes, logged)."""
        now = self.clock()
        gone = self._gone(now)
        if command != "pause":
            if gone and not self._lost_logged:
                self._lost_logged = True
                self._log("view_lost", f"{gone}; the run goes on without its live page")
            return command
        if gone:
            self._lost_logged = True
            self._log("view_lost", f"{gone}; the run paused from it resumes")
        elif now - max(self._paused_s, self._page_seen_s) > self.unattended_pause_s:
            self._log("pause_unattended", f"paused with no operator page open for "
                      f"{now - max(self._paused_s, self._page_seen_s):.0f} s (limit {self.unattended_pause_s:g} s); "
                      "the run resumes")
        else:
            return command
        self._control = None
        self._tell = "running"
        return None

    def _gone(self, now: float) -> str | None:
        """Why the page's server is gone, or None."""
        if self.error is not None:
            return f"the operator page's server is gone ({self.error})"
        if self._thread is not None and not self._thread.is_alive() and not self._stop.is_set():
            return "the live view's sender thread ended"
        if now - self._heard_s > self.server_silent_s:
            return (f"the operator page's server has not answered for {now - self._heard_s:.0f} s "
                    f"(limit {self.server_silent_s:g} s)")
        return None

    def _log(self, kind: str, message: str) -> None:
        """One line in the run's event log (the loop's own log is line-buffered and appends too)."""
        if self.events_path is None:
            return
        try:
            with open(self.events_path, "a") as f:
                f.write(json.dumps({"kind": kind, "message": message}) + "\n")
        except OSError:
            pass  # a full disk: the run's summary counts its own lost events; this one is not worth a crash

    # -- the sender ----------------------------------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="view-sender", daemon=True)
        self._thread.start()

    def finish(self) -> None:
        """The run ended: stop the sender (bounded wait) and send what is left."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
        self.push()

    def _run(self) -> None:
        c0 = time.thread_time()
        try:
            while not self._stop.wait(self.push_period_s):
                try:
                    self.push()
                except (OSError, EOFError, ValueError) as exc:  # the page's end went away: the run goes on
                    self.error = f"live view stopped: {type(exc).__name__}: {exc}"
                    return
        finally:
            self.cpu_s = time.thread_time() - c0  # what the sender took from the run's process (stand bench view)

    def _take(self, message) -> None:
        """One message from the server: a heartbeat with the number of open pages, or a control command."""
        now = self.clock()
        if isinstance(message, dict):
            self._heard_s = now
            self.pages = int(message.get("pages", 0))
            if message.get("pages", 0) > 0:
                self._page_seen_s = now
            return
        self._heard_s = now
        if isinstance(message, tuple):  # ("fault", payload): for the loop, in order
            self._faults.append(message[1])
            return
        if message == "pause" and self._control != "pause":
            self._paused_s = now
        self._control = message

    def push(self) -> None:
        for message in self.link.receive():
            self._take(message)
        if self._tell is not None:
            status, self._tell = self._tell, None
            self.link.send(("status", status))
        while self._answers:
            self.link.send(("fault", self._answers.popleft()))
        self._send_rows()
        if self.taps:
            self._send_frames()

    def _send_frames(self) -> None:
        """The frames the loop took since the last push, and the next asked for while a page is open."""
        for tap in self.taps:
            frame = tap.collect()
            if frame is not None:
                self.link.send(("frame", frame))
                self.frames_sent += 1
            if self.pages > 0:
                tap.arm()

    def _send_rows(self) -> None:
        rows = self.rows
        new = [rows.popleft() for _ in range(len(rows))]  # the loop appends on the right meanwhile
        if not new:
            return
        self.rows_taken += len(new)
        keep = []
        nxt = self._next_t
        for row in new:
            if row[0] >= nxt:
                keep.append(row)
                nxt = row[0] + self.spacing_s
        if keep and keep[-1] is not new[-1]:
            keep.append(new[-1])  # the newest row is always shown
        self._next_t = nxt
        self.link.send(("rows", np.asarray(keep, dtype=float)))
        self.pushes += 1


def fault_types() -> list[dict]:
    """The fault types a page or ``stand fault`` may offer (``stand.faults.FAULT_TYPES``): name, layer, the tap a
    device must offer, what it does and its parameters (``key`` may hold ``{unit}``, the device's measurement unit,
    as ``view.json`` gives it in ``fault_taps``)."""
    return [{"name": name, "layer": ft.layer, "tap": ft.tap, "text": ft.text, "instant": ft.instant,
             "params": [{"key": p.key, "shape": p.shape, "default": p.default, "text": p.text, "lo": p.lo,
                         "hi": p.hi, "options": list(p.options) if isinstance(p.options, tuple | list) else []}
                        for p in ft.params]}
            for name, ft in FAULT_TYPES.items()]


def fault_list(events: list[dict]) -> list[dict]:
    """Every fault the event log shows, in the order injected: ``name``, ``type``, ``device``, ``params``,
    ``injected_s``, ``cleared_s`` (None while active) and ``active``. A clearing closes the newest open injection
    of that name (a recurring fault is injected again under its name)."""
    out: list[dict] = []
    for ev in events:
        kind, name = ev.get("kind"), ev.get("fault")
        if kind == "fault_injected":
            out.append({"name": name, "type": ev.get("type"), "device": ev.get("device"),
                        "params": ev.get("params") or {}, "injected_s": ev.get("t_s"), "cleared_s": None,
                        "active": True})
        elif kind == "fault_cleared":
            for f in reversed(out):
                if f["name"] == name and f["active"]:
                    f["cleared_s"], f["active"] = ev.get("t_s"), False
                    break
    return out


class LiveSource:
    """The page's side of a live run: derives what the page draws from the rows the feed sends, keeps the history
    for pages that open mid-run, tails the event log, and turns the page's pause, resume and stop into control
    commands (``control(command)``, sent back to the feed). A fault command (:meth:`fault`) goes the same way as
    ``("fault", payload)`` and waits, bounded, for the run's answer (:meth:`answered`)."""

    mode = "live"

    def __init__(self, run_dir, meta: dict, control=None, max_samples: int = LIVE_MAX_SAMPLES,
                 recent_samples: int = LIVE_RECENT_SAMPLES):
        if not 0 < recent_samples < max_samples:
            raise ValueError(f"recent_samples {recent_samples} is not allowed: from 1 to max_samples - 1 "
                             f"({max_samples - 1}).")
        self.run_dir = Path(run_dir)
        self.meta = meta
        self.sky = Sky(meta)
        self.control = control or (lambda command: None)
        self.status = "running"
        self.pages = 0  # pages open (the server counts its websockets); the feed hears it every second
        self.max_samples, self.recent_samples = max_samples, recent_samples
        self._columns: list[dict] | None = None
        self._history: list[dict] = []
        self._held = 0  # samples in _history
        self._events: list[dict] = []
        self._events_pos = 0
        self._events_sent = 0  # how many of _events the pages were pushed (a snapshot gives no more than these)
        self.listeners: list = []  # callables(message dict)
        self.pushes = 0
        self._lock = threading.Lock()
        self._answered = threading.Condition()
        self._answers: dict[int, dict] = {}
        self._fault_ids = 0
        self.frames: dict[str, tuple[dict, bytes]] = {}  # device -> (header, PNG) of its newest frame
        self._recent_frames: dict[str, collections.deque] = {}  # device -> its last RECENT_FRAMES, by seq
        self._frame_seq = 0

    def fault(self, command: dict, timeout_s: float = FAULT_ANSWER_S) -> dict:
        """Send a fault command (``{"action": "inject", "fault": {...}}`` or ``{"action": "clear", "name": ...}``)
        to the run and wait at most ``timeout_s`` for its answer: ``{"ok": True, "name": ...}`` or ``{"ok": False,
        "status": HTTP status, "error": one sentence}``. Called from a worker thread of the server, never its loop."""
        with self._answered:
            if self.status in ("finished", "stopping"):
                return {"ok": False, "status": 409, "error": f"the run is {self.status}: it takes no more faults"}
            self._fault_ids += 1
            ident = self._fault_ids
        self.control(("fault", {**command, "id": ident}))
        deadline = time.monotonic() + timeout_s
        with self._answered:
            while ident not in self._answers:
                left = deadline - time.monotonic()
                if self.status == "finished":  # its last answers came before the end: this one was not taken
                    return {"ok": False, "status": 409, "error": "the run ended before it took the fault command"}
                if left <= 0:
                    return {"ok": False, "status": 504, "error": f"the run did not answer within {timeout_s:g} s; "
                            "the fault command may still apply (see the event log)"}
                self._answered.wait(left)
            return self._answers.pop(ident)

    def answered(self, answer: dict) -> None:
        """The run's answer to the fault command ``answer["id"]`` (from the pipe's reader)."""
        with self._answered:
            self._answers[answer.get("id")] = answer
            self._answered.notify_all()

    def faults(self) -> list[dict]:
        """Every fault injected so far, from the event log (:func:`fault_list`); read afresh, so the events the
        next push sends to the pages are not taken from them."""
        return fault_list(read_events(self.run_dir))

    def request(self, command: str) -> str:
        """``pause``, ``resume`` or ``stop`` from the page; returns the new status."""
        if command not in ("pause", "resume", "stop"):
            raise ValueError(f"control command {command!r} is not one of pause, resume, stop.")
        if self.status in ("finished", "stopping"):
            return self.status
        if command == "stop":
            self.status = "stopping"
            self.control("stop")
        elif command == "pause":
            self.status = "paused"
            self.control("pause")
        elif command == "resume" and self.status == "paused":
            self.status = "running"
            self.control(None)
        self._notify({"type": "status", "status": self.status})
        return self.status

    def released(self, status: str = "running") -> None:
        """The run's side resumed a pause by itself (its page or server was gone too long)."""
        if self.status == "paused":
            self.status = status
            self._notify({"type": "status", "status": self.status})

    def finished(self, run_status: str = "completed") -> None:
        with self._lock:
            events = self._unsent_events()
        with self._answered:  # a fault command still waiting is told the run ended
            self.status = "finished"
            self._answered.notify_all()
        self._notify({"type": "status", "status": "finished", "run_status": run_status,
                      **({"events": events} if events else {})})

    def frame(self, header: dict, pixels: bytes) -> None:
        """An image tracker's newest frame (8 bits, :meth:`stand.view.frames.FrameTap.collect`): encoded, kept for
        ``GET /api/frame``, and announced to the pages, which then load it."""
        png = encode_png(header, pixels)
        with self._lock:
            self._frame_seq += 1
            info = {**header, "seq": self._frame_seq, "bytes": len(png)}
            self.frames[str(header["device"])] = (info, png)
            self._recent_frames.setdefault(str(header["device"]), collections.deque(maxlen=RECENT_FRAMES)).append(
                (info, png))
        self._notify({"type": "frame", **info})

    def frame_numbered(self, device: str, seq: int) -> tuple[dict, bytes] | None:
        """Frame ``seq`` of ``device`` if it is among its last ``RECENT_FRAMES`` (the one a page was told of, even
        when a newer one came while it asked), else None."""
        with self._lock:
            return next((f for f in self._recent_frames.get(device, ()) if f[0]["seq"] == seq), None)

    def summary_ready(self) -> None:
        """The finished run's ``summary.json`` is written: the pages fetch the verdict (``/api/meta``)."""
        self._notify({"type": "summary"})

    def _schema(self) -> list[dict] | None:
        if self._columns is None:
            path = self.run_dir / "telemetry" / "schema.json"
            if path.is_file():
                self._columns = json.loads(path.read_text())["columns"]
        return self._columns

    def ingest(self, rows: np.ndarray) -> None:
        """New rows (already thinned by the feed): derive, keep, and push to the pages."""
        cols = self._schema()
        if cols is None or not len(rows):
            return
        with self._lock:
            derived = self.sky.derive(split_rows(rows, cols))
            self._history.append(derived)
            self._held += len(rows)
            if self._held > self.max_samples:
                self._thin()
            self.pushes += 1
            events = self._unsent_events()
        self._notify({"type": "samples", "samples": encode(derived), "status": self.status,
                      **({"events": events} if events else {})})

    def _thin(self) -> None:
        """Bound the history: the newest ``recent_samples`` stay as they came, the older ones are thinned evenly in
        time to half of what is left of ``max_samples`` (so this runs once per many pushes, not at every one)."""
        merged = self._merged()
        n = len(merged["t_s"])
        cut = n - self.recent_samples
        idx = np.append(decimate(merged["t_s"][:cut], max(2, (self.max_samples - self.recent_samples) // 2)),
                        np.arange(cut, n))
        self._history = [{k: np.asarray(v)[idx] for k, v in merged.items()}]
        self._held = len(idx)

    def _merged(self) -> dict:
        keys = self._history[0].keys()
        return {k: np.concatenate([np.asarray(h[k]) for h in self._history]) for k in keys}

    def _new_events(self) -> list[dict]:
        path = self.run_dir / "events.jsonl"
        if not path.is_file():
            return []
        with open(path, "rb") as f:
            f.seek(self._events_pos)
            data = f.read()
        cut = data.rfind(b"\n") + 1
        self._events_pos += cut
        out = []
        for line in data[:cut].decode("utf-8", "replace").splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue
        self._events += out
        return out

    def _unsent_events(self) -> list[dict]:
        """The events no push has carried yet (read from the log now), marked as pushed."""
        self._new_events()
        out, self._events_sent = self._events[self._events_sent:], len(self._events)
        return out

    def _notify(self, message: dict) -> None:
        for listener in list(self.listeners):
            listener(message)

    def snapshot(self) -> tuple[dict, list[dict]]:
        """Every sample and every event pushed so far, for a page that opens mid-run: what the next push carries,
        it gets then, as the pages already open do (a snapshot that took events from the log would leave them out
        of that push, and the open pages would never see them)."""
        with self._lock:
            events = self._events[:self._events_sent]
            if not self._history:
                return {}, events
            return self._merged(), events


class LocalLink:
    """Feed and source in one process (tests, the bench's in-process comparison): rows go straight to the
    source; the source's control commands come straight back."""

    def __init__(self, source: LiveSource):
        self.source = source
        self.inbox: list = []
        source.control = self.inbox.append

    def send(self, message) -> None:
        kind, data = message
        if kind == "status":
            self.source.released(data)
        elif kind == "fault":
            self.source.answered(data)
        elif kind == "frame":
            self.source.frame(*data)
        else:
            self.source.ingest(data)

    def receive(self) -> list:
        out = list(self.inbox)
        self.inbox.clear()
        return [*out, {"pages": self.source.pages}]
