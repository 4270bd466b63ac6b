"""The human-readable ICD, rendered from ``fixtures/devices/star_tracker.toml``.

    python -m drivers.star_tracker.icd > docs/star_tracker_icd.md

A test checks that ``docs/star_tracker_icd.md`` equals :func:`render` of the fixture, so the
document cannot drift from the definition the codec and the emulator are built on.
"""

from __future__ import annotations

from drivers.framing import crc16_doc
from drivers.icd_codec import attr_text, enums_doc, md_head, message_heading, messages_doc, range_text
from drivers.star_tracker.codec import StarTrackerCodec

__all__ = ["render"]


def _hex(v: int) -> str:
    return f"0x{v:02X}"


def render(codec: StarTrackerCodec | None = None) -> str:
    """The ICD as Markdown."""
    c = codec if codec is not None else StarTrackerCodec()
    p = c.icd["protocol"]
    fr, crc = p["framing"], p["crc"]
    out = [
        "# Star tracker serial interface (ICD)",
        "",
        "<!-- Generated from fixtures/devices/star_tracker.toml by `python -m drivers.star_tracker.icd`; "
        "do not edit by hand (a test compares them). -->",
        "",
        f"**{p['name']} {p['version']}.** Our own interface, modelled on public COTS tracker interfaces "
        "(Arcsec Sagitta transport, CubeSpace CubeStar and ESA Swarm STR flags; see the provenance comment "
        "in the TOML). Host = the flight computer or the stand; device = the tracker or its emulator.",
        "",
        "## Link and frame",
        "",
        f"- Physical: {p['physical']}.",
        f"- Framing: {fr['kind']}: END = {_hex(fr['end'])}, ESC = {_hex(fr['esc'])}; in the body "
        f"{_hex(fr['end'])} is sent as {_hex(fr['esc'])} {_hex(fr['esc_end'])} and {_hex(fr['esc'])} as "
        f"{_hex(fr['esc'])} {_hex(fr['esc_esc'])}.",
        "- Body (before escaping): `address u8 | message id u8 | payload | CRC u16`.",
        f"- Default address {_hex(p['default_address'])}; a device ignores frames for other addresses.",
        crc16_doc(crc),
        f"- At most {p['max_body_bytes']} body bytes; longer frames are dropped as oversize.",
        f"- Byte order: {p['byte_order']}-endian. Field value in SI = wire value x scale.",
        f"- Quaternion convention: {p['quaternion']}",
        "- Every frame the device cannot accept (bad CRC, bad escape, oversize, short) is counted and dropped; "
        "a command with an unknown id, a wrong length or a value outside its table gets a NACK. The host "
        "drops a reply with a value outside its range (below) and counts it per reason.",
        *messages_doc(c.messages.values(), "Messages", ("id", "message", "payload bytes"), lambda s: s.payload_len),
    ]
    for s in c.messages.values():
        out += [*message_heading(s),
                *md_head("offset", "field", "type", "scale to SI", "SI attribute", "range / values", "description")]
        offset = 0
        for f in s.fields:
            out.append(f"| {offset} | {f.name} | {f.type} | {f.scale:g} | {attr_text(f)} | {range_text(f)} | {f.doc} |")
            offset += f.size
        for attr, tol in s.norms:
            out.append("")
            out.append(f"`{attr}` must have unit norm within {tol:g}; a frame outside it is rejected as a bad value.")
    out += enums_doc(c.enums)
    out += ["", "## Parameters (SET_PARAM / GET_PARAM, value as f32 in the wire unit)", "",
            *md_head("id", "parameter", "unit", "scale to SI", "min", "max", "default", "description")]
    for ps in c.params.values():
        kind = " (whole number)" if ps.integer else ""
        out.append(f"| {ps.id} | {ps.name} | {ps.unit} | {ps.scale:g} | {ps.lo:g} | {ps.hi:g} | {ps.default:g} | "
                   f"{ps.doc}{kind} |")
    out += ["", "## Exchanges", "",
            "- SET_PARAM, ACTION, SUBSCRIBE, UNSUBSCRIBE -> ACK (command id) or NACK (command id, error).",
            "- GET_PARAM -> PARAM_VALUE or NACK UNKNOWN_PARAMETER.",
            "- REQUEST_TELEMETRY(id) -> that telemetry message (the newest SOLUTION, or STATUS now), or NACK "
            "NOT_READY while booting, UNKNOWN_TELEMETRY for another id.",
            "- After SUBSCRIBE(id, period) the device sends the telemetry unasked every period (0 = every new "
            "solution) until UNSUBSCRIBE or a reboot.",
            "- ACTION BOOT starts (or restarts) the application: mode BOOT, then LOST_IN_SPACE after the boot "
            "time; SET_TIME sets the device clock (us, e.g. Unix time) and the time-synced flag; "
            "RESET_COUNTERS zeroes the STATUS counters; any other action (NONE, or a value past the table) gets "
            "NACK UNKNOWN_ACTION.",
            "- Modes: LOST_IN_SPACE turns to TRACKING after `stable_count` consecutive good solutions; TRACKING "
            "falls back after `track_loss_count` bad ones. The valid flag is set only in TRACKING on a good "
            "solution: no Sun, Moon or Earth disk (plus its exclusion half-angle) touching the field, rate "
            "within `rate_limit`, at least `min_stars_matched` stars matched.",
            "- SOLUTION time stamp: the mid-exposure time in the device clock.",
            ""]
    return "\n".join(out)


if __name__ == "__main__":  # pragma: no cover
    import sys

    sys.stdout.write(render())
