"""The CAN node's fast paths give what its general paths give (drivers/can_node.py, drivers/can_loopback.py).

On the stand's ``stand_loopback`` bus a node pops the bus's ready queue and sorts each frame inline, and sends
through ``send_data`` without a sender's ``can.Message``; on any other bus (or a loopback bus with filters) it reads
with ``recv(0)``, sorts with ``_handle`` and sends ``data_frame``. Both are fed the same frames here, good and bad,
and must count, reject and apply exactly the same. No timing is measured.
"""

from __future__ import annotations

import uuid

import can
import numpy as np
import pytest

from drivers.can_bus import data_frame, open_bus
from drivers.errors import ProtocolError
from drivers.magnetorquer.codec import MagnetorquerCodec
from drivers.magnetorquer.emulator import COMMAND_BLOCK, MagnetorquerEmulator
from drivers.magnetorquer.host import MagnetorquerBoard
from drivers.reaction_wheel.codec import ReactionWheelCodec
from drivers.reaction_wheel.emulator import ReactionWheelEmulator
from drivers.reaction_wheel.host import ReactionWheelHost

#: A python-can acceptance filter that passes every frame: the bus then has filters, so a node on it reads with recv.
PASS_ALL = [{"can_id": 0, "can_mask": 0}]
#: Frames sent between two drains (several per drain, as on the stand's tick).
BATCH = 7


def _channel() -> str:
    return f"paths-{uuid.uuid4().hex}"


def _frames(ids, lengths, seed: int) -> list[can.Message]:
    """For every id: payloads of random bytes of the ICD length (some with a value outside an enum table), a payload
    one byte short, a remote frame, a 29-bit frame; plus error frames and ids of no one. Deterministic."""
    rng = np.random.default_rng(seed)
    out = []
    for frame_id in sorted(ids):
        n = lengths.get(frame_id, 8)
        for _ in range(12):
            out.append(can.Message(arbitration_id=frame_id, data=rng.integers(0, 256, n, dtype=np.uint8).tobytes(),
                                   is_extended_id=False))
        out.append(can.Message(arbitration_id=frame_id, data=bytes(max(n - 1, 0)), is_extended_id=False))
        out.append(can.Message(arbitration_id=frame_id, is_remote_frame=True, dlc=n, is_extended_id=False))
        out.append(can.Message(arbitration_id=frame_id, data=bytes(n), is_extended_id=True))
    out.append(can.Message(arbitration_id=0x7FF, data=bytes(8), is_extended_id=False))
    out.append(can.Message(arbitration_id=0x000, is_error_frame=True, is_extended_id=False))
    order = rng.permutation(len(out))
    return [out[i] for i in order]


def _state(node) -> dict:
    """What a node counted, why it last rejected, its newest messages and its emulated state."""
    got = {"counters": dict(node.counters), "last_rejected": node.last_rejected,
           "board": dict(node._board) if node._board is not None else None}
    got.update({k: v for k, v in vars(node).items() if k.startswith(("latest_", "last_"))})
    if hasattr(node, "dipole_xyz_at"):
        got.update(mode=node.mode, dipole=node.dipole_xyz_at(0.05), until=node._on_until_s)
    if hasattr(node, "command_at"):
        got.update(command=node.command_at(0.05), seq_ack=node._seq_ack)
    return got


NODES = {
    "mtq emulator": (lambda bus: MagnetorquerEmulator(bus, lambda t: (2e-5, -1e-5, 3e-5)),
                     lambda c: c.board_rx_ids | COMMAND_BLOCK | c.board_tx_ids, MagnetorquerCodec),
    "mtq host": (MagnetorquerBoard, lambda c: c.board_tx_ids | c.board_rx_ids, MagnetorquerCodec),
    "rw2 emulator": (lambda bus: ReactionWheelEmulator(bus, lambda t: 10.0, wheel=2),
                     lambda c: c.all_wheel_ids, lambda: ReactionWheelCodec(2)),
    "rw2 host": (lambda bus: ReactionWheelHost(bus, wheel=2), lambda c: c.all_wheel_ids,
                 lambda: ReactionWheelCodec(2)),
}


def _plain(msg: can.Message) -> bool:
    return not (msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame)


def _drive(make, frames, interface: str, via_send_data: bool = False, **bus_kwargs) -> tuple[dict, object]:
    """Send ``frames`` in batches to a new node on its own channel, draining after each batch; the node's state.
    ``via_send_data``: the standard-id data frames go through the loopback bus's ``send_data`` (queued as tuples)."""
    channel = _channel()
    sender, bus = open_bus(interface, channel), open_bus(interface, channel, **bus_kwargs)
    node = make(bus)
    try:
        for k in range(0, len(frames), BATCH):
            for msg in frames[k:k + BATCH]:
                if via_send_data and _plain(msg):
                    sender.send_data(msg.arbitration_id, bytes(msg.data))
                else:
                    sender.send(msg)
            n = node._drain(0.01 * k)
            assert n == len(frames[k:k + BATCH])
        return _state(node), getattr(bus, "rx_ready", None)
    finally:
        node.close()
        bus.shutdown()
        sender.shutdown()


@pytest.mark.parametrize("name", list(NODES))
@pytest.mark.parametrize("general", ["stand_loopback with a filter", "virtual"])
@pytest.mark.parametrize("sent", ["send", "send_data"])
def test_the_inline_drain_of_a_loopback_queue_sorts_and_applies_as_the_general_path(name, general, sent):
    make, ids, codec = NODES[name]
    c = codec()
    frames = _frames(ids(c), c.lengths, seed=sum(map(ord, name)))
    fast, ready = _drive(make, frames, "stand_loopback", via_send_data=sent == "send_data")
    assert ready is not None  # the node popped the ready queue
    if general == "virtual":
        slow, ready = _drive(make, frames, "virtual")
    else:
        slow, ready = _drive(make, frames, "stand_loopback", can_filters=PASS_ALL)
        assert ready is None  # a bus with filters offers no ready queue: the node used recv and _handle
    assert fast == slow
    counted = fast["counters"]
    # The frames really covered every way of sorting a frame.
    assert counted["foreign"] > 0 and counted["rejected_length"] > 0 and counted["rejected_other"] > 0
    assert counted["received"] == len(frames)
    assert counted["received"] > counted["foreign"] + counted["rejected_length"] + counted["rejected_other"]


@pytest.mark.parametrize("preserve", [True, False])
def test_send_data_delivers_what_send_of_a_data_frame_delivers(preserve):
    channel = _channel()
    sender = open_bus("stand_loopback", channel, receive_own_messages=True, preserve_timestamps=preserve)
    plain = open_bus("stand_loopback", channel, rx_queue_size=2)
    picky = open_bus("stand_loopback", channel, can_filters=[{"can_id": 0x0A0, "can_mask": 0x7FF}])
    buses = (sender, plain, picky)
    fields = ("arbitration_id", "is_extended_id", "is_remote_frame", "is_error_frame", "channel", "dlc", "data",
              "is_fd", "is_rx", "bitrate_switch", "error_state_indicator")
    frames = [(0x0A0, bytes(range(8))), (0x090, b"\x01\x02"), (0x2A0, bytes(8))]
    try:
        def collect(send):
            overflow = plain.rx_overflow
            for frame_id, payload in frames:
                send(frame_id, payload)
            got = [[(m.timestamp if preserve else None, *(getattr(m, f) for f in fields))
                    for m in iter(lambda b=b: b.recv(0.0), None)] for b in buses]
            return got, plain.rx_overflow - overflow

        fast, overflow_fast = collect(sender.send_data)
        slow, overflow_slow = collect(lambda i, p: sender.send(data_frame(i, p)))
    finally:
        for b in buses:
            b.shutdown()
    assert fast == slow and overflow_fast == overflow_slow == 1
    assert [len(x) for x in fast] == [3, 2, 1]  # own echo of each, a queue of two, the filter's one id


def test_the_ready_queue_is_offered_only_without_filters_and_while_open():
    channel = _channel()
    sender, a, b = (open_bus("stand_loopback", channel) for _ in range(3))
    try:
        for k in range(5):
            sender.send(can.Message(arbitration_id=0x100 + k, data=bytes([k]), is_extended_id=False))
        popped = []
        while a.rx_ready:
            popped.append(a.rx_ready.popleft())
        received = list(iter(lambda: b.recv(0.0), None))
        assert [(m.arbitration_id, m.data) for m in popped] == [(m.arbitration_id, m.data) for m in received]
        a.set_filters([{"can_id": 0x100, "can_mask": 0x7FF}])
        assert a.rx_ready is None
        a.set_filters(None)
        assert a.rx_ready is not None
        a.shutdown()
        assert a.rx_ready is None
    finally:
        for bus in (sender, a, b):
            bus.shutdown()


@pytest.mark.parametrize("codec", [MagnetorquerCodec, lambda: ReactionWheelCodec(3)])
def test_each_payload_decoder_gives_what_decode_gives(codec):
    c = codec()
    rng = np.random.default_rng(23)
    offered = c.payload_decoders()
    assert set(offered) <= set(c.lengths) and offered
    bad = 0
    for frame_id, (unpack, build) in offered.items():
        for _ in range(200):
            data = rng.integers(0, 256, c.lengths[frame_id], dtype=np.uint8).tobytes()
            try:
                expected = c.decode(frame_id, data)
            except ProtocolError:
                with pytest.raises(ValueError):
                    build(unpack(data))
                bad += 1
            else:
                assert build(unpack(data)) == expected
    assert bad > 0  # some payloads held a value outside an enum table
