"""The one state sender: time-tagged attitude state to a display node, one UDP datagram per frame, signed
with the shared key when there is one (``stand run``'s star-screen link, the benches and the tests all use it)."""

from __future__ import annotations

import secrets
import socket

from sim.time import Epoch
from star_screen.state_message import DisplayState, StateMessageError, encode

from .keys import check_key


class StateSender:
    """Sim side: sends one state datagram per frame to a display node at ``(host, port)``.

    ``scenario_epoch`` lets :meth:`send` derive each frame's instant from its sim time;
    ``stream_id`` (default random) tells the node that a restarted sender starts a new sequence;
    ``key`` (bytes, from :func:`load_key`) signs every message with HMAC-SHA256.

    A per-frame :meth:`send` never stops the sim: a state outside the message's physical ranges
    (a tumble faster than one turn per second, say) is not sent and counts in ``refused``, and a
    socket error (the node is down: ECONNREFUSED from an earlier datagram) counts in
    ``send_errors``; ``last_error`` keeps the newest sentence.
    """

    def __init__(self, host: str, port: int, *, scenario_epoch: Epoch | None = None, stream_id: int | None = None,
                 key: bytes | None = None):
        if not 0 < int(port) < 65536:
            raise ValueError(f"port = {port}; allowed 1 to 65535.")
        self.key = check_key(key)
        self.address = (str(host), int(port))
        self.scenario_epoch = scenario_epoch
        self.stream_id = secrets.randbits(32) if stream_id is None else int(stream_id)
        self.sequence = 0
        self.sent = 0
        self.refused = 0
        self.send_errors = 0
        self.last_error = ""
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.connect(self.address)

    def send(
        self,
        q_SN,
        sim_time_ns: int,
        *,
        epoch: Epoch | None = None,
        v_sc_gcrs_m_s=(0.0, 0.0, 0.0),
        omega_SN_S=None,
        sun_N=None,
        moon_N=None,
    ) -> DisplayState | None:
        """Send the state of the frame at ``sim_time_ns``; ``epoch`` is the frame's instant (default
        ``scenario_epoch + sim_time_ns``). Returns what was sent (with its sequence number), or None
        when the state was refused (counted, see the class docstring)."""
        if epoch is None:
            if self.scenario_epoch is None:
                raise ValueError("epoch = None and no scenario_epoch was given; pass one of them.")
            epoch = self.scenario_epoch.add_ns(int(sim_time_ns))
        state = DisplayState(self.sequence, int(sim_time_ns), epoch, tuple(float(x) for x in q_SN),
                             tuple(float(x) for x in v_sc_gcrs_m_s),
                             None if omega_SN_S is None else tuple(float(x) for x in omega_SN_S),
                             None if sun_N is None else tuple(float(x) for x in sun_N),
                             None if moon_N is None else tuple(float(x) for x in moon_N),
                             stream_id=self.stream_id)
        try:
            data = encode(state, self.key)
        except StateMessageError as exc:
            self.refused += 1
            self.last_error = str(exc)
            return None
        self.send_bytes(data)
        self.sequence += 1
        return state

    def send_state(self, state: DisplayState) -> int:
        """Send a prepared state as is (its own sequence and stream id); returns the bytes sent."""
        return self.send_bytes(encode(state, self.key))

    def send_bytes(self, data: bytes) -> int:
        """Send one datagram; a socket error is counted (``send_errors``), not raised: returns 0."""
        try:
            n = self._sock.send(data)
        except OSError as exc:
            self.send_errors += 1
            self.last_error = f"sending to {self.address[0]}:{self.address[1]} failed: {exc}"
            return 0
        self.sent += 1
        return n

    def close(self) -> None:
        self._sock.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
