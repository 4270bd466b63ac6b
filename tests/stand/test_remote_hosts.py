"""A scenario does not make the stand reach beyond this machine (issue 22 item 12): a cage ``url`` must name a
loopback host and a ``udp_multicast`` CAN channel a link- or host-local group, unless the operator allows the
address with ``stand run --allow-remote``. The refusal comes before t = 0 and before anything connects: the
Modbus client and the CAN bus are replaced here by fakes that record what would have been opened, and any socket
connect to a non-loopback address fails the test, so no packet leaves this machine."""

from __future__ import annotations

import ipaddress
import socket

import pytest

from drivers.cage.calibration import CageCalibration
from drivers.cage.model import CageConfig
from stand import scenario as scenario_mod
from stand.cli import main
from stand.devices import check_network, is_local_multicast, is_loopback_host
from stand.errors import ScenarioError


@pytest.fixture
def cage_hw(tmp_path) -> list[str]:
    """``--set`` items for a hardware cage with a valid calibration file (so only the URL can stop it)."""
    cal = CageCalibration.from_config(CageConfig()).save(tmp_path / "cal.json")
    return ["--set", "devices.cage.link=hardware", "--set", f"devices.cage.calibration={cal}"]


@pytest.fixture(autouse=True)
def nothing_leaves_this_machine(monkeypatch):
    """Every connect goes through here: one to an address beyond loopback fails the test before it is made."""
    real_connect = socket.socket.connect

    def connect(self, address):
        host = address[0] if isinstance(address, tuple) else ""
        if self.family in (socket.AF_INET, socket.AF_INET6) and not ipaddress.ip_address(host).is_loopback:
            pytest.fail(f"a connect to {address!r} was attempted")
        return real_connect(self, address)

    monkeypatch.setattr(socket.socket, "connect", connect)


@pytest.fixture
def opened(monkeypatch):
    """Fakes for the Modbus TCP client and the CAN bus: they record what the stand would open, and fail to open."""
    seen: list[tuple] = []

    class FakeModbusTcpClient:
        def __init__(self, host, port=502, **_kw):
            seen.append(("modbus", host, port))

        def connect(self):
            return False

        def close(self):
            pass

    def fake_open_bus(interface, channel, *a, **kw):
        seen.append(("can", interface, channel))
        raise OSError("not opened in this test")

    monkeypatch.setattr("drivers.cage.host.ModbusTcpClient", FakeModbusTcpClient)
    monkeypatch.setattr("drivers.can_bus.open_bus", fake_open_bus)
    return seen


@pytest.mark.parametrize("url", ["tcp://ANY_HOST:502", "tcp://192.0.2.7:502", "tcp://10.0.0.1:5020",
                                 "tcp://localhost.example:502", "tcp://0.0.0.0:502", "tcp://[2001:db8::1]:502"])
def test_a_cage_url_beyond_this_machine_is_refused_before_anything_connects(url, opened, cage_hw, tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["run", "detumble_cage", *cage_hw, "--set", f"devices.cage.url={url}", "--speed", "1",
                 "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert f"devices[0].url = '{url}'" in err and "--allow-remote" in err and "Traceback" not in err
    assert opened == [] and not out.exists()


def test_allow_remote_lets_the_named_host_through_and_no_other(opened, cage_hw, tmp_path, capsys):
    url = "tcp://192.0.2.7:502"
    code = main(["run", "detumble_cage", *cage_hw, "--set", f"devices.cage.url={url}", "--speed", "1",
                 "--allow-remote", "198.51.100.1", "--out", str(tmp_path / "a"), "--no-progress"])
    assert code == 2 and "devices[0].url" in capsys.readouterr().err and opened == []
    code = main(["run", "detumble_cage", *cage_hw, "--set", f"devices.cage.url={url}", "--speed", "1",
                 "--allow-remote", "192.0.2.7", "--out", str(tmp_path / "b"),
                 "--no-progress"])
    err = capsys.readouterr().err
    # the check let it through: the (fake) client was asked for that host, and failed to connect
    assert opened == [("modbus", "192.0.2.7", 502)] and code == 2 and "cannot connect to the cage" in err


@pytest.mark.parametrize("group", ["239.74.163.2", "224.0.1.1", "ff15:7079:7468:6f6e:6465:6d6f:6d63:6173",
                                   "ff0e::1", "192.0.2.7"])
def test_a_udp_multicast_group_beyond_the_link_is_refused_before_the_bus_opens(group, opened, tmp_path, capsys):
    code = main(["run", "detumble_cage", "--set", "devices.mtq.link=hardware", "--set",
                 "devices.mtq.interface=udp_multicast", "--set", f"devices.mtq.channel={group}", "--speed", "1",
                 "--out", str(tmp_path / "run"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert f"devices[1].channel = '{group}'" in err and f"--allow-remote {group}" in err
    assert opened == []


def _specs(*sets: str):
    return scenario_mod.load("detumble_cage", list(sets)).devices


@pytest.mark.parametrize("url", ["tcp://127.0.0.1:5020", "tcp://127.8.9.10:502", "tcp://localhost:502",
                                 "tcp://[::1]:502"])
def test_loopback_cage_urls_pass_the_check(url):
    check_network(_specs("devices.cage.link=hardware", f"devices.cage.url={url}", "devices.cage.calibration=c"))


def test_link_and_host_local_groups_pass_and_allowed_groups_pass():
    for group in ("224.0.0.1", "224.0.0.251", "ff02::1", "ff12::8000:1", "ff01::2"):
        assert is_local_multicast(group), group
        check_network(_specs("devices.mtq.link=hardware", "devices.mtq.interface=udp_multicast",
                             f"devices.mtq.channel={group}"))
    specs = _specs("devices.mtq.link=hardware", "devices.mtq.interface=udp_multicast",
                   "devices.mtq.channel=239.74.163.2")
    with pytest.raises(ScenarioError, match="devices\\[1\\].channel"):
        check_network(specs)
    check_network(specs, ["239.74.163.2"])
    assert not is_local_multicast("127.0.0.1") and not is_loopback_host("127.example") and is_loopback_host("::1")
