"""Host driver: the stand (or a test, or an operator) driving a Helmholtz cage controller over
Modbus, through pymodbus's synchronous client, on the register map in ``fixtures/devices/cage.toml``.

The cage may be real or :class:`~drivers.cage.emulator.CageEmulator`; the driver cannot tell.
Ports are URLs: ``tcp://HOST:PORT`` for Modbus TCP, anything else is a serial port for Modbus RTU
(a device path, a pty, or a pyserial URL such as ``socket://`` or ``rfc2217://``).

Hot path, once per control tick (two Modbus requests)::

    cage.command_field(b_T)     # one write of polarity, three set points and a new heartbeat
    sample = cage.take_field()  # one read: field (T, cage axes), its device time, valid, currents

Start-up::

    cage = CageHost.open("tcp://127.0.0.1:5020", calibration=CageCalibration.load(path))
    cage.enable()               # a heartbeat, then output_enable = 1; DriverError names any interlock

Every command refreshes the heartbeat; a host that stops commanding for longer than the cage's
``heartbeat_timeout_s`` must call :meth:`CageHost.heartbeat`, or the cage switches off.

``counters``: ``sent`` and ``received`` (Modbus frames), ``rejected`` (exception responses),
``timeouts`` (requests that got no answer).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from drivers.cage.calibration import CageCalibration
from drivers.cage.registers import RegisterMap, load_map
from drivers.endpoint import Endpoint
from drivers.errors import ConnectError, DeviceTimeoutError, DriverError, EncodeError, ProtocolError

__all__ = ["CageHost", "CageStatus", "FieldSample", "parse_url"]

_EXCEPTIONS = {1: "illegal function", 2: "illegal address", 3: "illegal value", 4: "device failure",
               6: "device busy", 11: "gateway target did not respond"}

#: Input registers a control tick reads: currents, field, its time, status and interlocks.
_TICK_COUNT = 16


@dataclass(frozen=True)
class FieldSample:
    """One magnetometer reading at the test position.

    Attributes:
        b_T: field in cage axes (T).
        t_s: device time of the sample (s since the cage powered up).
        valid: the sample exists and lies within the magnetometer's range.
        currents_A: coil currents read in the same request (A, signed by the relays).
        output_on: the supplies' outputs are on.
        interlocks: names of the interlocks engaged at that instant (empty when none).
    """

    b_T: tuple[float, float, float]
    t_s: float
    valid: bool
    currents_A: tuple[float, float, float]
    output_on: bool
    interlocks: frozenset[str]


@dataclass(frozen=True)
class CageStatus:
    """Everything the cage reports. ``values`` holds every register decoded, by map name."""

    output_on: bool
    currents_A: tuple[float, float, float]
    setpoints_A: tuple[float, float, float]
    polarity_request_negative: tuple[bool, bool, bool]
    relay_negative: tuple[bool, bool, bool]
    interlocks: frozenset[str]
    last_interlock: str
    last_interlock_axis: str
    temperatures_C: tuple[float, float, float]
    voltages_V: tuple[float, float, float]
    field: FieldSample
    values: dict[str, Any]

    @property
    def limits(self) -> dict[str, float]:
        """The cage's fixed limits, by register name."""
        keys = ("current_limit_A", "slew_limit_A_s", "heartbeat_timeout_s", "temperature_trip_C",
                "temperature_reset_C", "polarity_dead_time_s", "zero_current_A")
        return {k: self.values[k] for k in keys}


def parse_url(url: str) -> tuple[str, str, int | None]:
    """``("tcp", host, port)`` for ``tcp://HOST:PORT``, else ``("rtu", url, None)``.

    Raises ValueError naming the URL for a TCP URL without a valid port.
    """
    if url.startswith("tcp://"):
        rest = url[len("tcp://"):].rstrip("/")
        host, sep, port = rest.rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise ValueError(f"Modbus URL {url!r} is not allowed; give tcp://HOST:PORT with a port 1-65535, or a "
                             "serial port for RTU.")
        return "tcp", host.strip("[]"), int(port)
    if not url:
        raise ValueError("the Modbus URL is empty; give tcp://HOST:PORT or a serial port for RTU.")
    return "rtu", url, None


class CageHost(Endpoint):
    """Host driver of the cage on an open pymodbus sync client.

    Args:
        client: a connected ``ModbusTcpClient`` or ``ModbusSerialClient``; closed by :meth:`close` only
            when ``owns_client`` (as with :meth:`open`).
        device_id: the cage's Modbus unit id.
        calibration: coil constants and lab field, for :meth:`command_field`.
        regmap: the register map (default: the ICD).
        name: how errors name this device.
    """

    def __init__(self, client: Any, *, device_id: int = 1, calibration: CageCalibration | None = None,
                 regmap: RegisterMap | None = None, name: str = "cage", owns_client: bool = False,
                 where: str = "") -> None:
        self.client = client
        self.device_id = device_id
        self.calibration = calibration
        self.map = regmap if regmap is not None else load_map()
        self.name = name
        self.where = where
        self._owns_client = owns_client
        self._closed = False
        self._heartbeat = 0
        self.counters: dict[str, int] = {"sent": 0, "received": 0, "rejected": 0, "timeouts": 0}
        self.last_rx = b""
        self.last_tx = b""
        h = self.map.holding
        self._setpoint = [h[f"current_setpoint_{a}_A"] for a in self.map.axes]
        self._i_max = self._setpoint[0].si_range[1]
        self._n_input = self.map.size("input")
        self._n_holding = self.map.size("holding")

    @classmethod
    def open(cls, url: str, *, baudrate: int = 115200, timeout_s: float = 1.0, device_id: int = 1,
             calibration: CageCalibration | None = None, regmap: RegisterMap | None = None,
             name: str = "cage") -> CageHost:
        """Connect to the cage at ``url`` (``tcp://HOST:PORT`` or a serial port for RTU).

        Raises ValueError for a malformed URL and ConnectError when the port cannot be opened.
        """
        kind, host, port = parse_url(url)
        box: dict[str, CageHost] = {}

        def trace(sending: bool, data: bytes) -> bytes:
            drv = box.get("host")
            if drv is not None:
                drv._trace(sending, data)
            return data

        if kind == "tcp":
            client = ModbusTcpClient(host, port=port, timeout=timeout_s, retries=0, trace_packet=trace)
        else:
            client = ModbusSerialClient(host, baudrate=baudrate, timeout=timeout_s, retries=0, trace_packet=trace)
        if not client.connect():
            client.close()
            raise ConnectError(f"{name}: cannot connect to the cage at {url} (is it powered and listening?).",
                               where=url, reason="connect failed")
        drv = cls(client, device_id=device_id, calibration=calibration, regmap=regmap, name=name,
                  owns_client=True, where=url)
        box["host"] = drv
        return drv

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"CageHost({self.where or self.client!r}, {state}, counters={self.counters})"

    def _release(self) -> None:
        if self._owns_client:
            self.client.close()

    def _trace(self, sending: bool, data: bytes) -> None:
        if sending:
            self.counters["sent"] += 1
            self.last_tx = bytes(data)
        else:
            self.counters["received"] += 1
            self.last_rx = bytes(data)

    # -- requests --------------------------------------------------------------------------------

    def _call(self, what: str, fn, *args, **kwargs):
        if self._closed:
            raise DriverError(f"{self.name}: the cage driver is closed; open a new one.")
        try:
            rsp = fn(*args, device_id=self.device_id, **kwargs)
        except ModbusIOException as exc:
            self.counters["timeouts"] += 1
            timeout = float(getattr(self.client.comm_params, "timeout_connect", 0.0) or 0.0)
            raise DeviceTimeoutError(f"{self.name}: no answer to {what} from {self.where or 'the cage'} within "
                                     f"{timeout:g} s ({exc}).", device=self.name, awaited=what,
                                     timeout_s=timeout) from None
        except ConnectionException as exc:
            raise ConnectError(f"{self.name}: lost the connection to {self.where or 'the cage'} during {what} "
                               f"({exc}).", where=self.where, reason=str(exc)) from None
        except ModbusException as exc:
            raise DriverError(f"{self.name}: {what} failed: {exc}") from None
        if rsp.isError():
            self.counters["rejected"] += 1
            code = getattr(rsp, "exception_code", None)
            raise ProtocolError(f"{self.name}: the cage refused {what} with exception {code} "
                                f"({_EXCEPTIONS.get(code, 'unknown')})", frame_hex=self.last_rx.hex(),
                                expected="a normal response", computed=f"exception {code}")
        return rsp

    def read_registers(self, table: str, address: int, count: int) -> list[int]:
        """Raw words of ``table`` (``"holding"``/``"input"``) from ``address``."""
        fn = self.client.read_holding_registers if table == "holding" else self.client.read_input_registers
        rsp = self._call(f"a read of {table} registers {address}..{address + count - 1}", fn, address, count=count)
        if len(rsp.registers) != count:
            raise ProtocolError(f"{self.name}: short read of {table} registers", frame_hex=self.last_rx.hex(),
                                expected=count, computed=len(rsp.registers))
        return list(rsp.registers)

    def write_registers(self, address: int, words: Sequence[int]) -> None:
        """Write raw holding-register words from ``address`` (function 16)."""
        self._call(f"a write of holding registers {address}..{address + len(words) - 1}",
                   self.client.write_registers, address, list(words))

    def write(self, values: dict[str, Any]) -> None:
        """Write holding registers by name (SI values; they must be contiguous)."""
        start, words = self.map.encode("holding", values)
        self.write_registers(start, words)

    # -- commands --------------------------------------------------------------------------------

    def _next_heartbeat(self) -> int:
        self._heartbeat = (self._heartbeat + 1) & 0xFFFF
        return self._heartbeat

    def heartbeat(self) -> None:
        """Write a new heartbeat value (the cage's watchdog needs a change every timeout)."""
        self.write({"heartbeat": self._next_heartbeat()})

    def enable(self, on: bool = True) -> CageStatus:
        """Switch the outputs on (after a fresh heartbeat) or off; returns the status read back.

        Raises DriverError naming the interlocks when the cage stays off after an enable.
        """
        if on:
            self.heartbeat()
        self.write({"output_enable": 1 if on else 0})
        st = self.status()
        if on and not st.output_on:
            why = ", ".join(sorted(st.interlocks)) or "no interlock reported"
            raise DriverError(f"{self.name}: the cage did not switch its outputs on; interlocks: {why} (last: "
                              f"{st.last_interlock} on {st.last_interlock_axis}).")
        return st

    def command_currents(self, currents_A: Sequence[float]) -> None:
        """Drive signed coil currents (A, per axis): polarity, set points and a new heartbeat in one write.

        Raises EncodeError (a ValueError) naming the axis when a current is not finite or beyond
        what the register carries; currents above the cage's limit are accepted and held at the
        limit by the cage (interlock ``current_limit_*``).
        """
        try:
            cur = [float(c) for c in currents_A]
        except (TypeError, ValueError):
            raise EncodeError(f"currents_A = {currents_A!r} is not allowed; give three numbers in A.") from None
        if len(cur) != 3:
            raise EncodeError(f"currents_A = {currents_A!r} is not allowed; give three numbers in A (x, y, z).")
        polarity = 0
        words = []
        for a, (c, reg) in enumerate(zip(cur, self._setpoint, strict=True)):
            if not math.isfinite(c) or abs(c) > self._i_max:
                raise EncodeError(f"current {self.map.axes[a]} = {c!r} A is not allowed; the set point carries "
                                  f"-{self._i_max:g}..{self._i_max:g} A.")
            if c < 0:
                polarity |= 1 << a
            words += reg.encode(abs(c))
        self.write_registers(1, [polarity, *words, self._next_heartbeat()])

    def command_field(self, b_T: Sequence[float]) -> np.ndarray:
        """Make ``b_T`` (T, cage axes) at the test position through the calibration; returns the
        currents commanded (A). Raises DriverError without a calibration."""
        if self.calibration is None:
            raise DriverError(f"{self.name}: command_field needs a calibration (coil constants and lab field); "
                              "give calibration= or run drivers.cage.calibration.run_calibration first.")
        currents = self.calibration.currents_for(b_T)
        self.command_currents(currents)
        return currents

    def safe_off(self) -> None:
        """Zero the set points and switch the outputs off."""
        self.command_currents((0.0, 0.0, 0.0))
        self.write({"output_enable": 0})

    # -- telemetry -------------------------------------------------------------------------------

    def _field(self, v: dict[str, Any]) -> FieldSample:
        ax = self.map.axes
        return FieldSample(
            b_T=tuple(v[f"field_{a}_T"] for a in ax),  # type: ignore[arg-type]
            t_s=v["field_time_s"],
            valid="field_valid" in v["status"],
            currents_A=tuple(v[f"current_{a}_A"] for a in ax),  # type: ignore[arg-type]
            output_on="output_on" in v["status"],
            interlocks=v["interlocks"],
        )

    def take_field(self) -> FieldSample:
        """The newest magnetometer reading, with its device time tag and valid flag (one read)."""
        return self._field(self.map.decode("input", 0, self.read_registers("input", 0, _TICK_COUNT)))

    def status(self) -> CageStatus:
        """Everything: one read of all input registers and one of the holding registers."""
        v = self.map.decode("input", 0, self.read_registers("input", 0, self._n_input))
        hv = self.map.decode("holding", 0, self.read_registers("holding", 0, self._n_holding))
        v.update(hv)
        ax = self.map.axes
        req = hv["polarity_request"]
        return CageStatus(
            output_on="output_on" in v["status"],
            currents_A=tuple(v[f"current_{a}_A"] for a in ax),  # type: ignore[arg-type]
            setpoints_A=tuple(v[f"current_setpoint_{a}_A"] for a in ax),  # type: ignore[arg-type]
            polarity_request_negative=tuple(f"negative_{a}" in req for a in ax),  # type: ignore[arg-type]
            relay_negative=tuple(f"relay_negative_{a}" in v["status"] for a in ax),  # type: ignore[arg-type]
            interlocks=v["interlocks"],
            last_interlock=v["last_interlock"],
            last_interlock_axis=v["last_interlock_axis"],
            temperatures_C=tuple(v[f"coil_temperature_{a}_C"] for a in ax),  # type: ignore[arg-type]
            voltages_V=tuple(v[f"supply_voltage_{a}_V"] for a in ax),  # type: ignore[arg-type]
            field=self._field(v),
            values=v,
        )
