"""The ICD document of a CAN device, rendered as Markdown from its DBC file (read with cantools).

Every message (id, sender, period, length, comment) and every signal (bits, type, scale and
offset, range, unit, value table, comment) comes from the DBC, so the document cannot drift from
the definition the codec and the emulator are built on; each device's ``icd`` module adds its
title and the behaviour that a DBC cannot express.
"""

from __future__ import annotations

from drivers.dbc import DbcCodec

__all__ = ["render_dbc_icd"]


def _num(x: float) -> str:
    return f"{x:.10g}"


def render_dbc_icd(dbc: DbcCodec, *, title: str, source: str, generator: str, intro: str, id_note: str,
                   behaviour: list[str]) -> str:
    db = dbc.database
    version = (db.version or "").strip()
    out = [
        f"# {title}",
        "",
        f"<!-- Generated from {source} by `python -m {generator}`; do not edit by hand (a test compares them). -->",
        "",
        f"**{version}.** {intro}",
        "",
        "## Bus and frames",
        "",
        "- CAN 2.0A (11-bit identifiers), classic frames; every signal little-endian (Intel); "
        "physical value = raw x scale + offset, in the unit shown.",
        f"- Nodes: {'; '.join(f'{n.name}: {n.comment}' if n.comment else n.name for n in db.nodes)}",
        f"- {id_note}",
        "",
        "## Messages",
        "",
        "| id | message | sender | period | length (bytes) | description |",
        "|---|---|---|---|---|---|",
    ]
    for m in db.messages:
        period = f"{m.cycle_time} ms" if m.cycle_time else "on demand"
        out.append(f"| 0x{m.frame_id:03X} | {m.name} | {', '.join(m.senders)} | {period} | {m.length} | "
                   f"{m.comment or ''} |")
    for m in db.messages:
        out += ["", f"### {m.name} (0x{m.frame_id:03X})", "",
                "| signal | bits | type | scale | offset | range | unit | values | description |",
                "|---|---|---|---|---|---|---|---|---|"]
        for s in m.signals:
            bits = f"{s.start}" if s.length == 1 else f"{s.start}-{s.start + s.length - 1}"
            kind = f"{'int' if s.is_signed else 'uint'}{s.length}" if s.length > 1 else "bit"
            lo, hi = dbc.signal_range(m.name, s.name)
            values = ", ".join(f"{int(k)} {v}" for k, v in (s.choices or {}).items())
            out.append(f"| {s.name} | {bits} | {kind} | {_num(s.conversion.scale)} | {_num(s.conversion.offset)} | "
                       f"{_num(lo)}..{_num(hi)} | {s.unit or ''} | {values} | {s.comment or ''} |")
    out += ["", "## Behaviour", ""] + [f"- {line}" for line in behaviour] + [""]
    return "\n".join(out)
