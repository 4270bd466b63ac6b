"""Device kinds: one module per kind, one registry, one contract.

The scenario loader, composition, the loop, telemetry, plots and the summary iterate over devices and never
name a kind. Each kind is a :class:`DeviceKind` (its scenario table and validation, what it needs from the
truth, how it is built for each link) that builds a :class:`Device` (what it does each tick, what it gives the
truth, its telemetry columns, plots, summary counters and its host driver for the flight code).

Kinds are found by name in :data:`KINDS` (``name -> "module:attribute"``, imported lazily, as python-can finds
its interfaces) and in the entry-point group ``adcs_stand.devices``, so a bench adds its own kind with a
package of its own::

    [project.entry-points."adcs_stand.devices"]
    my_sensor = "my_bench.sensor:KIND"

Links (``link = ...`` in a ``[[devices]]`` table):

* ``emulated``: the stand runs the device's emulator on an in-process loopback (pty pair, python-can
  ``virtual``), fed by the truth, and talks to it through the host driver, over the real protocol.
* ``hardware``: the stand runs only the host driver, on a real port; what an actuator produced is read back
  from the device, never assumed.
* ``served``: the stand runs the emulator on a real port, fed by the truth, for a flight computer outside.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sim.effects import EFFECT_TYPES, Effect  # noqa: F401 - the effector interface, re-exported for kinds
from stand.checks import Table
from stand.errors import ScenarioError
from stand.registry import installed_names, load_named

LINKS = ("emulated", "hardware", "served")
#: Links whose other end lives in wall time: the run must be paced.
WALL_TIME_LINKS = ("hardware", "served")
ENTRY_POINT_GROUP = "adcs_stand.devices"

#: The kinds shipped with the stand: name -> "module:attribute" of a DeviceKind instance.
KINDS = {
    "magnetorquer": "stand.devices.magnetorquer:KIND",
    "star_tracker": "stand.devices.star_tracker:KIND",
    "sun_sensor": "stand.devices.sun_sensor:KIND",
    "cage": "stand.devices.cage:KIND",
    "gyro": "stand.devices.gyro:KIND",
    "reaction_wheel": "stand.devices.reaction_wheel:KIND",
    "magnetometer": "stand.devices.magnetometer:KIND",
}

#: Truth models a device may need, in the order ``stand check`` lists them.
TRUTH_MODELS = ("magnetic_field", "sun", "moon", "eclipse", "star_screen")

#: The one vocabulary of what a kind senses (``DeviceKind.senses``), actuates (``actuates``) or stimulates for the
#: other devices (``provides``): quantity -> what it is. A kind declares names from here (``stand check`` lists
#: them); an out-of-tree kind that declares nothing still works. The truth is reached only through effects
#: (``Device.effects``, ``sim.effects.EFFECT_TYPES``): a kind that actuates ``dipole`` gives a "dipole" effect,
#: ``torque`` a "torque" effect, ``wheel_torque`` a "momentum_exchange" effect.
QUANTITIES = {
    "magnetic_field": "the magnetic field vector (T)",
    "attitude": "the orientation of the body or of a sensor frame (quaternion)",
    "rate": "the angular rate of the body (rad/s)",
    "sun": "the Sun: its direction, or the light it puts on sensing cells",
    "star_sky": "the stars in a field of view: a catalogue, rendered stars or an image",
    "position": "the spacecraft's position (m)",
    "velocity": "the spacecraft's velocity (m/s)",
    "time": "a time stamp or clock (s)",
    "dipole": "a magnetic dipole on the body (A m^2); the torque is m x B",
    "torque": "a torque on the body (N m)",
    "wheel_torque": "the torque on a momentum wheel's rotor, taken from the body (N m)",
    "wheel_momentum": "a momentum wheel's speed and stored angular momentum (rad/s, N m s)",
}

_loaded: dict[str, DeviceKind] = {}


def kind_names() -> tuple[str, ...]:
    """Every kind known: the shipped ones, then those of installed packages."""
    return (*KINDS, *_installed_kinds())


@functools.cache
def _installed_kinds() -> tuple[str, ...]:
    # Validation asks for every device and criterion: scanned once per process.
    return installed_names(ENTRY_POINT_GROUP, KINDS)


def get(name: str) -> DeviceKind:
    """The kind called ``name`` (imported on first use). KeyError for an unknown name."""
    return load_named(name, KINDS, ENTRY_POINT_GROUP, _loaded)


@dataclass(frozen=True)
class DeviceSpec:
    """What every ``[[devices]]`` table gives; a kind's spec extends it."""

    name: str
    kind: str
    link: str
    q_SB: np.ndarray  # device (sensor) frame relative to body, scalar-first


@dataclass(frozen=True)
class DeviceCost:
    """What one device costs a run, for the estimate made before t = 0 (``stand.compose.budget``): how often it
    publishes (None: every tick), the floats it adds to a telemetry row, the memory it holds for the whole run
    (star databases, image buffers) and the computation of one publish beyond the usual codec round trip (s)."""

    rate_hz: float | None = None
    row_floats: int = 16
    memory_bytes: int = 0
    publish_s: float = 0.0


@dataclass
class BuildContext:
    """What a kind may use to build a device: the truth, the Sun and Moon tracks it asked for, the scenario
    epoch, its own seeded random stream and the dynamics step."""

    truth: Any
    tracks: dict
    epoch: Any
    rng: np.random.Generator
    step_s: float
    speed: float | None = None
    #: Stimulators built before this device (name -> Device): a magnetometer in a cage reads the cage's field.
    stimuli: dict = field(default_factory=dict)
    #: Momentum wheels in the truth's wheel cluster: device name -> its column (``DeviceKind.momentum_wheel``).
    wheels: dict = field(default_factory=dict)


class Device:
    """One device of a run, whatever its kind and link. The loop calls, every tick at sim time ``t_s``:

    1. ``publish(t_s)`` on the ticks in ``every_ticks``: sensors sample the truth and send (emulated and served
       links), or the host reads what a real device sent (hardware);
    2. the controller runs;
    3. ``receive(t_s)``: actuators take in commands;
    4. ``row()`` when a telemetry row is due, matching ``columns()`` (``(name, width, unit)``: the name is the
       device's name, a dot and the kind's column; its one-line meaning is in ``DeviceKind.columns``);
    5. the truth steps, reading once each :class:`Effect` of ``effects()`` (asked once before t = 0): what an
       actuator does to the truth, held over the step (a dipole, a torque on the body, a momentum exchange with a
       rotor of the truth's wheel cluster: ``sim.truth.EFFECT_TYPES``).

    ``activity()`` counts measurements that reached the stand; the loop's watch reports a device whose count
    stops moving for ``silent_after_s`` of sim time (None: not watched). ``host`` is the host driver the flight
    code gets (None on a served link: the flight computer outside has it).
    """

    name: str
    host: Any = None
    every_ticks: int = 1
    silent_after_s: float | None = None

    def columns(self) -> list[tuple[str, int, str]]:
        return []

    def publish(self, t_s: float) -> None:
        """Sample and send what is due at ``t_s``."""

    def receive(self, t_s: float) -> None:
        """Take in what arrived by ``t_s``."""

    def effects(self) -> tuple[Effect, ...]:
        """What this device does to the truth (none: a sensor); asked once before t = 0, each read every step."""
        return ()

    def row(self) -> tuple:
        return ()

    def activity(self) -> int:
        return 0

    def start(self, events) -> None:
        """Before t = 0: set device clocks and log what was measured (``events.log``)."""

    def summary(self) -> dict:
        return {}

    def close(self) -> None:
        """Release ports and buses (idempotent)."""

    def fault_tap(self, name: str):
        """Where a fault of tap ``name`` (``stand.faults.taps.TAPS``) acts on this device, or None to let
        ``stand.faults.taps.find`` follow the conventions (its emulator, the emulator's or host's port or bus).
        Asked only when a fault first starts on the device, never in a run without faults."""
        return None


def fault_taps(link: str, *own: str, measurement: dict | None = None, medium: str = "serial") -> dict:
    """The fault taps of a device whose emulator runs in the stand (emulated and served links: ``own`` physics
    taps, its ``measurement`` (``{"n": axes, "unit": key suffix}``), its line or bus, its clock, its reboot) or
    that is real (hardware: only its line or bus, through the in-process fault proxy on the host's port).
    ``medium``: "serial" or "can", what its link carries."""
    if link == "hardware":
        return {"link": {"medium": medium}}
    out = {"link": {"medium": medium}, "clock": {}, "reboot": {}, **{t: {} for t in own}}
    if measurement is not None:
        out["measurement"] = measurement
    return out


class DeviceKind:
    """A kind of device: its scenario table, its needs, how it is built, its metrics and plots."""

    name: str = ""
    links: tuple[str, ...] = LINKS
    default_link: str = "emulated"
    #: Criteria metrics this kind evaluates: name -> description with the unit.
    metrics: dict[str, str] = {}
    #: Metrics that need ``at_s``.
    metrics_at: tuple[str, ...] = ()
    #: What a device of this kind senses, actuates, and stimulates for the others (a Helmholtz cage:
    #: "magnetic_field"; stimulators are built, and step, before the devices that read them): names of QUANTITIES.
    senses: tuple[str, ...] = ()
    actuates: tuple[str, ...] = ()
    provides: tuple[str, ...] = ()
    #: Its telemetry columns (the part after ``NAME.``; widths and units are in ``Device.columns()``) -> a one-line
    #: meaning, written into the telemetry's schema.json and listed by ``stand check``.
    column_meanings: dict[str, str] = {}
    #: Its bit-field columns (after ``NAME.``) -> the name of each bit, bit 0 (value 1) first; a flags column a
    #: device's ICD defines holds the ICD's bits unchanged (docs/telemetry_columns.md lists them).
    column_bits: dict[str, tuple[str, ...]] = {}
    #: The plot files it draws (``{name}``: the device's name) -> what each shows (:meth:`plots`, :meth:`kind_plots`).
    plot_files: dict[str, str] = {}
    #: What the operator view draws for it besides its fields of view (:meth:`view_layers`): layer -> meaning.
    view_layer_meanings: dict[str, str] = {}
    #: How the operator view colours its fields of view and validity strip, from its ``NAME.valid`` (and
    #: ``NAME.flags``) columns: ``{"missing": text without a value, "flags": whether NAME.flags says why it is
    #: invalid (the tracker ICD's flags byte: values 2 Sun, 4 Moon, 8 Earth in the field, 16 rate too high), "invalid":
    #: [colour key, text] otherwise}``; None: not drawn.
    view_state: dict | None = None
    #: Its error columns (after ``NAME.``) the view plots on the pointing and knowledge error plot (arcsec).
    view_error_columns: tuple[str, ...] = ()
    #: The view's live plots of its 3-vector columns, one panel per title for all its devices: ``{"title", "unit",
    #: "column" (after ``NAME.``), "fallback" (a run column drawn when no device records one, or absent)}``.
    view_plots: tuple[dict, ...] = ()
    #: How ``stand emulate`` serves this kind (:class:`stand.devices.serving.Serving`); None: it cannot be served.
    serving = None

    def parse(self, t: Table, base: DeviceSpec, step_s: float) -> DeviceSpec:
        raise NotImplementedError

    def network_peers(self, spec: DeviceSpec) -> list[tuple[str, str]]:
        """Network addresses a device of this spec would reach: ``(scenario key, host or multicast group)``, checked
        by :func:`check_network` before anything is built (default: a python-can ``udp_multicast`` channel)."""
        if getattr(spec, "interface", None) == "udp_multicast":
            return [("channel", str(getattr(spec, "channel", "")))]
        return []

    def momentum_wheel(self, spec: DeviceSpec):
        """``(spin_axis_B, inertia_kg_m2, speed0_rad_s)`` when a device of this spec is a momentum wheel the truth
        must carry in its dynamics (composition builds the wheel cluster from these before any device), else
        None."""
        return None

    def datasheet(self, spec: DeviceSpec) -> dict[str, Any]:
        """What a flight team knows of a device of this spec from its datasheet and ICD, handed to flight code
        (:mod:`stand.controllers.spacecraft`): rates, ranges, ratings, SI units named in the key (``max_torque_Nm``).
        Never the simulated device's errors (noise, bias, misalignment): those are the truth the flight code is
        tested against. Default: nothing beyond the name, kind, link and mount every device has."""
        return {}

    def refs(self, spec: DeviceSpec) -> dict[str, tuple[str, str]]:
        """Other devices this one takes something from: scenario key -> (device name, what it must provide)."""
        return {}

    def needs(self, spec: DeviceSpec) -> dict[str, str]:
        """Truth models this device needs (a key of TRUTH_MODELS -> why), for composition and ``stand check``."""
        return {}

    def describe(self, spec: DeviceSpec) -> str:
        return f"{self.name}, {spec.link}"

    def build(self, spec: DeviceSpec, ctx: BuildContext) -> Device:
        raise NotImplementedError

    def fault_taps(self, spec: DeviceSpec) -> dict[str, dict]:
        """Where faults can act on a device of this spec: tap (``stand.faults.taps.TAPS``) -> its details (a
        measurement's ``{"n": axes, "unit": key suffix}``), for validation before t = 0 and docs/faults.md
        (:func:`fault_taps` builds the usual answer). Default: none, no fault can name it."""
        return {}

    def cost(self, spec: DeviceSpec) -> DeviceCost:
        """What the device costs a run (the default assumes a publish every tick and a 16-float row)."""
        return DeviceCost()

    def metric(self, metric: str, at_s: float | None, tel: dict, names: list[str]) -> float:
        """The value of one of ``metrics`` from the telemetry of this kind's devices ``names``."""
        return math.nan

    def plots(self, tel: dict, name: str, out_dir, limits: list) -> list[str]:
        """The plots of device ``name`` (files written in ``out_dir``, relative names)."""
        return []

    def kind_plots(self, tel: dict, names: list[str], out_dir) -> list[str]:
        """Plots drawn once for all the devices ``names`` of this kind in a run (one figure comparing them)."""
        return []

    def view_layers(self, spec: DeviceSpec) -> dict:
        """What the operator view draws for a device of this spec, into its entry in ``view.json``: ``fovs``
        (fields of view: ``{"shape": "rect", "axis_S", "fov_deg", "label"}`` or ``{"shape": "cone", "axis_S",
        "half_deg", "label"}``, ``"head": true`` for a head lit by its ``NAME.currents``), and any of
        ``exclusion_deg`` (body -> cone half-angle), ``rate_limit_deg_s`` and ``image`` (the live page's image panel:
        ``{"renders": True, "size_px", "delay_s"}`` for a device whose ``image`` solver renders a detector image,
        ``{"renders": False, "why"}`` for one of a kind that could but does not). (``view_state`` and
        ``view_error_columns`` join them.) The default draws a spec's ``fov_deg`` (rectangle) or ``fov_half_deg``
        (cone)."""
        fov, half = getattr(spec, "fov_deg", None), getattr(spec, "fov_half_deg", None)
        if fov is not None:
            return {"fovs": [{"shape": "rect", "axis_S": [0.0, 0.0, 1.0], "fov_deg": [float(x) for x in fov],
                              "label": spec.name}]}
        if half is not None:
            return {"fovs": [{"shape": "cone", "axis_S": [0.0, 0.0, 1.0], "half_deg": float(half),
                              "label": spec.name}]}
        return {"fovs": []}


#: CAN interfaces a link may use. Emulated devices stay in the process; a hardware or served link names a
#: CAN adapter (udp_multicast is for tests inside a private network namespace: it sends to the network).
CAN_INTERFACES = {
    "emulated": ("virtual", "stand_loopback"),
    "hardware": ("socketcan", "serial", "slcan", "pcan", "kvaser", "vector", "ixxat", "gs_usb", "neovi",
                 "canalystii", "systec", "seeedstudio", "cantact", "udp_multicast"),
}
CAN_INTERFACES["served"] = CAN_INTERFACES["hardware"]
#: Network hosts a serial URL (socket://, rfc2217://) may name: a scenario never makes the stand connect out.
LOCAL_HOSTS = ("127.0.0.1", "localhost", "[::1]")


#: What ``stand run --allow-remote`` says, for the sentence that refuses an address.
ALLOW_REMOTE_FLAG = "stand run --allow-remote"


def is_loopback_host(host: str) -> bool:
    """``localhost`` or an address in 127.0.0.0/8 or ::1: a peer on this machine."""
    import ipaddress

    host = host.strip("[]")
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # any other name may resolve anywhere


def is_local_multicast(group: str) -> bool:
    """A multicast group whose datagrams stay on this host or its link: 224.0.0.0/24 (never routed), or an IPv6
    interface-local (ffx1::/16) or link-local (ffx2::/16) group."""
    import ipaddress

    try:
        addr = ipaddress.ip_address(group.strip("[]"))
    except ValueError:
        return False
    if not addr.is_multicast:
        return False
    if addr.version == 4:
        return addr in ipaddress.ip_network("224.0.0.0/24")
    return addr.packed[1] & 0x0F in (1, 2)  # the scope nibble of ffXS::


def check_network(specs, allow_remote=()) -> None:
    """Before anything is built: every network address a device would reach is on this machine (loopback), or a
    link-/host-local multicast group, or one the operator allowed on the command line (``--allow-remote``).

    Raises ScenarioError naming the device's field, the value and the flag."""
    allowed = {h.strip().strip("[]").lower() for h in allow_remote}
    for i, spec in enumerate(specs):
        for key, address in get(spec.kind).network_peers(spec):
            value = str(getattr(spec, key, address))
            if address.strip("[]").lower() in allowed:
                continue
            if key == "channel":  # a multicast group
                if is_local_multicast(address):
                    continue
                raise ScenarioError(f"devices[{i}].{key}", value, "a multicast group that stays on this host or its "
                                    "link (224.0.0.0/24, ff01::/16, ff02::/16); a scenario does not make the stand "
                                    f"send to the network unless the operator allows that group: {ALLOW_REMOTE_FLAG} "
                                    f"{address}")
            if not is_loopback_host(address):
                raise ScenarioError(f"devices[{i}].{key}", value, "a host on this machine (127.0.0.0/8, ::1, "
                                    "localhost); a scenario does not make the stand connect to other hosts unless "
                                    f"the operator allows that host: {ALLOW_REMOTE_FLAG} {address}")


#: How an emulated serial device is wired to its host driver: ``pipe`` (in-process, the bytes never leave Python:
#: the fast default) or ``pty`` (a kernel pty pair, the tty path a bench's adapter takes).
SERIAL_LINES = ("pipe", "pty")


def serial_line(kind: str, name: str):
    """The two ends of an emulated device's serial line: ``(emulator_port, host_port, close)``.

    ``host_port`` is an open port (``pipe``) or the pty slave's path (``pty``) for the host driver to open;
    ``close()`` releases what the line holds once both drivers are closed. The emulator's end never waits to
    write (the loop's thread drives it): what the host has not read by then is counted as dropped."""
    import os

    from drivers.serial_port import pipe_pair, pty_pair

    if kind == "pipe":
        emulator_end, host_end = pipe_pair(name)
        emulator_end.write_timeout = 0.0

        def close():
            emulator_end.close()
            host_end.close()

        return emulator_end, host_end, close
    master, slave_path, slave_fd = pty_pair()
    return master, slave_path, lambda: os.close(slave_fd)


def check_serial_url(t: Table, key: str, value: str) -> str:
    """A serial port: a device path, a pty, ``loop://``, or a socket/RFC 2217 URL to this machine only."""
    if "\x00" in value:
        raise t.error(key, value.replace("\x00", "\\0"), "a port name without NUL bytes")
    scheme, sep, rest = value.partition("://")
    if not sep:
        return value
    if scheme == "loop":
        return value
    if scheme in ("socket", "rfc2217"):
        host = rest.rsplit(":", 1)[0]
        if host in LOCAL_HOSTS:
            return value
        raise t.error(key, value, f"a {scheme}:// URL to this machine ({', '.join(LOCAL_HOSTS)}); a scenario does "
                      "not make the stand connect to other hosts (use a device path for a real line)")
    raise t.error(key, value, "a device path (/dev/ttyUSB0), a pty, loop://, or socket://127.0.0.1:PORT")


def can_endpoint(t: Table, base: DeviceSpec) -> tuple[str, str]:
    """A CAN device's ``interface`` and ``channel``, checked: an emulated device defaults to the in-process
    ``stand_loopback`` bus on a channel of its own, a hardware or served one to ``socketcan`` on ``can0``."""
    emulated = base.link == "emulated"
    interface = t.text("interface", "stand_loopback" if emulated else "socketcan")
    channel = t.text("channel", f"stand-{base.name}" if emulated else "can0")
    check_can(t, base.link, interface, channel)
    return interface, channel


def check_can(t: Table, link: str, interface: str, channel: str) -> None:
    allowed = CAN_INTERFACES[link]
    if interface not in allowed:
        raise t.error("interface", interface, f"for link = {link!r} one of " + ", ".join(repr(a) for a in allowed)
                      + (" (an emulated device stays inside the stand; a real adapter needs link = 'hardware' or "
                         "'served')" if link == "emulated" else ""))
    if interface in ("serial", "slcan"):
        check_serial_url(t, "channel", channel)
    elif "\x00" in channel:
        raise t.error("channel", channel.replace("\x00", "\\0"), "a channel name without NUL bytes")


#: Wall-clock seconds a served device may hear nothing from outside before the run says so (:class:`Rejections`).
UNHEARD_AFTER_S = 5.0


class Rejections:
    """What a served device drops of what the flight computer outside sends, for the event log and the summary.

    A served device counts and drops what it cannot decode (a bad CRC, a cut frame, a bad SLIP escape, a CAN frame
    its adapter cannot decode or with an id it does not take) and goes on, as a real one does. ``count()`` reads the
    device's count, ``reason()`` the latest reason; :meth:`check`, called by the device each tick, logs a
    ``frames_rejected`` event at the first rejected frame and at each tenfold count after it (1, 10, 100...), so
    a flood of garbage cannot flood the log, and once a ``device_conflict`` when ``conflict()`` says another node
    serves the same device. The whole count goes to the summary (``rejected_frames``).

    ``heard()`` (optional) counts what arrived from outside at all, good or bad: when it is still 0 after
    :data:`UNHEARD_AFTER_S` of wall time from the first tick, a ``device_unheard`` event (a WARNING on the console,
    once) says that no flight computer talks to the device, and ``device_heard`` when something arrives later."""

    def __init__(self, name: str, count, reason, conflict=None, heard=None, clock=time.monotonic):
        self.name = name
        self.count, self.reason, self.conflict, self.heard = count, reason, conflict, heard
        self.events = None
        self._next = 1
        self._conflict_logged = False
        self._clock = clock
        self._since: float | None = None  # wall time of the first check
        self.unheard = False  # said so, not heard from since

    def start(self, events) -> None:
        self.events = events

    def _listen(self, t_s: float) -> None:
        """The once-only unheard warning (one clock read per tick, and only until it is decided)."""
        now = self._clock()
        if self._since is None:
            self._since = now
        heard = self.heard()
        if self.unheard and heard:
            self.unheard, self.heard = False, None
            self.events.log("device_heard", f"{self.name}: first frame from outside by t = {t_s:.3f} s", t_s=t_s,
                            device=self.name)
        elif heard:
            self.heard = None  # heard from: nothing more to watch
        elif not self.unheard and now - self._since >= UNHEARD_AFTER_S:
            self.unheard = True
            self.events.log("device_unheard", f"{self.name}: nothing received from outside in the first "
                            f"{UNHEARD_AFTER_S:g} s of wall time (t = {t_s:.3f} s): no flight computer talks to this "
                            "served device; check its port or bus, the cable and that the flight program runs (the "
                            "run goes on)", t_s=t_s, device=self.name)

    def check(self, t_s: float) -> None:
        if self.events is None:
            return
        if self.heard is not None:
            self._listen(t_s)
        n = self.count()
        if n >= self._next:
            self.events.log("frames_rejected", f"{self.name}: {n} frame{'' if n == 1 else 's'} from outside rejected "
                            f"by t = {t_s:.3f} s, counted and dropped (the run goes on); the latest: {self.reason()}",
                            t_s=t_s, device=self.name, count=n)
            while self._next <= n:
                self._next *= 10
        if self.conflict is not None and not self._conflict_logged:
            text = self.conflict()
            if text:
                self._conflict_logged = True
                self.events.log("device_conflict", f"{self.name}: {text}", t_s=t_s, device=self.name)


#: Longest wall-clock wait for a datagram to cross an in-process serial line.
SETTLE_TIMEOUT_S = 1.0


def frames_in(counters: dict) -> int:
    """Frames a serial driver has taken in, good or rejected (from its ``counters``)."""
    n = counters["frames_received"]
    for key, value in counters.items():
        if key.startswith("rejected"):
            n += value
    return n


def taken_in(sent: int, counters: dict) -> bool:
    """Whether a serial driver (its ``counters``) has taken in ``sent`` frames, good or rejected; the good ones alone
    answer most calls, without summing the rejections."""
    return sent <= counters["frames_received"] or sent <= frames_in(counters)


class SerialDevice(Device):
    """What the serial kinds (star tracker, gyro, sun sensor) share: a host driver, an emulator or both (by link), and
    the emulated line between them (:func:`serial_line`), all released by :meth:`close`."""

    host = None
    emulator = None
    _close_line = None  # releases the emulated serial line
    rejections = None  # a served emulator's Rejections (serve())

    def serve(self, emulator) -> None:
        """The served link: ``emulator`` on a real port, for a flight computer outside. What it rejects of what the
        flight computer sends goes to the event log (:class:`Rejections`, checked by :meth:`check_rejections`) and
        to the summary (``rejected_frames``)."""
        self.emulator = emulator
        self.rejections = Rejections(self.name, lambda: emulator.rejected_frames, lambda: emulator.last_rejected,
                                     heard=lambda: emulator.counters.get("bytes_received", 0))

    def start(self, events) -> None:
        if self.rejections is not None:
            self.rejections.start(events)

    def open_emulated(self, port: str, make_emulator, make_host) -> None:
        """The emulated link: an in-process serial line of kind ``port`` (:func:`serial_line`) with
        ``make_emulator(emulator_end)`` and ``make_host(host_end)`` on its two ends; on any failure everything
        opened so far is released before the error goes on."""
        emulator_end, host_end, self._close_line = serial_line(port, self.name)
        try:
            self.emulator = make_emulator(emulator_end)
            self.host = make_host(host_end)
        except BaseException:
            self.close()
            raise

    def driver_counters(self) -> dict:
        """The host's and the emulator's counters, for the summary (``host_counters``, ``emulator_counters``)."""
        out = {}
        if self.host is not None:
            out["host_counters"] = dict(self.host.counters)
        if self.emulator is not None:
            out["emulator_counters"] = dict(self.emulator.counters)
        if self.rejections is not None:
            out["rejected_frames"] = self.rejections.count()
        return out

    def close(self) -> None:
        if self.host is not None:
            self.host.close()
        if self.emulator is not None:
            self.emulator.close()
        if self._close_line is not None:
            self._close_line()
            self._close_line = None


def line_faulted(emulator) -> bool:
    """Whether a protocol fault has been put on ``emulator``'s line (``stand.faults``): frames may then be lost, held
    or added on purpose, and the counts of the two ends can no longer match."""
    return getattr(emulator.port, "wrapped", None) is not None


def take_in_arrived(host) -> None:
    """The host takes in whatever has arrived on an in-process line (a pipe hands bytes over at once), without
    waiting for frames a fault may have lost; bounded."""
    for _ in range(8):
        if not host.port.in_waiting:
            break
        host.poll()


def settle_serial(emulator, host, name: str, awaited: str, timeout_s: float = SETTLE_TIMEOUT_S) -> None:
    """Wait (bounded) until ``host`` has taken in every datagram ``emulator`` sent on their in-process serial line
    (:func:`serial_line`).

    A pty hands bytes over asynchronously (a pipe at once); settling each tick makes every sample reach the flight
    code in the tick it was sent, the same in every run. Raises :class:`drivers.errors.DeviceTimeoutError` after
    ``timeout_s`` of wall time."""
    if line_faulted(emulator):  # checked first: duplicates and babble can put the host's count ahead
        take_in_arrived(host)
        return
    if taken_in(emulator.counters["sent"], host.counters):
        return
    host.poll()  # a pipe has handed the bytes over already: most ticks end here, without a wait
    if taken_in(emulator.counters["sent"], host.counters):
        return
    from drivers.errors import DeviceTimeoutError
    from drivers.serial_port import wait_readable

    deadline = time.monotonic() + timeout_s
    while not taken_in(emulator.counters["sent"], host.counters):
        left = deadline - time.monotonic()
        if left <= 0:
            raise DeviceTimeoutError(f"{name}: a datagram written to the in-process serial line did not arrive "
                                     f"within {timeout_s:g} s.", device=name, awaited=awaited, timeout_s=timeout_s)
        wait_readable(host.port, min(left, 0.01))
        host.poll()
