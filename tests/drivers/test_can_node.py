"""A magnetorquer and four reaction wheels on one CAN bus (drivers/can_node.py): each node takes its own frames,
ignores the others', recognises its own echoes, and counts as rejected only frames addressed to it that it cannot
accept. On python-can's ``virtual`` bus, the stand's ``stand_loopback`` bus, and ``udp_multicast`` (which hands every
frame back to its sender) inside a private network namespace."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import can
import pytest

from drivers.can_bus import open_bus
from drivers.magnetorquer.codec import DipoleCommand, MagnetorquerCodec
from drivers.magnetorquer.emulator import EmulatorConfig, MagnetorquerEmulator
from drivers.magnetorquer.host import MagnetorquerBoard
from drivers.reaction_wheel.codec import ReactionWheelCodec
from drivers.reaction_wheel.emulator import ReactionWheelEmulator
from drivers.reaction_wheel.host import ReactionWheelHost
from tests.stand.processes import REPO, private_netns_ok, stand_env

WHEELS = 4
DIPOLE_A_m2 = (0.1, -0.05, 0.02)
TORQUE_Nm = (1e-4, -2e-4, 3e-4)  # wheels 0..2; wheel 3 is set to SPEED
SPEED_rad_s = 50.0
#: A bounded wait for frames in flight (udp_multicast delivers through the kernel); never an assertion on time.
SETTLE_S = 5.0


class SharedBus:
    """One magnetorquer and four wheels, each emulated, each with its host, every endpoint on its own handle of one
    bus ``interface``/``channel``."""

    def __init__(self, interface: str, channel: str) -> None:
        self._buses: list[can.BusABC] = []
        self.mtq_emu = MagnetorquerEmulator(self._open(interface, channel), lambda t: (2e-5, -1e-5, 3e-5),
                                            EmulatorConfig(mag_noise_T=0.0))
        self.mtq = MagnetorquerBoard(self._open(interface, channel))
        self.wheel_emus = [ReactionWheelEmulator(self._open(interface, channel), lambda t, n=n: 10.0 * (n + 1),
                                                 wheel=n) for n in range(WHEELS)]
        self.wheels = [ReactionWheelHost(self._open(interface, channel), wheel=n) for n in range(WHEELS)]
        self.emulators = [self.mtq_emu, *self.wheel_emus]
        self.hosts = [self.mtq, *self.wheels]
        self.nodes = [*self.emulators, *self.hosts]

    def _open(self, interface: str, channel: str) -> can.BusABC:
        bus = open_bus(interface, channel)
        self._buses.append(bus)
        return bus

    def settle(self, t_s: float, until) -> None:
        """Drain every node at ``t_s`` until ``until()`` holds (every frame sent has reached every node), at most
        ``SETTLE_S``."""
        deadline = time.monotonic() + SETTLE_S
        while True:
            for e in self.emulators:
                e.receive(t_s)
            for h in self.hosts:
                h.poll()
            if until() or time.monotonic() > deadline:
                return
            time.sleep(0.001)

    def all_delivered(self) -> bool:
        """Every node has read every frame of every other node (and of its own, where the bus hands it back)."""
        sent = sum(n.counters["sent"] for n in self.nodes)
        echoes = any(n.counters["echoes"] for n in self.nodes)
        return all(n.counters["received"] == sent - (0 if echoes else n.counters["sent"]) for n in self.nodes)

    def close(self) -> None:
        for node in self.nodes:
            node.close()
        for bus in self._buses:
            bus.shutdown()


def shared_bus_run(interface: str, channel: str) -> dict:
    """Command every node once, let the devices answer, and report what each node counted."""
    rig = SharedBus(interface, channel)
    try:
        rig.mtq.set_mode("DIPOLE")
        rig.mtq.command_dipole(DIPOLE_A_m2, 1.0)
        seqs = [rig.wheels[n].command_torque(TORQUE_Nm[n]) for n in range(3)]
        seqs.append(rig.wheels[3].command_speed(SPEED_rad_s))
        rig.settle(0.0, lambda: all(e.counters["received"] >= 2 for e in rig.emulators))
        for e in rig.emulators:
            e.publish(0.0)  # first publication: sample, status (with the applied commands), heartbeat
        rig.settle(0.0, rig.all_delivered)
        return {
            "counters": {n.name: dict(n.counters) for n in rig.nodes},
            "rejected": {n.name: n.rejected_frames for n in rig.nodes},
            "delivered": rig.all_delivered(),
            "dipole": list(rig.mtq_emu.dipole_xyz_at(0.5)),
            "wheel_commands": [list(e.command_at(0.5)) for e in rig.wheel_emus],
            "mtq_board_rejected": rig.mtq.latest_counters.rejected_frames,
            "mtq_board_accepted": rig.mtq.latest_counters.commands_accepted,
            "wheel_status": [[w.latest_status.rejected_frames, w.latest_status.seq_ack, w.latest_status.mode]
                             for w in rig.wheels],
            "wheel_seqs": seqs,
            "samples": [rig.mtq.take_sample() is not None] + [w.take_speed() is not None for w in rig.wheels],
        }
    finally:
        rig.close()


def check_shared_bus(got: dict, echoes: bool) -> None:
    assert got["delivered"], got["counters"]
    assert got["rejected"] == dict.fromkeys(got["rejected"], 0), got["counters"]
    counters = got["counters"]
    # Every command applied, as commanded.
    assert counters["mtq emulator"]["commands_accepted"] == 2
    lsb = EmulatorConfig().dipole_lsb_A_m2
    assert got["dipole"] == pytest.approx([round(m / lsb) * lsb for m in DIPOLE_A_m2])
    tq_lsb = ReactionWheelCodec(0).dbc.signal_scale("RW_TORQUE_CMD", "torque")
    for n in range(3):
        assert got["wheel_commands"][n] == pytest.approx(["TORQUE", TORQUE_Nm[n], 0.0], abs=tq_lsb)
    w_lsb = ReactionWheelCodec(0).speed_lsb_rad_s
    assert got["wheel_commands"][3][0] == "SPEED"
    assert got["wheel_commands"][3][2] == pytest.approx(SPEED_rad_s, abs=w_lsb)
    for n in range(WHEELS):
        assert counters[f"rw{n} emulator"]["commands_accepted"] == 1
        assert got["wheel_status"][n] == [0, got["wheel_seqs"][n], "SPEED" if n == 3 else "TORQUE"]
    # The boards' own counters, as the ICDs report them: nothing refused.
    assert got["mtq_board_rejected"] == 0 and got["mtq_board_accepted"] == 2
    assert all(got["samples"])
    # Each node read the others' frames as foreign traffic and, where the bus hands frames back, its own as echoes.
    sent = sum(c["sent"] for c in counters.values())
    for name, c in counters.items():
        assert c["echoes"] == (c["sent"] if echoes else 0), name
        taken = c["received"] - c["echoes"] - c["foreign"]
        assert taken > 0 and c["foreign"] > 0, name
        assert c["received"] == sent - (0 if echoes else c["sent"]), name


@pytest.mark.parametrize("interface", ["virtual", "stand_loopback"])
def test_a_magnetorquer_and_four_wheels_share_one_bus_without_rejecting_each_other(interface):
    check_shared_bus(shared_bus_run(interface, f"shared-{interface}"), echoes=False)


@pytest.mark.parametrize(("frame_id", "data", "target", "key"), [
    (0x092, bytes(8), "mtq emulator", "rejected_unknown_id"),  # in the board's command block, not assigned by its ICD
    (MagnetorquerCodec().id_mag_sample, bytes(3), "mtq", "rejected_length"),  # a sample cut short
    (ReactionWheelCodec(2).ids["RW_TORQUE_CMD"], bytes(2), "rw2 emulator", "rejected_length"),
    (ReactionWheelCodec(1).ids["RW_SPEED_TLM"], bytes(5), "rw1", "rejected_length"),
])
def test_a_frame_a_node_cannot_accept_is_counted_once_by_that_node_only(frame_id, data, target, key):
    rig = SharedBus("stand_loopback", f"bad-{frame_id:x}-{len(data)}")
    rogue = open_bus("stand_loopback", f"bad-{frame_id:x}-{len(data)}")
    try:
        rogue.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False))
        rig.settle(0.0, lambda: all(n.counters["received"] == 1 for n in rig.nodes))
        for node in rig.nodes:
            assert node.counters["received"] == 1, node.name
            if node.name == target:
                assert node.rejected_frames == node.counters[key] == 1
                assert f"{frame_id:03X}#" in node.last_rejected
            else:
                assert node.rejected_frames == 0 and node.counters["foreign"] == 1, node.name
    finally:
        rogue.shutdown()
        rig.close()


def test_an_emulated_board_reports_a_rejection_in_its_own_counters():
    rig = SharedBus("stand_loopback", "board-counters")
    rogue = open_bus("stand_loopback", "board-counters")
    try:
        fid, payload = MagnetorquerCodec().encode(DipoleCommand((0.1, 0.0, 0.0), 1.0))
        rogue.send(can.Message(arbitration_id=fid, data=payload[:5], is_extended_id=False))
        rig.settle(0.0, lambda: rig.mtq_emu.counters["received"] == 1)
        rig.mtq_emu.publish(0.0)
        rig.settle(0.0, lambda: rig.mtq.latest_counters is not None)
        assert rig.mtq.latest_counters.rejected_frames == 1 and rig.mtq.rejected_frames == 0
    finally:
        rogue.shutdown()
        rig.close()


def test_a_magnetorquer_and_four_wheels_share_udp_multicast_with_echoes_in_a_private_namespace(tmp_path):
    if not private_netns_ok():
        pytest.skip("unshare --net with loopback multicast routing is not permitted here (needs root or user "
                    "namespaces); udp_multicast is never used in the default namespace")
    group = "224.0.0.171"  # link-local: stays on the private namespace's loopback
    code = ("import json; from tests.drivers.test_can_node import shared_bus_run; "
            f"print(json.dumps(shared_bus_run('udp_multicast', '{group}')))")
    proc = subprocess.run(["unshare", "--net", "sh", "-c",
                           f"ip link set lo up && ip route add 224.0.0.0/4 dev lo && {sys.executable} -c \"{code}\""],
                          env=stand_env(), cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    check_shared_bus(json.loads(proc.stdout.strip().splitlines()[-1]), echoes=True)
