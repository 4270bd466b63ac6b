"""Host driver: the stand (or flight software) driving one reaction wheel over CAN.

The wheel may be real (``socketcan`` on a bench) or :class:`~drivers.reaction_wheel.emulator.
ReactionWheelEmulator` on a python-can ``virtual`` bus: the driver cannot tell. Several wheels share
one bus, each with its own number (node 0x20 + n)::

    wheel = ReactionWheelHost(bus, wheel=2)
    wheel.command_torque(1.5e-3)          # RW_TORQUE_CMD (mode TORQUE), once per control tick
    tlm = wheel.take_speed()              # the newest unseen RW_SPEED_TLM, or None (never blocks)
    tlm.speed_rad_s, tlm.valid, tlm.seq

Receiving never raises on bad traffic (:class:`drivers.can_node.CanNode`): frames of other nodes
(the other wheels, a magnetorquer, 29-bit ids) are counted in ``foreign`` and ignored, our own
commands looped back by ``udp_multicast`` in ``echoes``; this wheel's frames of a wrong length or
with an undecodable value are counted and dropped.
"""

from __future__ import annotations

from typing import Any

import can

from drivers.can_node import CanHost
from drivers.errors import DeviceTimeoutError
from drivers.reaction_wheel.codec import (
    Heartbeat,
    ModeCommand,
    ReactionWheelCodec,
    Status,
    WheelSpeed,
    new_speed_command,
    new_torque_command,
)

__all__ = ["ReactionWheelHost"]


class ReactionWheelHost(CanHost):
    """Host-side driver of wheel ``wheel`` on an open python-can ``bus``.

    Args:
        bus: an open :class:`can.BusABC`; the caller keeps it unless ``owns_bus`` (as with :meth:`open`).
        wheel: the wheel number, 0..15 (node 0x20 + wheel).
        codec: a :class:`ReactionWheelCodec` for that wheel (default: built on the ICD in ``fixtures/``).
        name: how errors name this device.

    Attributes:
        latest_speed, latest_status, last_heartbeat: the newest decoded message of each kind, or None.
        counters: the node's (:data:`drivers.can_node.NODE_COUNTERS`), then ``samples`` (RW_SPEED_TLM
            accepted).
    """

    def __init__(self, bus: can.BusABC, wheel: int = 0, codec: ReactionWheelCodec | None = None,
                 name: str | None = None, *, owns_bus: bool = False) -> None:
        codec = codec if codec is not None else ReactionWheelCodec(wheel)
        if codec.wheel != wheel:
            raise ValueError(f"reaction wheel host: wheel = {wheel} but the codec is for wheel {codec.wheel}.")
        self._init_host(bus, codec, name or f"rw{wheel}", codec.wheel_tx_ids, codec.wheel_rx_ids, owns_bus)
        self._tlm_id = codec.ids["RW_SPEED_TLM"]

    @classmethod
    def open(cls, interface: str, channel: str, *, wheel: int = 0, codec: ReactionWheelCodec | None = None,
             name: str | None = None, **bus_kwargs: Any) -> ReactionWheelHost:
        """Open ``interface``/``channel`` (ConnectError on failure) and drive wheel ``wheel`` there;
        :meth:`close` shuts that bus down."""
        from drivers.can_bus import open_bus

        return cls(open_bus(interface, channel, **bus_kwargs), wheel, codec, name, owns_bus=True)

    _closed_text = "the reaction wheel driver is closed; open a new one."
    _mode_command = ModeCommand
    _latest = {WheelSpeed: "latest_speed", Status: "latest_status", Heartbeat: "last_heartbeat"}
    latest_speed: WheelSpeed | None
    latest_status: Status | None
    last_heartbeat: Heartbeat | None
    _sample_type, _sample_attr = WheelSpeed, "latest_speed"

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"ReactionWheelHost(wheel={self.codec.wheel}, {state}, counters={self.counters})"

    # -- commands -------------------------------------------------------------------------------

    def command_torque(self, torque_Nm: float, timeout_s: float = 0.0) -> int:
        """Send RW_TORQUE_CMD (mode TORQUE): motor torque on the rotor about the spin axis, N m.

        ``timeout_s`` > 0 makes the wheel go IDLE that long after it unless commanded again (0 = hold). Returns the
        sequence number, echoed in ``latest_status.seq_ack`` once applied. EncodeError (a ValueError)
        beyond what the field carries (+-1 N m); the wheel itself clips at its rating.
        """
        seq = self._next_seq()
        self.send(new_torque_command(float(torque_Nm), seq, float(timeout_s)))
        return seq

    def command_speed(self, speed_rad_s: float, timeout_s: float = 0.0) -> int:
        """Send RW_SPEED_CMD (mode SPEED): wheel speed about the spin axis, rad/s; returns the seq."""
        seq = self._next_seq()
        self.send(new_speed_command(float(speed_rad_s), seq, float(timeout_s)))
        return seq

    # -- receiving ------------------------------------------------------------------------------

    #: ``take_speed() -> WheelSpeed | None``: poll, then the newest RW_SPEED_TLM not returned before
    #: (``.speed_rad_s``, ``.torque_Nm``, ``.valid``, ``.seq``), or None.
    take_speed = CanHost._newest_unseen

    def read_speed(self, timeout_s: float) -> WheelSpeed:
        """Wait up to ``timeout_s`` (monotonic) for a RW_SPEED_TLM newer than the last one returned.

        Raises DeviceTimeoutError naming the device, what was awaited and the timeout.
        """
        c = self.codec
        return self._wait_newest(timeout_s, lambda: DeviceTimeoutError(
            f"{self.name}: no RW_SPEED_TLM (id 0x{self._tlm_id:03X}) within {timeout_s:g} s on "
            f"{self.bus.channel_info}; {self.counters['samples']} received so far. Is wheel {c.wheel} "
            f"(node 0x{c.node:02X}) powered and on this bus?",
            device=self.name, awaited="RW_SPEED_TLM", timeout_s=timeout_s,
        ))
