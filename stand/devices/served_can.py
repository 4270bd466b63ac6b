"""What the CAN kinds served to a flight computer outside share (the magnetorquer board, the reaction wheels): the
emulator on a :class:`drivers.can_bus.ServedBus` link, whose rejections (the node's and the link's,
:class:`drivers.can_node.ServedNode`) the stand watches, and whose activity is the commands it accepted."""

from __future__ import annotations

from typing import Any

from drivers.can_node import ServedNode
from stand.devices import Rejections


class ServedCan:
    """Mixin for a served CAN device with ``self.emulator`` (a :class:`drivers.can_node.CanDevice`) on ``self.link``;
    its constructor calls :meth:`_watch_rejections` once both exist."""

    emulator: Any
    link: Any

    def _watch_rejections(self, name: str) -> None:
        self.served = ServedNode(self.emulator, self.link)
        self.rejections = Rejections(name, self.served.rejected_frames, self.served.last_rejected,
                                     self.served.conflict)

    def start(self, events):
        self.rejections.start(events)

    def publish(self, t_s):
        self.emulator.publish(t_s)

    def activity(self):
        return self.emulator.counters["commands_accepted"]
