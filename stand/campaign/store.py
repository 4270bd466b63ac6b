"""The campaign folder: one folder per case, written whole or not at all, and read back."""

from __future__ import annotations

import json
import os
import secrets
import shutil
import time
from pathlib import Path

from ..report import write_json_atomic
from .errors import CampaignError
from .spec import Spec

CASE_DIGITS = 5


# ----------------------------------------------------------------------------------------------- campaign
def case_dir(out: Path, index: int) -> Path:
    return Path(out) / "cases" / f"{index:0{CASE_DIGITS}d}"


def finished(out: Path) -> dict[int, dict]:
    """Records of the cases already written (a ``case.json`` is written last, so its presence means whole)."""
    found = {}
    for p in sorted((Path(out) / "cases").glob("*/case.json")):
        try:
            rec = json.loads(p.read_bytes().decode("utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            continue
        # A record that is not whole or not its folder's (damaged, edited) is not a finished case: a resume runs
        # it again rather than aggregate what it cannot vouch for.
        if _whole(rec, p.parent.name):
            found[rec["index"]] = rec
    return found


CRITERION_KEYS = frozenset(("name", "metric", "value", "limit", "pass"))


def _is_digest(value) -> bool:
    return value is None or (isinstance(value, str) and len(value) == 64
                             and all(c in "0123456789abcdef" for c in value))


def _whole(rec, folder: str) -> bool:
    """Has a case record what aggregation reads, of the right types, in its own folder?"""
    if not isinstance(rec, dict):
        return False
    index, crit = rec.get("index"), rec.get("criteria")
    return (isinstance(index, int) and not isinstance(index, bool) and folder == f"{index:0{CASE_DIGITS}d}"
            and isinstance(rec.get("seed"), int) and isinstance(rec.get("status"), str)
            and isinstance(crit, list) and all(isinstance(c, dict) and CRITERION_KEYS <= set(c) for c in crit)
            and _is_digest(rec.get("digest")))


#: A file in the campaign folder holding this session's token: a Dask worker that reads the same token there sees the
#: campaign folder (the client's machine, or a shared file system) and writes its case there, as a local worker does.
TOKEN_FILE = ".workers-token"


def write_token(out: Path) -> str:
    token = secrets.token_hex(16)
    (Path(out) / TOKEN_FILE).write_text(token)
    return token


def sees_campaign(dest: str, token: str) -> bool:
    """Does this process see the campaign folder of the case folder ``dest`` (its token file holds ``token``)?"""
    try:
        return (Path(dest).parent.parent / TOKEN_FILE).read_text() == token
    except (OSError, UnicodeDecodeError):
        return False


def part_dir(out: Path, index: int) -> Path:
    """Where case ``index`` is written before it counts (renamed to ``case_dir`` once whole)."""
    final = case_dir(out, index)
    return final.with_name(final.name + ".part")


def write_record(folder: Path, rec: dict) -> None:
    """A case's ``case.json``, the last file of its folder."""
    (Path(folder) / "case.json").write_text(json.dumps(rec, indent=1, default=float) + "\n")


def _write_case(out: Path, result: dict, received: float) -> dict:
    """Make a case's folder whole: its files and its ``case.json`` (unless the worker wrote both there already:
    ``dir`` and ``written``), then the rename that makes it count."""
    rec = result["record"]
    t0, cpu0 = time.time(), time.process_time()
    final, part = str(case_dir(out, rec["index"])), str(part_dir(out, rec["index"]))
    timing = rec.setdefault("timing", {})
    timing["transfer_s"] = max(0.0, received - timing.get("worker_end", received))
    folder = result.get("dir") if _beside(result.get("dir"), part) else None
    if folder is None or not result.get("written"):
        if folder is None:
            folder = part
            shutil.rmtree(part, ignore_errors=True)
            os.makedirs(part)
            for name, data in result["files"].items():
                (Path(part) / name).parent.mkdir(parents=True, exist_ok=True)
                (Path(part) / name).write_bytes(data)
        timing["write_s"] = time.time() - t0
        timing["write_cpu_s"] = time.process_time() - cpu0
        write_record(folder, rec)
    try:
        os.replace(folder, final)  # a folder renames over a missing or empty one
    except OSError:  # a case written before (a resume that runs it again): the new one replaces it
        shutil.rmtree(final, ignore_errors=True)
        os.replace(folder, final)
    return rec


def _beside(folder: str | None, part: str) -> bool:
    """Is ``folder`` where a worker wrote this case: its ``.part`` folder, or one of the worker's own beside it
    (``NNNNN.part.*``: a Dask worker, which the scheduler may run twice at once)? The worker names it from the
    absolute campaign folder; ``part`` may be relative to the working directory (``--out camp``): both are compared
    absolute and normalised."""
    if folder is None:
        return False
    where, name = os.path.split(os.path.normpath(folder))
    want_where, want = os.path.split(os.path.abspath(part))
    return where == want_where and (name == want or name.startswith(want + "."))


def _prepare(out: Path, spec: Spec) -> None:
    meta = out / "campaign.json"
    if meta.exists():
        try:
            old = json.loads(meta.read_text()).get("spec", {})
        except (OSError, json.JSONDecodeError):
            old = {}
        if old.get("key") != spec.key:
            raise CampaignError(f"--out {out} is not allowed: it holds another campaign (scenario, dispersions, "
                                "seed, --set or --duration differ); use a new folder, or the same inputs to resume.")
    elif out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise CampaignError(f"--out {out} is not allowed: an empty or new folder, or one of the same campaign "
                            "to resume.")
    out.mkdir(parents=True, exist_ok=True)
    (out / "scenario.toml").write_text(spec.scenario_text)
    (out / "dispersions.toml").write_text(spec.dispersions_text)
    if not meta.exists():
        write_json_atomic(meta, {"spec": spec.to_json(), "status": "running"})
    remove_parts(out)


def remove_parts(out: Path) -> None:
    """Case folders not made whole (``NNNNN.part``, a Dask worker's ``NNNNN.part.*``): what a worker that died or
    was ended left, or a second run of a case the scheduler started twice."""
    for stale in (Path(out) / "cases").glob("*.part*"):
        shutil.rmtree(stale, ignore_errors=True)
