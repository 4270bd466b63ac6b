"""Host driver: the stand (or a test) talking to a magnetorquer board over CAN.

The board may be real (``socketcan`` on a bench) or :class:`~drivers.magnetorquer.emulator.
MagnetorquerEmulator` on a python-can ``virtual`` bus: the driver cannot tell, and has no
``if emulated`` branch.

Hot path, once per control tick::

    sample = board.take_sample()       # drain what arrived (never blocks); the newest MagSample once, or None
    board.command_dipole(m, 0.2)       # one MTQ_DIPOLE_CMD frame

(``take_sample`` polls by itself; call :meth:`MagnetorquerBoard.poll` on ticks that take no sample
to keep status, counters and heartbeat fresh.)

Receiving never raises on bad traffic (:class:`drivers.can_node.CanNode`): frames of other nodes
(a wheel on the same bus, commands from another host, 29-bit ids) are counted in ``foreign`` and
ignored, our own commands looped back by ``udp_multicast`` in ``echoes``; board frames of a wrong
length or with an undecodable value are counted in :attr:`MagnetorquerBoard.counters` and dropped.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import can

from drivers.can_node import CanHost
from drivers.errors import DeviceTimeoutError
from drivers.magnetorquer.codec import (
    Counters,
    DipoleCommand,
    Heartbeat,
    MagnetorquerCodec,
    MagSample,
    ModeCommand,
    Status,
)

if TYPE_CHECKING:  # pragma: no cover
    from collections.abc import Sequence

__all__ = ["MagnetorquerBoard"]


class MagnetorquerBoard(CanHost):
    """Host-side driver of the magnetorquer board on an open python-can ``bus``.

    Args:
        bus: an open :class:`can.BusABC`. The caller keeps ownership unless ``owns_bus`` is true
            (as with :meth:`open`), in which case :meth:`close` shuts it down.
        codec: a :class:`MagnetorquerCodec` (default: one built on the ICD in ``fixtures/``).
        name: how errors and logs name this device.

    Attributes:
        latest_sample, latest_status, latest_counters, last_heartbeat: the newest decoded message
            of each kind, or None.
        counters: the node's (:data:`drivers.can_node.NODE_COUNTERS`), then ``samples`` (MAG_SAMPLE
            frames accepted).
    """

    def __init__(
        self,
        bus: can.BusABC,
        codec: MagnetorquerCodec | None = None,
        name: str = "mtq",
        *,
        owns_bus: bool = False,
    ) -> None:
        codec = codec if codec is not None else MagnetorquerCodec()
        # set_mode's seq is echoed in latest_counters.mode_seq_ack once applied.
        self._init_host(bus, codec, name, codec.board_tx_ids, codec.board_rx_ids, owns_bus)
        self._sample_id = codec.id_mag_sample

    @classmethod
    def open(
        cls,
        interface: str,
        channel: str,
        *,
        codec: MagnetorquerCodec | None = None,
        name: str = "mtq",
        **bus_kwargs: Any,
    ) -> MagnetorquerBoard:
        """Open ``interface``/``channel`` (ConnectError on failure) and drive the board there.

        The driver owns that bus: :meth:`close` shuts it down.
        """
        from drivers.can_bus import open_bus

        return cls(open_bus(interface, channel, **bus_kwargs), codec=codec, name=name, owns_bus=True)

    # -- lifecycle ------------------------------------------------------------------------------

    _closed_text = "the magnetorquer driver is closed; open a new one."
    _mode_command = ModeCommand
    _latest = {MagSample: "latest_sample", Status: "latest_status", Counters: "latest_counters",
               Heartbeat: "last_heartbeat"}
    _sample_type, _sample_attr = MagSample, "latest_sample"
    latest_sample: MagSample | None
    latest_status: Status | None
    latest_counters: Counters | None
    last_heartbeat: Heartbeat | None

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"MagnetorquerBoard(name={self.name!r}, {state}, counters={self.counters})"

    # -- commands -------------------------------------------------------------------------------

    def command_dipole(self, dipole_A_m2: Sequence[float], duration_s: float) -> None:
        """Send MTQ_DIPOLE_CMD: drive ``dipole_A_m2`` (board axes) for ``duration_s`` (0 = coils off).

        Raises EncodeError (a ValueError) naming the field when a value is outside what the ICD can
        carry (|m| <= 0.32767 A m^2 per axis, 0 <= duration <= 65.535 s): clip to the board's rating
        before calling. The board itself saturates at its rating, keeping the sign.
        """
        mx, my, mz = dipole_A_m2
        self.send(DipoleCommand((float(mx), float(my), float(mz)), float(duration_s)))

    # -- receiving ------------------------------------------------------------------------------

    #: ``take_sample() -> MagSample | None``: poll, then the newest MagSample if it has not been returned yet, else
    #: None. When several samples arrived since the last call only the newest is returned (its ``seq`` tells how
    #: many were skipped).
    take_sample = CanHost._newest_unseen

    def read_sample(self, timeout_s: float) -> MagSample:
        """Return a sample newer than the last one returned, waiting up to ``timeout_s`` (monotonic).

        Raises DeviceTimeoutError naming the device, what was awaited and the timeout.
        """
        return self._wait_newest(timeout_s, lambda: self._timeout("a new MAG_SAMPLE", timeout_s))

    def _timeout(self, awaited: str, timeout_s: float) -> DeviceTimeoutError:
        last = self.latest_sample
        tail = (
            "no sample has been received yet"
            if last is None
            else f"the last one had seq {last.seq} ({self.counters['samples']} received so far)"
        )
        return DeviceTimeoutError(
            f"{self.name}: no {awaited} (id 0x{self._sample_id:03X}) within {timeout_s:g} s on "
            f"{self.bus.channel_info}; {tail}. Is the board powered and publishing?",
            device=self.name,
            awaited=awaited,
            timeout_s=timeout_s,
        )
