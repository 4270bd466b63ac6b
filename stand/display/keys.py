"""The shared key of authenticated state messages (HMAC-SHA256), for the sender and the node alike.

The key comes from a file only its owner can read (``--key-file``, a scenario's ``screen_key_file``) or the
environment variable :data:`KEY_ENV`, never from a command line, where other users can read it in the process
list.
"""

from __future__ import annotations

import os
import stat

from star_screen.state_message import MIN_KEY_BYTES

#: Environment variable holding the shared key of authenticated state messages.
KEY_ENV = "STAND_DISPLAY_KEY"


def load_key(key_file=None, environ=None, *, option: str = "--key-file") -> bytes | None:
    """The shared key: the contents of ``key_file`` (surrounding whitespace removed), else the
    environment variable :data:`KEY_ENV`, else None. Refuses a key shorter than 16 bytes and a key
    file that other users can read (ValueError naming ``option`` and the file, or the variable)."""
    environ = os.environ if environ is None else environ
    if key_file is not None:
        try:
            st = os.stat(key_file)
            with open(key_file, "rb") as f:
                key = f.read(4096).strip()
        except OSError as exc:
            raise ValueError(f"{option} {key_file!r} cannot be read ({exc.strerror}).") from None
        if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
            raise ValueError(f"{option} {key_file!r} can be read by other users (mode "
                             f"{stat.S_IMODE(st.st_mode):o}); make it private: chmod 600.")
        where = f"{option} {key_file!r}"
    elif environ.get(KEY_ENV):
        key, where = environ[KEY_ENV].strip().encode(), f"{KEY_ENV}"
    else:
        return None
    if len(key) < MIN_KEY_BYTES:
        raise ValueError(f"{where} holds a key of {len(key)} bytes; a shared key needs at least {MIN_KEY_BYTES}.")
    return key


def check_key(key) -> bytes | None:
    """``key`` as bytes (None: no signing); ValueError unless it is bytes of at least MIN_KEY_BYTES."""
    if key is not None and (not isinstance(key, bytes | bytearray) or len(key) < MIN_KEY_BYTES):
        raise ValueError(f"key must be bytes of at least {MIN_KEY_BYTES}; see load_key().")
    return None if key is None else bytes(key)
