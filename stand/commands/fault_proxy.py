"""``stand fault-proxy``: put protocol faults between a host driver and a real device (or an emulator in another
process), on a serial line or a CAN bus, in wall time::

    stand fault-proxy serial --host-port /dev/pts/7 --device-port /dev/ttyUSB0 --framing gyro \\
        --fault drop:rate=0.1 --fault delay:delay_s=0.02,direction=to_host --duration 60 --counters c.json
    stand fault-proxy can --host socketcan:vcan0 --device socketcan:can0 --faults faults.toml

A fault is ``KIND:param=value,...`` (``at_s`` and ``duration_s`` say when, in seconds since the proxy started; the
kinds and parameters are drivers.link_faults's) or a ``[[faults]]`` table with ``type = KIND`` in the TOML file.
The proxy ends after ``--duration`` or on SIGTERM/SIGINT, then prints its counters as JSON (and writes them to
``--counters``). Exit 2 for a bad option or fault, 1 when a port or bus cannot be opened.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import tomllib
from pathlib import Path
from typing import Any

FRAMINGS = ("chunk", "slip", "gyro", "sun-sensor")


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("fault-proxy", help="forward a serial line or CAN bus between a host and a device, "
                                                 "with protocol faults (drops, delays, corruption ...)",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("mode", choices=("serial", "can"), help="what the link is")
    p.add_argument("--host-port", help="serial: the host's side (a path, a pty or socat link, a loopback URL)")
    p.add_argument("--device-port", help="serial: the device's side")
    p.add_argument("--framing", default="chunk", choices=FRAMINGS,
                   help="serial: how the bytes are cut into frames (chunk: as read; slip: the star tracker's; gyro, "
                        "sun-sensor: their datagrams)")
    p.add_argument("--baud", type=int, default=115200, help="serial: baud rate of device paths")
    p.add_argument("--host", help="CAN: the host's bus as INTERFACE:CHANNEL (e.g. socketcan:vcan0)")
    p.add_argument("--device", help="CAN: the device's bus as INTERFACE:CHANNEL")
    p.add_argument("--host-bus-arg", action="append", default=[], metavar="KEY=VALUE",
                   help="CAN: a keyword for the host's python-can bus (repeatable), e.g. port=43114 or bitrate=500000")
    p.add_argument("--device-bus-arg", action="append", default=[], metavar="KEY=VALUE",
                   help="CAN: a keyword for the device's python-can bus (repeatable)")
    p.add_argument("--fault", action="append", default=[], metavar="KIND:P=V,...",
                   help="a fault (repeatable), e.g. drop:rate=0.1 or delay:delay_s=0.05,direction=to_host,at_s=5")
    p.add_argument("--faults", metavar="TOML", help="a file of [[faults]] tables (type = KIND and its parameters)")
    p.add_argument("--seed", type=int, default=0, help="seed of the faults' random draws (default 0)")
    p.add_argument("--duration", type=float, help="stop after S seconds (default: until SIGTERM or Ctrl-C)")
    p.add_argument("--counters", metavar="FILE", help="also write the counters as JSON to FILE")
    p.set_defaults(func=run)
    return p


def _fail(msg: str) -> int:
    print(f"stand fault-proxy: error: {msg}", file=sys.stderr)
    return 2


def _value(text: str) -> Any:
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def parse_fault(text: str) -> dict:
    """``KIND:p=v,p=v`` -> ``{"type": KIND, p: v, ...}`` (numbers as numbers); ValueError naming the text."""
    kind, _, rest = text.partition(":")
    table: dict[str, Any] = {"type": kind.strip()}
    for part in filter(None, (x.strip() for x in rest.split(","))):
        key, eq, value = part.partition("=")
        if not eq or not key.strip():
            raise ValueError(f"--fault {text!r}: {part!r} is not allowed; allowed: KIND:param=value,param=value.")
        table[key.strip()] = _value(value.strip())
    return table


def _faults(args) -> list[dict]:
    tables = [parse_fault(t) for t in args.fault]
    if args.faults:
        try:
            data = tomllib.loads(Path(args.faults).read_text())
        except (OSError, tomllib.TOMLDecodeError) as exc:
            raise ValueError(f"--faults {args.faults!r} cannot be read: {exc}.") from None
        listed = data.get("faults", [])
        if not isinstance(listed, list) or not all(isinstance(t, dict) for t in listed):
            raise ValueError(f"--faults {args.faults!r}: faults must be [[faults]] tables.")
        tables += listed
    return tables


def _framing(name: str) -> Any:
    if name == "chunk":
        return None
    if name == "slip":
        return "slip"
    if name == "gyro":
        from drivers.gyro.codec import GyroCodec

        return GyroCodec()
    from drivers.sun_sensor.codec import SunSensorCodec

    return SunSensorCodec()


def _bus_arg(flag: str, value: str | None) -> tuple[str, str]:
    from stand.devices import is_local_multicast

    if not value or ":" not in value:
        raise ValueError(f"{flag} = {value!r} is not allowed; allowed: INTERFACE:CHANNEL, e.g. socketcan:vcan0.")
    interface, channel = value.split(":", 1)
    if interface == "udp_multicast" and not is_local_multicast(channel):
        raise ValueError(f"{flag} = {value!r} is not allowed; allowed: a udp_multicast group that stays on this "
                         "host or its link (224.0.0.0/24, ff01::/16, ff02::/16).")
    return interface, channel


def _bus_kwargs(flag: str, items: list[str]) -> dict[str, Any]:
    out = {}
    for item in items:
        key, eq, value = item.partition("=")
        if not eq or not key.strip().isidentifier():
            raise ValueError(f"{flag} = {item!r} is not allowed; allowed: KEY=VALUE, e.g. port=43114.")
        out[key.strip()] = _value(value.strip())
    return out


def _check_port(flag: str, value: str | None) -> str:
    from stand.devices import is_loopback_host

    if not value:
        raise ValueError(f"{flag} is required in serial mode (a path or a loopback URL).")
    if "://" in value and not value.startswith(("loop://", "spy://")):
        host = value.split("://", 1)[1].rsplit(":", 1)[0]
        if not is_loopback_host(host):
            raise ValueError(f"{flag} = {value!r} is not allowed; allowed: a path, or a URL to a host on this "
                             "machine (127.0.0.0/8, ::1, localhost).")
    return value


def _open(args) -> Any:
    from drivers.fault_proxy import CanFaultProxy, SerialFaultProxy

    if args.mode == "serial":
        return SerialFaultProxy(args.host_port, args.device_port, framing=_framing(args.framing), baudrate=args.baud)
    from drivers.can_bus import open_bus

    host = open_bus(*_bus_arg("--host", args.host), **_bus_kwargs("--host-bus-arg", args.host_bus_arg))
    try:
        device = open_bus(*_bus_arg("--device", args.device), **_bus_kwargs("--device-bus-arg", args.device_bus_arg))
    except Exception:
        host.shutdown()
        raise
    return CanFaultProxy(host, device)


def run(args) -> int:
    from drivers.errors import DriverError

    try:
        tables = _faults(args)
        if args.duration is not None and not 0 < args.duration < 1e9:
            raise ValueError(f"--duration = {args.duration!r} is not allowed; allowed: seconds > 0.")
        if args.mode == "serial":
            _check_port("--host-port", args.host_port)
            _check_port("--device-port", args.device_port)
        else:
            _bus_arg("--host", args.host)
            _bus_arg("--device", args.device)
            _bus_kwargs("--host-bus-arg", args.host_bus_arg)
            _bus_kwargs("--device-bus-arg", args.device_bus_arg)
        from drivers.fault_proxy import check_faults

        check_faults(tables, ("error_frame",) if args.mode == "can" else ())
    except ValueError as exc:
        return _fail(str(exc))
    try:
        proxy = _open(args)
    except (DriverError, OSError, ValueError) as exc:
        print(f"stand fault-proxy: {exc}", file=sys.stderr)
        return 1
    stopping: list[int] = []

    def on_signal(signum, _frame) -> None:
        stopping.append(signum)

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        with proxy:
            proxy.schedule(tables, args.seed)
            print(f"stand fault-proxy: forwarding ({args.mode}) with {len(tables)} fault(s)", flush=True)
            proxy.run(args.duration, stop=lambda: bool(stopping))
            report = {"mode": args.mode, **proxy.report(), "stopped_by": "signal" if stopping else "duration"}
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
    text = json.dumps(report, indent=1, sort_keys=True)
    print(text, flush=True)
    if args.counters:
        Path(args.counters).write_text(text + "\n")
    return 0
