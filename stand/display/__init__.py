"""The star screen's display library: one state sender, the display node, and the shared key that signs them.

The sim PC sends time-tagged attitude state, not pixels (the wire format is ``star_screen.state_message``); a
display node renders it locally. :class:`StateSender` is the only sender: ``stand run``'s star-screen link
(``screen = "state"``), the benches and the tests use it, and it signs with the shared key when one is given.
:class:`DisplayNode` is what ``stand display-node`` and ``stand emulate star-tracker --source screen`` serve.
"""

from __future__ import annotations

from .keys import KEY_ENV, check_key, load_key
from .node import LOOPBACK, DirectoryOutput, DisplayNode, NodeFrame, NodeStats, parse_hostport
from .sender import StateSender

__all__ = ["KEY_ENV", "LOOPBACK", "DirectoryOutput", "DisplayNode", "NodeFrame", "NodeStats", "StateSender",
           "check_key", "load_key", "parse_hostport"]
