"""Scenario files: finding one (a path or a shipped name), reading it (size, UTF-8, TOML) and ``--set`` overrides;
the result goes through :func:`stand.scenario.loader.parse`."""

from __future__ import annotations

import difflib
import tomllib
from pathlib import Path
from typing import Any

import fixtures
from stand.errors import ScenarioError

from .loader import parse
from .model import Scenario

FIXTURES = fixtures.ROOT
SCENARIO_DIR = FIXTURES / "scenarios"
DEFAULT_SCENARIO = SCENARIO_DIR / "detumble.toml"
#: A scenario file larger than this is refused before it is parsed (the shipped ones are under 5 KiB).
MAX_FILE_BYTES = 1 << 20


def shipped() -> dict[str, str]:
    """The scenarios shipped in ``fixtures/scenarios``: name -> one-line description."""
    out = {}
    for f in sorted(SCENARIO_DIR.glob("*.toml")):
        try:
            data = tomllib.loads(f.read_text(encoding="utf-8"))
        except (tomllib.TOMLDecodeError, OSError):
            data = {"scenario": {"description": "(unreadable)"}}
        if "scenario" in data:  # a campaign's dispersion file lives beside its scenario but is none
            out[f.stem] = data["scenario"].get("description", "")
    return out


def find(arg: str | Path) -> Path:
    """A scenario by path, by shipped name, or by shipped name with ``.toml``; ScenarioError with the closest
    shipped names otherwise. A file wins over a shipped name; a folder never counts as a scenario."""
    path = Path(arg)
    if path.is_file():
        return path
    stem = path.name[:-5] if path.name.endswith(".toml") else path.name
    if path.parent == Path(".") and (SCENARIO_DIR / f"{stem}.toml").is_file():
        return SCENARIO_DIR / f"{stem}.toml"
    names = list(shipped())
    close = difflib.get_close_matches(stem, names, n=3, cutoff=0.5)
    hint = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
    what = "a folder, not a scenario file; " if path.is_dir() else ""
    raise ScenarioError("SCENARIO", str(arg), f"{what}a scenario file or a shipped name ({', '.join(names)}){hint}")


def load(path: str | Path, overrides: list[str] | None = None) -> Scenario:
    """Read and validate a scenario file (a path or a shipped name), with ``KEY=VALUE`` overrides applied
    (``set_value``); raises ``ScenarioError`` naming the first bad field."""
    path = find(path)
    try:
        size = path.stat().st_size
        # The size a file reports is not always what it holds (procfs says 0): read no more than the limit allows.
        with path.open("rb") as f:
            raw = f.read(MAX_FILE_BYTES + 1)
        if size > MAX_FILE_BYTES or len(raw) > MAX_FILE_BYTES:
            raise ScenarioError("SCENARIO", str(path), f"a scenario file under {MAX_FILE_BYTES >> 10} KiB "
                                f"(this one has {max(size, len(raw))}{'' if size > MAX_FILE_BYTES else ' or more'} "
                                "bytes)")
        text = raw.decode("utf-8")
    except OSError as exc:
        raise ScenarioError("SCENARIO", str(path), f"a readable TOML file is required ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise ScenarioError("SCENARIO", str(path), f"a UTF-8 text file (byte {exc.start} is not UTF-8)") from None
    data = loads(text, str(path))
    for item in overrides or []:
        set_value(data, item)
    return parse(data, source=path.name)


def loads(text: str, where: str = "<string>") -> dict:
    """TOML text to a dict, every failure (syntax, nesting too deep for the parser) a ScenarioError."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError("SCENARIO", where, f"valid TOML is required ({exc})") from None
    except RecursionError:
        raise ScenarioError("SCENARIO", where, "TOML without arrays or tables nested hundreds deep") from None


def set_value(data: dict, item: str) -> None:
    """Apply one ``dotted.key=VALUE`` override (VALUE in TOML syntax; a bare word is a string). A
    ``[[devices]]`` entry is addressed by its name: ``devices.mtq.channel=can1``."""
    key, sep, text = item.partition("=")
    if not sep or not key.strip():
        raise ScenarioError("--set", item, "KEY=VALUE with a dotted key, e.g. devices.mtq.channel=can1")
    try:
        value = tomllib.loads(f"v = {text.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = text.strip()
    parts = key.strip().split(".")
    if any(not part.strip() for part in parts):
        raise ScenarioError("--set", item, "a dotted key without an empty part, e.g. devices.mtq.channel=can1")
    node: Any = data
    for i, part in enumerate(parts[:-1]):
        if isinstance(node, list):
            match = [d for d in node if isinstance(d, dict) and d.get("name") == part]
            if not match:
                raise ScenarioError("--set", item, f"a name of an entry of {'.'.join(parts[:i]) or 'the list'}")
            node = match[0]
        else:
            node = node.setdefault(part, {})
            if not isinstance(node, dict | list):
                raise ScenarioError("--set", item, f"a key inside a table ({'.'.join(parts[:i + 1])} is a value)")
    if isinstance(node, list):
        names = [str(d.get("name")) for d in node if isinstance(d, dict)]
        where = ".".join(parts[:-1])
        if parts[-1] not in names:
            raise ScenarioError("--set", item, f"a name of an entry of {where} ({', '.join(names) or 'none'}) "
                                "and one of its keys, e.g. devices.mtq.channel=can1")
        raise ScenarioError("--set", item, f"a key inside the entry: {key.strip()} names an entry of {where}, so "
                            f"set one of its keys, e.g. {key.strip()}.KEY=VALUE")
    if not isinstance(node, dict):
        raise ScenarioError("--set", item, "a key of a table")
    node[parts[-1]] = value  # an inline table replaces the whole table: --set 'controller={kind = "external"}'
