"""What the CAN kinds share (the magnetorquer board, the magnetometer, the reaction wheels): the table keys of their
adapter (:class:`CanSpec`); telemetry of an emulated or hardware device seen beside the flight code
(:class:`ObservedCan`); and, served to a flight computer outside, the emulator on a
:class:`drivers.can_bus.ServedBus` link, whose rejections (the node's and the link's,
:class:`drivers.can_node.ServedNode`) the stand watches, and whose activity is the commands it accepted
(:class:`ServedCan`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drivers.can_node import ServedNode
from stand.devices import DeviceSpec, Rejections


@dataclass(frozen=True)
class CanSpec(DeviceSpec):
    """The adapter of a CAN device: a python-can interface and channel (``stand.devices.can_endpoint``)."""

    interface: str = "stand_loopback"
    channel: str = ""


class ObservedCan:
    """Mixin for a device whose telemetry is its periodic sample (id ``_sample_id``) as a listen-only node of the
    stand sees it, beside the flight code and never through its driver. The device keeps ``self._buses`` (buses it
    shut down on :meth:`close`), ``self.spec`` (a :class:`CanSpec`) and ``self.name``."""

    observer = None
    _buses: list
    spec: Any
    name: str
    close: Callable[[], None]  # the device's

    def _open_emulated(self, make_emulator: Callable[[Any], Any], make_host: Callable[[Any], Any], codec: Any,
                       sample_id: int) -> None:
        """The emulator and the host driver on two handles of the in-process bus, telemetry from what the emulator
        sends (everything closed again if a part cannot be built)."""
        from drivers.can_bus import open_bus

        spec = self.spec
        try:
            self._buses.append(open_bus(spec.interface, spec.channel))
            self._buses.append(open_bus(spec.interface, spec.channel))
            self.emulator = make_emulator(self._buses[0])
            self._observe_sent(self.emulator, codec, sample_id)
            self.host = make_host(self._buses[1])
        except BaseException:
            self.close()
            raise

    def _observe_sent(self, emulator: Any, codec: Any, sample_id: int) -> None:
        """Telemetry of an in-process link: what the emulator put on the bus, decoded by the stand as a receiver
        decodes it. A bus handle of its own would see the same frames, each copied once more (``_observe`` does
        that where no emulator is in the stand)."""
        from drivers.can_observer import CanObserver

        self.observer = CanObserver(None, codec, frozenset({sample_id}), f"{self.name} observer", owns_bus=False)
        self._sample_id = sample_id
        emulator.add_sent_observer(self.observer.feed)

    def _observe(self, codec: Any, sample_id: int) -> None:
        """On an adapter every handle of which sees the whole bus (``SHARED_INTERFACES``), the stand's listen-only
        node (opened before anything is sent; the device closed again if it cannot be). A serial-line adapter is
        one stream the host driver holds alone: no observer there."""
        from drivers.can_observer import SHARED_INTERFACES, open_observer

        spec = self.spec
        if spec.interface not in SHARED_INTERFACES:
            return
        try:
            self.observer = open_observer(spec.interface, spec.channel, codec, frozenset({sample_id}),
                                          f"{self.name} observer")
        except BaseException:
            self.close()
            raise
        self._sample_id = sample_id

    def _observed_samples(self) -> int:
        self.observer.poll()  # the watch asks once a second of sim time, telemetry may ask less often
        return self.observer.seen[self._sample_id]


class ServedCan:
    """Mixin for a served CAN device with ``self.emulator`` (a :class:`drivers.can_node.CanDevice`) on ``self.link``;
    its constructor calls :meth:`_open_served`."""

    emulator: Any
    link: Any
    _buses: list
    close: Callable[[], None]  # the device's

    def _open_served(self, spec: CanSpec, own_ids: frozenset[int], make_emulator: Callable[[Any], Any]) -> None:
        """The emulator ``make_emulator(link)`` on a :class:`drivers.can_bus.ServedBus` over the adapter of
        ``spec`` (everything closed again if it cannot be built), its rejections watched."""
        from drivers.can_bus import ServedBus, open_device_bus

        self.link = ServedBus(open_device_bus(spec.interface, spec.channel), own_ids=own_ids)
        self._buses.append(self.link)
        try:
            self.emulator = make_emulator(self.link)
        except BaseException:
            self.close()
            raise
        self.served = ServedNode(self.emulator, self.link)
        counters = self.emulator.counters
        self.rejections = Rejections(spec.name, self.served.rejected_frames, self.served.last_rejected,
                                     self.served.conflict, heard=lambda: counters.get("received", 0) + counters.get(
                                         "foreign", 0) + self.served.rejected_frames())

    def start(self, events):
        self.rejections.start(events)

    def publish(self, t_s):
        self.emulator.publish(t_s)

    def activity(self):
        return self.emulator.counters["commands_accepted"]

    def summary(self):
        return {"emulator": {**self.emulator.counters, **self.link.counters},
                "rejected_frames": self.served.rejected_frames()}
