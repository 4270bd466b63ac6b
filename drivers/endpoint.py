"""What every device endpoint shares, host driver or emulator: a bus it may own, an idempotent
``close()``, and use as a context manager. Subclasses set ``self.bus``, ``self._owns_bus`` and
``self._closed = False`` in their constructor."""

from __future__ import annotations

from typing import Any


class BusEndpoint:
    bus: Any
    _owns_bus: bool
    _closed: bool

    def close(self) -> None:
        """Stop using the bus (and shut it down if this endpoint owns it). Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        if self._owns_bus:
            self.bus.shutdown()

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
