"""The Modbus functions the cage answers, checked with raw frames built here (not by pymodbus's client)
over TCP and over RTU on a socat pty pair: the functions the map document lists are applied and answered
normally (function 6 too: applied and echoed), every other function gets exception 1 and applies nothing,
and another unit id gets no answer at all. Issue 22 item 7: function 6 was applied and answered exception 1;
functions 7, 8, 17 and 43 were answered although the map says any other function gets exception 1; a refused
enable counted as a heartbeat trip."""

from __future__ import annotations

import os
import re
import socket
import struct
import subprocess
import time
from pathlib import Path

import pytest
import serial

from drivers.cage.emulator import CageEmulator
from drivers.cage.model import CageConfig, CageModel
from tests.oracles import require_tool

DOC = Path(__file__).resolve().parents[2] / "docs" / "cage_register_map.md"
HR_ENABLE, HR_HEARTBEAT, IR_STATUS, IR_HEARTBEAT_TRIPS, IR_LAST = 0, 5, 14, 20, 16
STATUS_OUTPUT_ON, LAST_HEARTBEAT_LOST = 1, 3

# Requests of functions outside the map, each a whole PDU (function code first). Several would write
# (coils, mask write, read/write multiple, a diagnostics restart): none may change anything.
OTHER_FUNCTIONS = {
    1: bytes([1, 0, 0, 0, 1]),
    2: bytes([2, 0, 0, 0, 1]),
    5: bytes([5, 0, 0, 0xFF, 0]),
    7: bytes([7]),
    8: bytes([8, 0, 0, 0x12, 0x34]),  # diagnostics: return query data
    11: bytes([11]),
    12: bytes([12]),
    15: bytes([15, 0, 0, 0, 1, 1, 1]),
    17: bytes([17]),
    22: bytes([22, 0, 0, 0, 0, 0, 1]),  # mask write: output_enable = 1
    23: bytes([23, 0, 0, 0, 1, 0, 0, 0, 1, 2, 0, 1]),  # read/write: output_enable = 1
    24: bytes([24, 0, 0]),
    43: bytes([0x2B, 0x0E, 1, 0]),  # read device identification
    65: bytes([65, 1, 2, 3]),  # user-defined, unknown to pymodbus
}


def _crc(frame: bytes) -> bytes:
    crc = 0xFFFF
    for byte in frame:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return struct.pack("<H", crc)


class TcpLink:
    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=2.0)
        self.tid = 0

    def ask(self, pdu: bytes, unit: int = 1, timeout_s: float = 2.0) -> bytes | None:
        self.tid += 1
        self.sock.settimeout(timeout_s)
        self.sock.sendall(struct.pack(">HHHB", self.tid, 0, len(pdu) + 1, unit) + pdu)
        try:
            head = self._exactly(7)
        except TimeoutError:
            return None
        tid, pid, length, uid = struct.unpack(">HHHB", head)
        assert (tid, pid, uid) == (self.tid, 0, unit)
        return self._exactly(length - 1)

    def _exactly(self, n: int) -> bytes:
        out = b""
        while len(out) < n:
            chunk = self.sock.recv(n - len(out))
            assert chunk, "the emulator closed the connection"
            out += chunk
        return out

    def close(self) -> None:
        self.sock.close()


class RtuLink:
    def __init__(self, path: str) -> None:
        self.port = serial.Serial(path, 115200, timeout=0.05)

    def ask(self, pdu: bytes, unit: int = 1, timeout_s: float = 2.0) -> bytes | None:
        frame = bytes([unit]) + pdu
        self.port.reset_input_buffer()
        self.port.write(frame + _crc(frame))
        got = b""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:  # an RTU answer ends with silence: read until a whole CRC-good frame
            got += self.port.read(256)
            if len(got) >= 4 and _crc(got[:-2]) == got[-2:]:
                assert got[0] == unit
                return got[1:-2]
        assert not got, f"a partial or corrupt answer: {got.hex()}"
        return None

    def close(self) -> None:
        self.port.close()


@pytest.fixture(params=["tcp", "rtu"])
def link(request, tmp_path):
    emu = CageEmulator(clock=None)
    socat = None
    try:
        if request.param == "tcp":
            _, port = emu.serve_tcp("127.0.0.1", 0)
            lk = TcpLink(port)
        else:
            # skipped on a developer's machine without socat, a failure under CI (tests.oracles.require_tool)
            socat_path = require_tool("socat", "socat")
            a, b = tmp_path / "cage-dev", tmp_path / "cage-host"
            socat = subprocess.Popen([socat_path, f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            deadline = time.monotonic() + 5.0
            while not (os.path.exists(a) and os.path.exists(b)) and time.monotonic() < deadline:
                time.sleep(0.02)
            assert a.exists() and b.exists(), "socat did not create its pty pair"
            emu.serve_rtu(str(a), baudrate=115200)
            lk = RtuLink(str(b))
        yield emu, lk
        lk.close()
    finally:
        emu.close()
        if socat is not None:
            socat.terminate()
            socat.wait(5)


def _holding(lk) -> list[int]:
    rsp = lk.ask(bytes([3, 0, 0, 0, 6]))
    assert rsp is not None and rsp[:2] == bytes([3, 12])
    return list(struct.unpack(">6H", rsp[2:]))


def _input(lk, address: int) -> int:
    rsp = lk.ask(bytes([4, 0, address, 0, 1]))
    assert rsp is not None and rsp[:2] == bytes([4, 2])
    return struct.unpack(">H", rsp[2:])[0]


def test_the_functions_checked_here_are_those_of_the_document():
    line = next(li for li in DOC.read_text().splitlines() if li.startswith("- Function codes:"))
    listed = {int(n) for n in re.findall(r"(\d+) (?:read|write)", line)}
    assert listed == {3, 4, 6, 16}
    assert listed.isdisjoint(OTHER_FUNCTIONS)
    assert "Any other function code gets exception 1" in line


def test_function_6_is_applied_and_echoed(link):
    emu, lk = link
    for address, value in ((HR_HEARTBEAT, 7), (HR_ENABLE, 1)):
        pdu = bytes([6]) + struct.pack(">HH", address, value)
        assert lk.ask(pdu) == pdu  # the normal answer to function 6 is an echo of the request
    assert _holding(lk) == [1, 0, 0, 0, 0, 7]
    assert _input(lk, IR_STATUS) & STATUS_OUTPUT_ON and emu.model.output_on
    assert lk.ask(bytes([6, 0, 0, 0, 2])) == bytes([0x86, 3])  # a value the register does not accept
    assert lk.ask(bytes([6, 0, 100, 0, 1])) == bytes([0x86, 2])  # outside the map
    assert _holding(lk) == [1, 0, 0, 0, 0, 7]
    assert emu.counters["rejected"] == 2


def test_every_other_function_gets_exception_1_and_applies_nothing(link):
    emu, lk = link
    before_holding = _holding(lk)
    before_events = repr(emu.model.events)
    for fc, pdu in OTHER_FUNCTIONS.items():
        assert lk.ask(pdu) == bytes([0x80 | fc, 1]), f"function {fc}"
    assert _holding(lk) == before_holding == [0, 0, 0, 0, 0, 0]
    assert not emu.model.output_on and repr(emu.model.events) == before_events
    assert emu.counters["rejected"] == len(OTHER_FUNCTIONS)


def test_another_unit_id_gets_no_answer_whatever_the_function(link):
    emu, lk = link
    for pdu in (bytes([3, 0, 0, 0, 1]), OTHER_FUNCTIONS[8], OTHER_FUNCTIONS[43], bytes([6, 0, 0, 0, 1])):
        assert lk.ask(pdu, unit=7, timeout_s=0.3) is None
    assert emu.counters["ignored_other_id"] == 4 and emu.counters["rejected"] == 0
    assert _holding(lk) == [0, 0, 0, 0, 0, 0]


def test_a_refused_enable_is_not_a_heartbeat_trip(link):
    emu, lk = link
    emu.step(2.0)  # no heartbeat was ever written: an enable now is refused
    assert lk.ask(bytes([16, 0, 0, 0, 1, 2, 0, 1])) == bytes([16, 0, 0, 0, 1])
    assert not _input(lk, IR_STATUS) & STATUS_OUTPUT_ON
    assert _input(lk, IR_LAST) == LAST_HEARTBEAT_LOST  # the register says why it stayed off ...
    assert _input(lk, IR_HEARTBEAT_TRIPS) == 0  # ... but nothing that was on switched off


def test_heartbeat_trips_counts_outputs_switched_off_only():
    m = CageModel(CageConfig(heartbeat_timeout_s=0.5))
    m.advance(1.0)
    for _ in range(3):  # three refused enables
        assert m.write(HR_ENABLE, [1]) == 0 and not m.output_on
    assert m.events.heartbeat_trips == 0 and m.heartbeat_lost
    m.write(HR_HEARTBEAT, [1])
    m.write(HR_ENABLE, [1])
    assert m.output_on and not m.heartbeat_lost
    m.advance(2.0)  # the heartbeat stops: one real trip
    assert not m.output_on and m.events.heartbeat_trips == 1
