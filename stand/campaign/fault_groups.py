"""Faults in a campaign: the faults each case runs with, and pass rates grouped by fault type and by device.

A campaign of faults (docs/faults.md, "Campaigns of faults") draws a fault per case (a ``choice`` over whole
``[[faults]]`` tables, a ``uniform`` time...). Each case records the faults its scenario had, as drawn;
``campaign.json`` groups the verdicts by fault type and by device, so "does the flight code survive every single
fault" reads off one table. A case with two faults counts in the group of each.
"""

from __future__ import annotations

from ..faults.spec import TRIGGERS
from ..faults.types import FAULT_TYPES, LAYERS

#: Keys of a fault table a case record keeps besides its name, type and device: when it happened and how long.
WHEN = (*TRIGGERS, "delay_s", "duration_s")


def case_faults(data: dict) -> list[dict]:
    """The faults of a case's scenario dict (validated: every table is a fault the scenario accepts), each
    ``{name, type, device, layer, at_s | after | ..., duration_s}`` as the case draws them."""
    out = []
    for f in data.get("faults", []) if isinstance(data.get("faults"), list) else []:
        ftype = FAULT_TYPES.get(f.get("type"))
        device = f.get("device", f.get("link"))
        out.append({"name": f.get("name", f"{device}.{f.get('type')}"), "type": f.get("type"), "device": device,
                    "layer": ftype.layer if ftype is not None else None,
                    **{k: f[k] for k in WHEN if k in f}})
    return out


def started(faults: list[dict], summary: dict) -> list[dict]:
    """The case's faults with the time each first started in the run (``started_s``; None: it never did, e.g.
    the run ended first), from the run's ``summary["faults"]``."""
    record = summary.get("faults") or {}
    out = []
    for f in faults:
        occ = (record.get(f["name"]) or {}).get("occurrences") or []
        out.append({**f, "started_s": occ[0][0] if occ else None})
    return out


def _order(key: str, layer_of: dict) -> tuple:
    layer = layer_of.get(key)
    return (LAYERS.index(layer) if layer in LAYERS else len(LAYERS), key)


def group(records: list[dict], by: str, interval) -> dict:
    """Pass rates of the cases grouped by their faults' ``by`` (``type`` or ``device``): per group ``runs``,
    ``passed``, ``rate``, ``ci95`` (``interval(k, n)``), ``failed_cases`` and, by type, its ``layer`` and the
    ``devices`` it hit (by device: the ``types``). Empty when no case has a fault."""
    members: dict[str, dict[int, dict]] = {}
    layer_of: dict[str, str] = {}
    other: dict[str, set] = {}
    for r in records:
        for f in r.get("faults") or []:
            key = str(f.get(by))
            members.setdefault(key, {})[r["index"]] = r  # once per case, however many of its faults match
            layer_of.setdefault(key, f.get("layer") if by == "type" else None)
            other.setdefault(key, set()).add(str(f.get("device" if by == "type" else "type")))
    out = {}
    for key in sorted(members, key=lambda k: _order(k, layer_of)):
        rs = list(members[key].values())
        k = sum(bool(r.get("passed")) for r in rs)
        lo, hi = interval(k, len(rs))
        out[key] = {**({"layer": layer_of[key]} if by == "type" else {}),
                    "devices" if by == "type" else "types": sorted(other[key]),
                    "runs": len(rs), "passed": k, "rate": k / len(rs), "ci95": [lo, hi],
                    "failed_cases": sorted(r["index"] for r in rs if not r.get("passed"))}
    return out


def fault_lines(result: dict, limit: int = 5) -> list[str]:
    """The printed summary's lines for the fault groups of ``campaign.json`` (none without faults)."""
    lines = []
    for title, table in (("fault", result.get("by_fault_type") or {}), ("device", result.get("by_fault_device") or {})):
        for key, g in table.items():
            label = f"{title} {key}" + (f" ({g['layer']})" if g.get("layer") else "")
            failed = g["failed_cases"]
            worst = (f"; failed: case {', '.join(map(str, failed[:limit]))}" + (" ..." if len(failed) > limit else "")
                     if failed else "")
            lines.append(f"{label}: {g['passed']}/{g['runs']} passed ({100 * g['rate']:.1f} %, 95 % interval "
                         f"{100 * g['ci95'][0]:.1f} to {100 * g['ci95'][1]:.1f} %){worst}")
    return lines


def report_lines(result: dict, limit: int = 8) -> list[str]:
    """report.md's sections of pass rates by fault type and by device (none without faults)."""
    lines: list[str] = []
    for title, key, table in (("fault type", "type", result.get("by_fault_type") or {}),
                              ("device", "device", result.get("by_fault_device") or {})):
        if not table:
            continue
        extra = "layer | devices" if key == "type" else "fault types"
        header = f"| {key} | {extra} | passed | rate | 95 % interval | failed cases |"
        lines += ["", f"## Pass rate by {title}", "", header, "|---" * (header.count("|") - 1) + "|"]
        for name, g in table.items():
            what = f"{g['layer']} | {', '.join(g['devices'])}" if key == "type" else ", ".join(g["types"])
            failed = g["failed_cases"]
            shown = ", ".join(map(str, failed[:limit])) + (f" (+{len(failed) - limit})" if len(failed) > limit else "")
            lines.append(f"| {name} | {what} | {g['passed']}/{g['runs']} | {100 * g['rate']:.1f} % | "
                         f"{100 * g['ci95'][0]:.1f} to {100 * g['ci95'][1]:.1f} % | {shown} |")
    return lines
