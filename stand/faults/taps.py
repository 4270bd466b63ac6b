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
        return link_tap(emulator if emulator is not None else host)
    if name in ("clock", "reboot", "wheel", "tracker", "coils", "cage"):
        return emulator
    return None


def link_tap(endpoint):
    """Put a fault-injecting wrapper over ``endpoint``'s serial port or CAN bus (once) and return it."""
    if endpoint is None:
        return None
    from drivers.link_faults import FaultyBus, FaultyPort

    for attr, wrapper in (("port", FaultyPort), ("bus", FaultyBus)):
        inner = getattr(endpoint, attr, None)
        if inner is None or isinstance(inner, str):
            continue
        if isinstance(inner, wrapper):
            return inner
        wrapped = wrapper(inner)
        setattr(endpoint, attr, wrapped)
        return wrapped
    return None
