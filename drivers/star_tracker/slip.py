"""SLIP framing of the star tracker: the shared framer in :mod:`drivers.framing`, named here for
the tracker's callers."""

from drivers.framing import END, ESC, ESC_END, ESC_ESC, SlipDecoder, escape, take_frame, unescape

__all__ = ["END", "ESC", "ESC_END", "ESC_ESC", "SlipDecoder", "escape", "take_frame", "unescape"]
