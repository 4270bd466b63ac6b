"""drivers.can_frames, the one source of a CAN node's drain and send and of the in-process bus's delivery of a data
frame: its compiled twin (Cython, compiled_paths) and the plain module count, sort, reject, deliver and raise the
same, on the same frames (good ones, wrong lengths, undecodable values, remote, error and 29-bit frames, other
nodes' ids, echoes, receivers with filters, a full queue). `.ci/run` runs this file again with ``STAND_NATIVE=0``.
No timing is measured."""

from __future__ import annotations

import functools
import math
import uuid

import can
import pytest

import compiled_paths
import drivers.can_frames as plain
from drivers.can_loopback import LoopbackBus
from drivers.can_messages import CanCodec
from drivers.can_node import CanHost, CanNode
from drivers.errors import DriverError
from tests.drivers.test_can_node_paths import BATCH, NODES, _frames, _plain, _state
from tests.oracles import build_fixtures, require_compiled

compiled, build = build_fixtures("drivers.can_frames")


def _bus_class(module):
    return type("Bus", (LoopbackBus,), {"send_data": module.send_data})


def _run_node(module, name: str) -> tuple[dict, list]:
    """A node of ``NODES`` on a bus whose methods are ``module``'s: fed every kind of frame in batches (standard data
    frames through send_data, the rest through send), draining after each; then it answers (an emulator publishes,
    a host sends a mode command). Its state, and what its peer received of its answers."""
    make, ids, codec = NODES[name]
    c = codec()
    frames = _frames(ids(c), c.lengths, seed=sum(map(ord, name)))
    channel = f"frames-{uuid.uuid4().hex}"
    bus_class = _bus_class(module)
    sender, bus = bus_class(channel), bus_class(channel)
    node = make(bus)
    node._drain = module.drain.__get__(node)  # this build's drain, send and encode, on this instance only
    node._send = module.send.__get__(node)
    node._encode = functools.partial(module.encode, node.codec)
    seen: list = []
    if isinstance(node, CanHost):  # and its take, observed
        node._take = functools.partial(module.take_observed, node, functools.partial(module.host_take, node))
        node._observers = (seen.append,)
    try:
        for k in range(0, len(frames), BATCH):
            for msg in frames[k:k + BATCH]:
                if _plain(msg):
                    sender.send_data(msg.arbitration_id, bytes(msg.data))
                else:
                    sender.send(msg)
            assert node._drain(0.01 * k) == len(frames[k:k + BATCH])
        if hasattr(node, "publish"):
            for k in range(40):
                node.publish(0.05 * k)
        else:
            node.set_mode(1, reset_counters=True)
        answered = [(m.arbitration_id, bytes(m.data), m.is_rx, m.dlc) for m in iter(lambda: sender.recv(0.0), None)]
        return _state(node), answered, seen
    finally:
        node.close()
        bus.shutdown()
        sender.shutdown()


@pytest.mark.parametrize("name", list(NODES))
def test_a_node_drains_and_sends_the_same_on_both_builds(name, compiled):
    expected, answered, seen = _run_node(plain, name)
    assert _run_node(compiled, name) == (expected, answered, seen)
    assert ("host" in name) == bool(seen)
    counted = expected["counters"]
    assert counted["foreign"] > 0 and counted["rejected_length"] > 0 and counted["rejected_other"] > 0
    assert answered and counted["sent"] == len(answered)


def _deliver(module, preserve: bool, channel: str) -> tuple[list, list]:
    """Frames sent with ``module``'s send_data to an echoing sender, a plain receiver, one of two frames, one with a
    filter and a listen-only one of a few ids: what each received (its fields) and the overflow counts."""
    bus_class = _bus_class(module)
    picky = [{"can_id": 0x0A0, "can_mask": 0x7FF}]
    buses = (bus_class(channel, receive_own_messages=True, preserve_timestamps=preserve), bus_class(channel),
             bus_class(channel, rx_queue_size=2), bus_class(channel, can_filters=picky),
             bus_class(channel, accept_ids=frozenset({0x0A0, 0x2A0}), listen_only=True))
    fields = ("arbitration_id", "is_extended_id", "is_remote_frame", "is_error_frame", "channel", "dlc", "data",
              "is_fd", "is_rx", "bitrate_switch", "error_state_indicator")
    try:
        for frame_id, payload in ((0x0A0, bytes(range(8))), (0x090, bytearray(b"\x01\x02")), (0x2A0, bytes(8)),
                                  (0x123, b"")):
            buses[0].send_data(frame_id, payload)
        got = [[(m.timestamp if preserve else None, *(getattr(m, f) for f in fields))
                for m in iter(lambda b=b: b.recv(0.0), None)] for b in buses]
        return got, [b.rx_overflow for b in buses]
    finally:
        for b in buses:
            b.shutdown()


@pytest.mark.parametrize("preserve", [True, False])
def test_the_bus_delivers_the_same_on_both_builds(preserve, compiled):
    channel = f"frames-{uuid.uuid4().hex}"  # the frames name it: the same for both runs, one after the other
    expected = _deliver(plain, preserve, channel)
    assert _deliver(compiled, preserve, channel) == expected
    assert [len(x) for x in expected[0]] == [4, 4, 2, 1, 2] and expected[1] == [0, 0, 2, 0, 0]


class _Failing(can.BusABC):
    """A bus whose send fails (a CanError), with no fast paths: the node sends data_frame through send."""

    channel_info = "failing bus"

    def __init__(self):  # noqa: D107 - no python-can set-up needed
        self._is_shutdown = False

    def send(self, msg, timeout=None):
        raise can.CanOperationError("the adapter is gone")

    def _recv_internal(self, timeout):
        return None, False


def test_both_builds_raise_the_same_errors(build):
    from drivers.reaction_wheel.codec import TorqueCommand
    from drivers.reaction_wheel.host import ReactionWheelHost

    host = ReactionWheelHost(_Failing(), wheel=1)
    with pytest.raises(DriverError, match=r"^rw1: cannot send TorqueCommand on failing bus: the adapter is gone$"):
        build.send(host, TorqueCommand(1e-3, 1, 0.0))
    assert host.counters["sent"] == 0
    host.close()
    with pytest.raises(DriverError, match="rw1: the reaction wheel driver is closed; open a new one."):
        build.drain(host)
    with pytest.raises(DriverError, match="closed"):
        build.send(host, TorqueCommand(1e-3, 1, 0.0))
    bus = _bus_class(build)(f"frames-{uuid.uuid4().hex}")
    bus.shutdown()
    with pytest.raises(can.CanOperationError, match="Cannot send on stand_loopback channel .*: the bus is shut down"):
        bus.send_data(0x100, b"\x00")


def _encode_errors(module) -> list[str]:
    from drivers.magnetorquer.codec import MagnetorquerCodec
    from drivers.reaction_wheel.codec import ReactionWheelCodec, Status, TorqueCommand

    out = []
    wheel, mtq = ReactionWheelCodec(2), MagnetorquerCodec()
    for codec, msg in ((wheel, TorqueCommand(5.0, 1, 0.0)), (wheel, TorqueCommand("x", 1, 0.0)),
                       (wheel, TorqueCommand(1e-3, 300, 0.0)), (wheel, TorqueCommand(1e-3, 2**80, 0.0)),
                       (wheel, Status("IDLE", temperature_C=math.nan)), (wheel, 1.0), (mtq, "not a message"),
                       (wheel, TorqueCommand(1e-3, 1, 0.25))):
        try:
            out.append(module.encode(codec, msg))
        except Exception as exc:  # noqa: BLE001 - the type and the sentence are what is compared
            out.append((type(exc).__name__, str(exc)))
    return out


def test_both_builds_encode_and_refuse_the_same(compiled):
    expected = _encode_errors(plain)
    assert _encode_errors(compiled) == expected
    assert [x[0] for x in expected[:-1]] == ["EncodeError"] * 5 + ["TypeError", "EncodeError"]
    assert expected[-1][0] == 0x0B2 and len(expected[-1][1]) == 8


def test_the_node_and_the_bus_run_the_build_compiled_paths_chose():
    chosen = compiled_paths.load("drivers.can_frames")
    assert CanNode._drain is chosen.drain and CanNode._send is chosen.send and LoopbackBus.send_data is chosen.send_data
    assert CanHost._take is chosen.host_take and CanCodec.encode is chosen.encode
    expected = "compiled" if compiled_paths.native_allowed() else "python"
    if expected == "compiled":
        require_compiled("drivers.can_frames")
    assert compiled_paths.active()["drivers.can_frames"] == expected
