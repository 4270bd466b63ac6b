"""What every device endpoint shares, host driver or emulator, CAN or serial: an idempotent
``close()``, a ``closed`` flag, and use as a context manager. Subclasses fill one hook,
``_release()``, which lets go of the bus or port if the endpoint owns it, and set
``self._closed = False`` in their constructor."""

from __future__ import annotations

from typing import Any


class Endpoint:
    _closed: bool

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
