"""The cage's register map as a Markdown page, generated from ``fixtures/devices/cage.toml``.

    python -m drivers.cage.register_doc > docs/cage_register_map.md

A test checks that ``docs/cage_register_map.md`` equals :func:`render` of the fixture, so the
document cannot drift from the map the emulator's server and the host driver are built on.
"""

from __future__ import annotations

from collections.abc import Iterable

from drivers.cage.registers import Register, RegisterMap, load_map

__all__ = ["render"]


def _rows(regs: Iterable[Register]) -> list[str]:
    out = []
    for r in regs:
        if r.bits is not None:
            meaning = "bits: " + ", ".join(f"{i} {b}" for i, b in enumerate(r.bits))
        elif r.enum is not None:
            meaning = "values: " + ", ".join(f"{i} {v}" for i, v in enumerate(r.enum))
        elif r.scale != 1.0:
            lo, hi = r.si_range
            meaning = f"{lo:g}..{hi:g} {r.unit}"
        else:
            lo, hi = r.raw_range
            meaning = f"{lo}..{hi}"
        if r.values is not None or r.values_max is not None:
            meaning = ("" if r.bits is None else meaning + "; ") + f"accepts {r.allowed()}"
        span = str(r.address) if r.words == 1 else f"{r.address}-{r.address + r.words - 1}"
        out.append(f"| {span} | `{r.name}` | {r.type} | {r.scale:g} | {meaning} | {r.doc} |")
    return out


def render(regmap: RegisterMap | None = None) -> str:
    """The register map as Markdown."""
    m = regmap if regmap is not None else load_map()
    d = m.device
    head = ["| address | register | type | scale to SI | range, meaning | description |", "|---|---|---|---|---|---|"]
    out = [
        "# Helmholtz cage Modbus register map",
        "",
        "<!-- Generated from fixtures/devices/cage.toml by `python -m drivers.cage.register_doc`; "
        "do not edit by hand (a test compares them). -->",
        "",
        f"**{d['name']} {d['version']}.** Our own map for a three-axis Helmholtz cage controller: three "
        "single-quadrant current supplies behind polarity relays, a magnetometer at the test position, and "
        "interlocks that hold whatever is commanded. The emulator (`drivers/cage/emulator.py`), the host "
        "driver (`drivers/cage/host.py`) and this page are all built from the TOML.",
        "",
        "## Link",
        "",
        f"- Transports: {d['transports']}.",
        f"- Device (unit) id {d['default_device_id']}; requests for other ids get no answer.",
        f"- Function codes: {d['function_codes']}. A function-6 write is answered with the echo of the request, "
        "a function-16 write with its start address and count. Any other function code gets exception 1 (illegal "
        "function) and applies nothing; an address outside the tables, or a request that starts or ends inside a "
        "32-bit value, exception 2 (illegal address); a value a register does not accept, exception 3 (illegal value), "
        "and nothing of that request is applied.",
        "- Addresses are the 0-based addresses a request carries (a manual counting from 1 would call "
        "holding register 0 \"40001\" and input register 0 \"30001\").",
        "- Registers are 16-bit big-endian; 32-bit values take two registers, high word first. "
        "Each name ends in its SI unit, and SI value = register value x scale.",
        f"- Axes {', '.join(m.axes)}: {m.frame}.",
        "",
        "## Holding registers (function 3 read, 6 and 16 write)",
        "",
        *head,
        *_rows(m.holding.values()),
        "",
        "## Input registers (function 4 read)",
        "",
        *head,
        *_rows(m.input.values()),
        "",
        "## Behaviour",
        "",
        "- **Control tick.** The host writes holding registers 1-5 (polarity, three set points, heartbeat) "
        "in one function-16 request, and reads input registers 0-15 (currents, field, its time tag, status, "
        "interlocks) in one function-4 request.",
        "- **Supplies.** Single quadrant: each supply regulates its current magnitude towards "
        "min(set point, `current_limit_A`), ramping at most at `slew_limit_A_s`, with an output voltage between "
        "0 and its compliance voltage. The coils obey L di/dt = V - R i; with the voltage at 0 a current "
        "decays with the coil's time constant L/R, never faster.",
        "- **Polarity.** A relay switches only with its current below `zero_current_A`, and the output of that "
        "axis stays off for `polarity_dead_time_s` around the switch. A polarity change under current is held "
        "(`polarity_held_*`): the current is brought to zero first.",
        "- **Heartbeat.** While the outputs are on, the `heartbeat` register must change at least every "
        "`heartbeat_timeout_s`; otherwise the outputs switch off, `output_enable` reads 0 and `heartbeat_lost` "
        "latches. Write a new heartbeat, then `output_enable` = 1, to go on again.",
        "- **Temperature.** A coil above `temperature_trip_C` switches the outputs off (`over_temperature` "
        "latched) until every coil is below `temperature_reset_C` and `output_enable` is written 1.",
        "- **Magnetometer.** Samples the field at the test position (coil field plus the lab's residual "
        "field) in cage axes; `field_time_s` tags the newest sample in device time.",
        "- **Why.** `interlocks` shows every interlock engaged now; `last_interlock` and its axis the most recent "
        "one; the event counters count each engagement, so a host that polls slowly still sees it happened.",
        "",
    ]
    return "\n".join(out)


if __name__ == "__main__":  # pragma: no cover
    import sys

    sys.stdout.write(render())
