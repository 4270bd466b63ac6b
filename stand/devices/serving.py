"""How a kind is served by ``stand emulate KIND``: the declaration a kind carries (``DeviceKind.serving``) and the
wall-clock serving loops the kinds share.

``stand emulate`` names no kind: it finds the kind through the one registry (:func:`stand.devices.get`, shipped
kinds and those of the ``adcs_stand.devices`` entry point alike), builds the kind's options from its
:class:`Serving` and calls its ``serve(args, fail)``. A kind without ``serving`` cannot be served.

Open loop (no ``--scenario``) a kind serves fixed values (its options say which); with ``--scenario`` the scenario
runs paced with the device on a ``served`` link and ``port_fields`` turns ``--port`` into the device's table keys.
"""

from __future__ import annotations

import json
import math
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

#: After a SIGTERM the emulator has this long to stop cleanly; then SIGALRM's default action ends the process
#: (a write to an output nobody drains, or a server thread that does not stop, cannot keep it alive).
SIGTERM_GRACE_S = 10
OPEN_LOOP = "; open loop (no --scenario: a fixed source, not a simulated spacecraft)"


@dataclass(frozen=True)
class ServeOption:
    """One option of ``stand emulate KIND`` (the arguments of ``argparse.add_argument``)."""

    flag: str
    help: str
    default: Any = None
    type: Callable[[str], Any] = str
    choices: tuple | None = None
    #: Options shown under one heading (e.g. the star tracker looking at the screen).
    group: str | None = None


@dataclass(frozen=True)
class Serving:
    """How ``stand emulate`` serves a kind.

    ``serve(args, fail) -> exit status`` runs the emulator open loop on ``args.port`` until ``args.duration``
    (None: until Ctrl-C or SIGTERM) and prints its counters as one JSON line; ``fail(sentence)`` reports a usage
    error (exit 2; a port another process holds is one). ``port_fields(port, args)`` gives the scenario keys of a
    served device on ``port`` (ValueError with one sentence for a bad port); None: no ``--scenario``.
    """

    summary: str
    port_help: str
    serve: Callable[[Any, Callable[[str], int]], int]
    options: tuple[ServeOption, ...] = ()
    port_fields: Callable[[str, Any], dict[str, str]] | None = None


def serial_port_fields(port: str, args) -> dict[str, str]:
    """A served serial device: ``port`` and ``baudrate`` (``--baud``)."""
    return {"port": port, "baudrate": str(args.baud)}


def can_endpoint(port: str, what: str) -> tuple[str, str]:
    """``INTERFACE:CHANNEL`` split (ValueError naming the value and what is allowed)."""
    interface, _, channel = port.partition(":")
    if not interface or not channel:
        raise ValueError(f"--port {port!r} is not allowed for the {what}; give INTERFACE:CHANNEL, e.g. socketcan:can0, "
                         "serial:/dev/ttyUSB0 or virtual:adcs.")
    return interface, channel


def can_port_fields(what: str) -> Callable[[str, Any], dict[str, str]]:
    def fields(port: str, args) -> dict[str, str]:
        interface, channel = can_endpoint(port, what)
        return {"interface": interface, "channel": channel}

    return fields


#: ``--port`` of every CAN kind.
CAN_PORT_HELP = "INTERFACE:CHANNEL of python-can (socketcan:can0, serial:/dev/ttyUSB0, virtual:adcs)"
#: ``--seed`` of an emulator with noise.
SEED_OPTION = ServeOption("--seed", "noise seed (default 0)", 0, int)


def can_serving(summary: str, what: str, serve: Callable[[Any, Callable[[str], int]], int],
                options: tuple[ServeOption, ...]) -> Serving:
    """How a CAN kind is served: on ``--port INTERFACE:CHANNEL`` (``what`` names the device in errors)."""
    return Serving(summary=summary, port_help=CAN_PORT_HELP, serve=serve, port_fields=can_port_fields(what),
                   options=options)


def field_option(help_text: str) -> ServeOption:
    """``--field-nT X,Y,Z``: the fixed field a magnetometer sees open loop."""
    return ServeOption("--field-nT", help_text, "20000,0,-40000")


def fixed_field(args) -> Callable[[float], tuple[float, float, float]]:
    """``t_s -> field, T`` from ``--field-nT`` (ValueError naming the option, the value and what is allowed)."""
    field_T = tuple(x * 1e-9 for x in numbers(args.field_nT, 3, "--field-nT", "nT (X,Y,Z)"))
    return lambda _t: field_T


def serve_can_in_field(args, fail, what: str, own_ids, make: Callable[[Any, Callable[[float], Any]], Any],
                       detail: str = "") -> int:
    """:func:`serve_can` for a device with a magnetometer seeing the fixed field of ``--field-nT``:
    ``make(bus, field)``; a bad ``--field-nT`` is a usage error. ``detail`` ends the banner (what is added to it)."""
    try:
        field = fixed_field(args)
    except ValueError as exc:
        return fail(str(exc))
    return serve_can(args, fail, what, own_ids, lambda bus: make(bus, field), detail)


def numbers(text: str, count: int, flag: str, unit: str) -> tuple[float, ...]:
    """``count`` finite numbers from ``A,B,...`` (ValueError naming the option, the value and what is allowed)."""
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{flag} {text!r} is not allowed; give {count} numbers separated by commas, in {unit}.")
    return values


def banner(what: str, where: str, duration_s: float | None, detail: str = "") -> None:
    print(f"stand emulate: {what} on {where}" + (f" for {duration_s:g} s" if duration_s else " until Ctrl-C")
          + OPEN_LOOP + (f"; {detail}" if detail else ""), flush=True)


def report(args, **fields) -> None:
    print(json.dumps({"device": args.device, "port": args.port, **fields}), flush=True)


def stop_on_sigterm():
    """SIGTERM stops like Ctrl-C, and for sure within ``SIGTERM_GRACE_S``; returns the previous handler (None off
    the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        return None

    def _term(signum, frame):
        signal.signal(signal.SIGALRM, signal.SIG_DFL)
        signal.alarm(SIGTERM_GRACE_S)
        raise KeyboardInterrupt

    return signal.signal(signal.SIGTERM, _term)


def serve_until_stopped(emu, duration_s: float | None, start=None) -> int:
    """Run an emulator's own loop until ``duration_s``, Ctrl-C or SIGTERM; a device error (the port lost) is
    printed and gives exit status 1. ``start`` runs first, inside the same handling (e.g. setting time zero)."""
    from drivers.errors import DriverError

    old = stop_on_sigterm()
    try:
        if start is not None:
            start()
        emu.run(duration_s)
    except KeyboardInterrupt:
        pass
    except DriverError as exc:
        print(f"stand emulate: {exc}", file=sys.stderr)
        return 1
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)
    return 0


def serve_serial(args, fail, what: str, make: Callable[[], Any]) -> int:
    """A serial emulator ``make()`` (it opens ``args.port``, exclusively) served in wall time; its counters as one
    JSON line at the end. A port that cannot be opened, or that another process holds, is a usage error."""
    from drivers.errors import DriverError

    old = stop_on_sigterm()  # from before the banner: a SIGTERM any time after it stops cleanly
    status = 0
    try:
        try:
            emu = make()
        except (ValueError, DriverError) as exc:
            return fail(str(exc))
        with emu:
            banner(what, args.port, args.duration)
            status = serve_until_stopped(emu, args.duration)
            report(args, counters=emu.counters)
    except KeyboardInterrupt:  # stopped while the port was being opened: nothing served, nothing to report
        pass
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)
    return status


def serve_can(args, fail, what: str, own_ids, make: Callable[[Any], Any], detail: str = "") -> int:
    """A CAN emulator ``make(bus)`` on ``args.port`` (INTERFACE:CHANNEL; a serial-line adapter is held exclusively)
    served in wall time, 1 ms between services. What the flight computer sends that the device cannot decode is
    counted and dropped, never raised (``ServedBus``)."""
    from drivers.can_bus import ServedBus, open_device_bus
    from drivers.errors import DriverError

    try:
        interface, channel = can_endpoint(args.port, what)
        bus = ServedBus(open_device_bus(interface, channel), own_ids=own_ids)
    except (ValueError, DriverError) as exc:
        return fail(str(exc))
    old = stop_on_sigterm()
    status = 0
    try:
        emu = make(bus)
    except ValueError as exc:
        bus.shutdown()
        return fail(str(exc))
    with emu:
        banner(what, f"CAN {interface}:{channel}", args.duration, detail)
        t0 = time.monotonic()
        try:
            while args.duration is None or time.monotonic() - t0 < args.duration:
                emu.service(time.monotonic() - t0)
                time.sleep(0.001)
        except KeyboardInterrupt:
            pass
        except DriverError as exc:  # the adapter lost
            print(f"stand emulate: {exc}", file=sys.stderr)
            status = 1
        finally:
            if old is not None:
                signal.signal(signal.SIGTERM, old)
        if bus.conflict:
            print(f"stand emulate: {bus.conflict}", file=sys.stderr)
        report(args, counters={**emu.counters, **bus.counters},
               rejected_frames=emu.rejected_frames + bus.counters["rejected_undecodable"])
    return status
