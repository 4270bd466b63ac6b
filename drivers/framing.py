"""The framing layer shared by the serial devices: the CRC every serial ICD uses, and sans-I/O SLIP
framing (RFC 1055, with an END byte before and after every frame).

No port, no clock. A framer looks at a buffer and reports how many bytes it consumed (0 = need
more) and what it found there, the way pymodbus's framers do: :func:`take_frame` for SLIP (the
star tracker), :func:`drivers.datagram.take_datagram` for fixed-length datagrams (the gyro, the
sun sensor). :class:`SlipDecoder` keeps the buffer between calls, counts what it drops and never
raises on bad input::

    dec = SlipDecoder(max_body=128)
    for body in dec.feed(chunk):        # unescaped frame bodies, in order
        ...
    dec.counters                         # frames, oversize, bad_escape, bytes_dropped

Bytes between two END bytes form one frame; back-to-back END bytes (idle fill) are ignored.
Garbage before a frame's opening END therefore comes out as a frame of its own, which the codec
rejects (bad CRC or too short): that is how a receiver resynchronises.
"""


from __future__ import annotations

import binascii
from typing import Any

__all__ = ["END", "ESC", "ESC_END", "ESC_ESC", "FrameObserver", "SlipDecoder", "crc16", "escape", "take_frame",
           "unescape"]

END = 0xC0
ESC = 0xDB
ESC_END = 0xDC
ESC_ESC = 0xDD

_END_B = bytes([END])
_ESC_B = bytes([ESC])
_ESCAPED_END = bytes([ESC, ESC_END])
_ESCAPED_ESC = bytes([ESC, ESC_ESC])


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor)."""
    return binascii.crc_hqx(data, 0xFFFF)


def escape(body: bytes) -> bytes:
    """A full SLIP frame of ``body``: END, body with END/ESC escaped, END."""
    return _END_B + body.replace(_ESC_B, _ESCAPED_ESC).replace(_END_B, _ESCAPED_END) + _END_B


def unescape(chunk: bytes | bytearray) -> bytes | None:
    """The body of an escaped chunk (no END bytes in it), or None for an invalid escape.

    Split at every ESC: each piece after the first must start with ESC_END or ESC_ESC (an empty piece is an ESC
    followed by another ESC, or by nothing), which stands for END or ESC; the rest of the piece is plain bytes."""
    if ESC not in chunk:
        return bytes(chunk)
    pieces = bytes(chunk).split(_ESC_B)
    out = [pieces[0]]
    for piece in pieces[1:]:
        if not piece:
            return None
        code = piece[0]
        if code == ESC_END:
            out.append(_END_B)
        elif code == ESC_ESC:
            out.append(_ESC_B)
        else:
            return None
        out.append(piece[1:])
    return b"".join(out)


def take_frame(buf: bytes | bytearray, max_body: int) -> tuple[int, bytes | None, str | None]:
    """Look for one frame at the start of ``buf``.

    Returns ``(consumed, body, error)``:

    - ``(0, None, None)``: no END yet and not too long: feed more bytes;
    - ``(n, body, None)``: a frame; ``n`` bytes (through its closing END) are consumed;
    - ``(n, None, None)``: an empty chunk (idle END) was consumed;
    - ``(n, None, "bad_escape")``: a chunk with an ESC not followed by ESC_END/ESC_ESC;
    - ``(n, None, "oversize")``: a chunk whose body exceeds ``max_body`` bytes; when no END was
      found at all, every byte is consumed and the caller must drop up to the next END.
    """
    i = buf.find(END)
    if i < 0:
        if len(buf) > 2 * max_body:  # even fully escaped, the body would be too long
            return len(buf), None, "oversize"
        return 0, None, None
    if i == 0:
        return 1, None, None
    body = bytes(buf[:i])
    if ESC in body:  # only then is there anything to unescape (most frames have no END or ESC byte in them)
        body = unescape(body)
        if body is None:
            return i + 1, None, "bad_escape"
    if len(body) > max_body:
        return i + 1, None, "oversize"
    return i + 1, body, None


class SlipDecoder:
    """Streaming SLIP decoder: :meth:`feed` bytes, get frame bodies; bad input is counted, never raised.

    ``counters``: ``frames`` (bodies returned), ``oversize``, ``bad_escape``, ``bytes_dropped``
    (bytes of rejected chunks and of oversize runs).
    """

    def __init__(self, max_body: int = 128) -> None:
        if not (isinstance(max_body, int) and max_body >= 1):
            raise ValueError(f"SlipDecoder max_body must be an int >= 1; got {max_body!r}.")
        self.max_body = max_body
        self._buf = bytearray()
        self._dropping = False  # inside an oversize run: drop everything up to the next END
        self.counters = {"frames": 0, "oversize": 0, "bad_escape": 0, "bytes_dropped": 0}

    def reset(self) -> None:
        """Forget any partial frame (after a reconnect)."""
        self.counters["bytes_dropped"] += len(self._buf)
        self._buf.clear()
        self._dropping = False

    @property
    def pending(self) -> int:
        """Bytes held waiting for an END."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[bytes]:
        """Add ``data``; return the complete frame bodies found, oldest first."""
        buf = self._buf
        buf += data
        frames: list[bytes] = []
        counters = self.counters
        while buf:
            if self._dropping:
                i = buf.find(END)
                if i < 0:
                    counters["bytes_dropped"] += len(buf)
                    buf.clear()
                    break
                counters["bytes_dropped"] += i + 1
                del buf[: i + 1]
                self._dropping = False
                continue
            if buf[0] == END:  # an idle END, as every frame opens with one: take_frame would consume it alone
                del buf[:1]
                continue
            consumed, body, error = take_frame(buf, self.max_body)
            if consumed == 0:
                break
            if error is not None:
                counters[error] += 1
                counters["bytes_dropped"] += consumed
                if error == "oversize" and buf.find(END, 0, consumed) < 0:
                    self._dropping = True
            elif body is not None:
                counters["frames"] += 1
                frames.append(body)
            del buf[:consumed]
        return frames


class FrameObserver:
    """What the stand keeps of a link it watches beside the flight code (``endpoint.add_observer(observer)``, see
    :mod:`drivers.endpoint`): the newest message of each type and how many of each came, in arrival order.

    It never touches the endpoint: the messages come from the endpoint's framing layer, decoded once by its codec.
    """

    __slots__ = ("_latest", "_counts", "_order", "frames")

    def __init__(self) -> None:
        self._latest: dict[type, Any] = {}
        self._counts: dict[type, int] = {}
        self._order: dict[type, int] = {}
        #: Every message observed, of any type.
        self.frames = 0

    def __call__(self, msg: Any) -> None:
        kind = type(msg)
        self.frames += 1
        self._latest[kind] = msg
        self._counts[kind] = self._counts.get(kind, 0) + 1
        self._order[kind] = self.frames

    def latest(self, *types: type) -> Any:
        """The newest message of any of ``types``, or None."""
        if len(types) == 1:  # the usual case, read every recorded row
            return self._latest.get(types[0])
        best, newest = None, 0
        for kind in types:
            n = self._order.get(kind, 0)
            if n > newest:
                best, newest = self._latest[kind], n
        return best

    def count(self, *types: type) -> int:
        """How many messages of ``types`` were observed."""
        if len(types) == 1:  # the usual case, asked every tick
            return self._counts.get(types[0], 0)
        return sum(self._counts.get(kind, 0) for kind in types)


def check_crc16_spec(crc: dict, what: str) -> None:
    """ValueError (naming ``what``) unless the ICD's ``crc`` table asks for :func:`crc16`."""
    if crc16(b"123456789") != crc["check"] or (crc["poly"], crc["init"], crc["width"]) != (0x1021, 0xFFFF, 16):
        raise ValueError(f"{what}: this codec implements CRC-16/CCITT-FALSE only; the ICD asks for {crc}.")


def crc16_doc(crc: dict) -> str:
    """The ICD document's checksum line."""
    return (f"- Checksum: {crc['name']} (poly 0x{crc['poly']:04X}, init 0x{crc['init']:04X}, no reflection, "
            f"xorout 0x{crc['xorout']:04X}, check 0x{crc['check']:04X}) over {crc['covers']}; {crc['placement']}.")
