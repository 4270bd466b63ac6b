"""The serial devices share one framing layer (drivers/framing.py), one ICD codec layer
(drivers/icd_codec.py) and one host/emulator base (drivers/serial_port.py): the star tracker, the gyro
and the sun sensor each add only their ICD and their behaviour (issue 23)."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

import drivers.datagram as datagram
import drivers.framing as framing
import drivers.icd_codec as icd_codec
import drivers.star_tracker.codec as st_codec
import drivers.star_tracker.slip as st_slip
from drivers.errors import EncodeError
from drivers.gyro.codec import GyroCodec, GyroRate, SetTime
from drivers.serial_port import SerialHost, SerialServer
from drivers.star_tracker.emulator import StarTrackerEmulator
from drivers.star_tracker.host import StarTrackerHost
from drivers.sun_sensor.emulator import SunSensorEmulator
from drivers.sun_sensor.host import SunSensorHost

ROOT = Path(__file__).resolve().parents[2]


def test_one_crc16_one_field_spec_one_message_spec() -> None:
    assert st_codec.crc16 is datagram.crc16 is framing.crc16
    assert st_codec.FieldSpec is datagram.FieldSpec is icd_codec.FieldSpec
    assert st_codec.MessageSpec is datagram.MessageSpec is icd_codec.MessageSpec
    assert not hasattr(st_codec.StarTrackerCodec, "_wire_value")
    assert not hasattr(datagram.DatagramCodec, "_wire_value")
    # CRC-16/CCITT-FALSE check value
    assert framing.crc16(b"123456789") == 0x29B1


def test_the_tracker_and_the_datagram_devices_share_host_and_emulator_bases() -> None:
    assert issubclass(StarTrackerHost, SerialHost) and issubclass(SunSensorHost, SerialHost)
    assert issubclass(StarTrackerEmulator, SerialServer) and issubclass(SunSensorEmulator, SerialServer)
    for cls in (StarTrackerHost, datagram.DatagramHost):
        assert "_reopen" not in vars(cls)
    for cls in (StarTrackerEmulator, datagram.DatagramEmulator):
        assert "run" not in vars(cls)


def test_slip_framer_reads_a_buffer_and_says_what_it_consumed() -> None:
    assert st_slip.take_frame is framing.take_frame and st_slip.SlipDecoder is framing.SlipDecoder
    one = framing.escape(bytes([0x21, 0xC0, 0xDB, 0x05]))
    assert one == bytes([0xC0, 0x21, 0xDB, 0xDC, 0xDB, 0xDD, 0x05, 0xC0])
    buf = bytearray(one + one[:3])
    assert framing.take_frame(buf, 16) == (1, None, None)  # the opening END (idle fill)
    del buf[:1]
    consumed, body, error = framing.take_frame(buf, 16)
    assert (consumed, body, error) == (len(one) - 1, bytes([0x21, 0xC0, 0xDB, 0x05]), None)
    del buf[:consumed]
    assert framing.take_frame(buf, 16) == (1, None, None)
    del buf[:1]
    assert framing.take_frame(buf, 16) == (0, None, None)  # a partial frame: feed more


def test_datagram_encode_refuses_a_huge_int_with_one_sentence() -> None:
    # today's main raised a bare OverflowError from math.isfinite(10**400)
    with pytest.raises(EncodeError, match=r"gyro SET_TIME\.time = 10{400} is outside the field: allowed 0 to"):
        GyroCodec().encode(SetTime(10**400))


def test_datagram_encode_refuses_a_flag_that_is_not_a_flag() -> None:
    codec = GyroCodec()
    good = GyroRate((0.01, -0.02, 0.03), True, False, False, False, False, True, 7, 0.0005, 123_456)
    assert codec.decode(codec.encode(good)).valid is True
    # today's main encoded any truthy object as a set bit
    with pytest.raises(EncodeError, match=r"gyro RATE\.status: valid = 'no' is not a flag; allowed: True or False"):
        codec.encode(replace(good, valid="no"))


def test_shared_serial_modules_have_no_function_above_complexity_15() -> None:
    files = ["drivers/framing.py", "drivers/icd_codec.py", "drivers/datagram.py", "drivers/serial_port.py",
             "drivers/star_tracker/codec.py", "drivers/star_tracker/host.py", "drivers/star_tracker/emulator.py"]
    out = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--isolated", "--select", "C901", "--config",
         "lint.mccabe.max-complexity = 15", "--output-format", "json", *files],
        cwd=ROOT, capture_output=True, text=True, timeout=120, check=False,
    )
    assert out.returncode in (0, 1), out.stderr
    assert json.loads(out.stdout) == []
