"""What every device endpoint shares, host driver or emulator, CAN or serial: an idempotent
``close()``, a ``closed`` flag, and use as a context manager. Subclasses fill one hook,
``_release()``, which lets go of the bus or port if the endpoint owns it, and set
``self._closed = False`` in their constructor.

The observer tap (:meth:`Endpoint.add_observer`): the stand's telemetry watches a link beside the flight code
instead of reading the flight code's driver. Each framing layer hands every frame it decoded (with the endpoint's
own codec, once) to the endpoint's observers after the endpoint took it itself, so what the driver keeps, counts and
returns to its user is the same with or without an observer; :class:`drivers.framing.FrameObserver` is the usual
observer."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


class Endpoint:
    _closed: bool
    #: Called with every frame this endpoint decodes (and an emulator sends); see :meth:`add_observer`.
    _observers: tuple[Callable[[Any], None], ...] = ()

    def add_observer(self, observer: Callable[[Any], None]) -> None:
        """Have ``observer(msg)`` called with every message this endpoint decodes from its link, after the endpoint
        itself took it: a host driver's received frames; an emulator's received commands and the frames it sent.
        Bad traffic is not passed on (the endpoint counts it). The endpoint's state and counters never depend on
        its observers, and an observer must not call back into the endpoint."""
        self._observers = (*self._observers, observer)

    def _release(self) -> None:
        """Give back what this endpoint owns (called once, by ``close``)."""

    def close(self) -> None:
        """Stop using the bus or port (and shut it if this endpoint owns it). Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._release()

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class BusEndpoint(Endpoint):
    """A CAN endpoint: ``self.bus``, shut down on close when ``self._owns_bus``."""

    bus: Any
    _owns_bus: bool

    def _release(self) -> None:
        if self._owns_bus:
            self.bus.shutdown()
