"""Host driver: the flight code (or the stand) talking to a standalone magnetometer over CAN.

The unit may be real or :class:`~drivers.magnetometer.emulator.MagnetometerEmulator`; the driver cannot tell.
Its sample API is the magnetorquer board's (``take_sample``, ``read_sample``, :class:`MagSample` with ``b_T``,
``valid``, ``coil_active``, ``seq``), so a B-dot written against one reads the other.

Receiving never raises on bad traffic (:class:`drivers.can_node.CanNode`): other nodes' frames are counted in
``foreign``, our own commands looped back by ``udp_multicast`` in ``echoes``.
"""

from __future__ import annotations

from typing import Any

import can

from drivers.can_node import CanHost
from drivers.errors import DeviceTimeoutError
from drivers.magnetometer.codec import Heartbeat, MagnetometerCodec, MagSample, ModeCommand, Status

__all__ = ["MagnetometerHost"]


class MagnetometerHost(CanHost):
    """Host-side driver of the standalone magnetometer on an open python-can ``bus``.

    Attributes:
        latest_sample, latest_status, last_heartbeat: the newest decoded message of each kind, or None.
        counters: the node's (:data:`drivers.can_node.NODE_COUNTERS`), then ``samples`` (MAG_FIELD frames taken).
    """

    _closed_text = "the magnetometer driver is closed; open a new one."
    _mode_command = ModeCommand
    _latest = {MagSample: "latest_sample", Status: "latest_status", Heartbeat: "last_heartbeat"}
    _sample_type, _sample_attr = MagSample, "latest_sample"
    latest_sample: MagSample | None
    latest_status: Status | None
    last_heartbeat: Heartbeat | None

    def __init__(self, bus: can.BusABC, codec: MagnetometerCodec | None = None, name: str = "mag", *,
                 owns_bus: bool = False) -> None:
        codec = codec if codec is not None else MagnetometerCodec()
        self._init_host(bus, codec, name, codec.unit_tx_ids, codec.unit_rx_ids, owns_bus)

    @classmethod
    def open(cls, interface: str, channel: str, *, codec: MagnetometerCodec | None = None, name: str = "mag",
             **bus_kwargs: Any) -> MagnetometerHost:
        """Open ``interface``/``channel`` (ConnectError on failure); :meth:`close` shuts that bus down."""
        from drivers.can_bus import open_bus

        return cls(open_bus(interface, channel, **bus_kwargs), codec=codec, name=name, owns_bus=True)

    def __repr__(self) -> str:
        return f"MagnetometerHost(name={self.name!r}, {'closed' if self._closed else 'open'}, counters={self.counters})"

    #: ``take_sample() -> MagSample | None``: poll, then the newest sample not returned yet, else None.
    take_sample = CanHost._newest_unseen

    def read_sample(self, timeout_s: float) -> MagSample:
        """A sample newer than the last one returned, waiting up to ``timeout_s`` (DeviceTimeoutError after)."""
        def timeout() -> DeviceTimeoutError:
            return DeviceTimeoutError(
                f"{self.name}: no new MAG_FIELD (id 0x{self.codec.id_sample:03X}) within {timeout_s:g} s on "
                f"{self.bus.channel_info} ({self.counters['samples']} received so far). Is the unit powered and in "
                "mode MEASURE?", device=self.name, awaited="a new MAG_FIELD", timeout_s=timeout_s)

        return self._wait_newest(timeout_s, timeout)
