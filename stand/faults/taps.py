"""Where a fault acts on a device: its *taps*.

A tap is found on a built device only when a fault first starts on it (:func:`find`), so a run whose faults never
fire, and every run without ``[[faults]]``, builds and ticks exactly as before: the same bits, nothing per tick.

* ``measurement``: the sensor's measured vector, in sensor axes and the kind's SI unit, on its way to the codec
  (``sim.sensor_faults.VectorTap``, installed over the callable that produces it, named by ``Device.fault_tap``).
* ``link``: the bytes or frames between an emulator and the host (or, on a hardware link, between the host and the
  real port): ``drivers.link_faults.FaultyPort`` / ``FaultyBus`` put over the emulator's (or host's) port or bus.
* ``clock`` and ``reboot``: the emulator's device clock and its power cycle.
* ``wheel``, ``tracker``, ``coils``, ``cage``: the kind's own physics, attributes of its emulator or model.

A kind may override ``Device.fault_tap(name)`` to say where a tap is; otherwise :func:`find` follows the
conventions every shipped emulator keeps (``device.emulator``, its ``port`` or ``bus``).
"""

from __future__ import annotations

#: Taps a device may offer, and what each is (docs/faults.md lists the fault types of each).
TAPS = {
    "measurement": "the measured vector a sensor sends (sensor axes, the kind's SI unit)",
    "link": "the serial line or CAN bus between the device and the host",
    "clock": "the device clock that stamps its messages",
    "reboot": "the device's power cycle (sequence numbers, clock, boot message)",
    "wheel": "a reaction wheel's motor, bearing and speed sensor",
    "tracker": "a star tracker's solution (blinding, loss, misidentification, latency)",
    "coils": "a magnetorquer's coils (the dipole it produces)",
    "cage": "a Helmholtz cage's coil pairs (the field it produces)",
    "stimulus": "what a stimulator shows a real sensor (the star screen's sky, the Helmholtz cage's field)",
}


class TapError(LookupError):
    """A device does not have the tap a fault needs (said before t = 0 by validation; live, to the caller)."""


def find(device, name: str):
    """The object a fault of tap ``name`` acts on, on ``device`` (installed on first use, then kept). Raises
    :class:`TapError` with the reason when the device has none."""
    cache = device.__dict__.setdefault("_fault_taps", {})
    if name in cache:
        return cache[name]
    tap = device.fault_tap(name) if hasattr(device, "fault_tap") else None
    if tap is None:
        tap = _conventional(device, name)
    if tap is None:
        raise TapError(f"device {device.name!r} offers no {name!r} tap ({TAPS.get(name, name)})")
    cache[name] = tap
    return tap


def _conventional(device, name: str):
    emulator, host = getattr(device, "emulator", None), getattr(device, "host", None)
    if name == "link":
        return link_tap(emulator, "device") if emulator is not None else link_tap(host, "host")
    if name in ("clock", "reboot", "wheel", "tracker", "coils", "cage"):
        return emulator
    if name == "stimulus":
        return device
    return None


def link_tap(endpoint, side: str):
    """Put a fault-injecting wrapper (``drivers.link_faults``) over ``endpoint``'s serial port or CAN bus (once) and
    return it. ``side``: ``"device"`` for an emulator's end, ``"host"`` for a host driver's (a hardware link: the
    in-process proxy between the host and the real port)."""
    if endpoint is None:
        return None
    from drivers.link_faults import FaultyBus, FaultyPort

    port, bus = getattr(endpoint, "port", None), getattr(endpoint, "bus", None)
    if port is not None and not isinstance(port, str):
        if not isinstance(port, FaultyPort):
            codec = getattr(endpoint, "codec", None)
            # Bytes read are cut into frames the way the endpoint's own framing does: fixed-length datagrams by
            # identifier, or SLIP.
            datagrams = hasattr(codec, "by_id") and hasattr(codec, "byte_order")
            port = endpoint.port = FaultyPort(port, side=side, framing=codec if datagrams else "slip")
        return port
    if bus is not None:
        if not isinstance(bus, FaultyBus):
            bus = FaultyBus(bus, side=side)
            endpoint.use_bus(bus)  # the node re-reads its fast paths from the wrapper
        return bus
    return None
