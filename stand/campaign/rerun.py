"""Re-run one case of a campaign alone and compare it with the recorded one."""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import MISSING, ScenarioError
from ..scenario import parse
from .case import digest
from .errors import CampaignError
from .spec import MAX_RUNS, Spec
from .store import _is_digest, case_dir


# ------------------------------------------------------------------------------------------ re-run a case
def load_case(campaign_dir: str | Path, index: int):
    """``(Scenario, base folder, recorded case or None)`` of one case of a campaign on disk."""
    d = Path(campaign_dir)
    try:
        meta = json.loads((d / "campaign.json").read_text())
        spec = Spec.from_json(meta["spec"])
    except (OSError, json.JSONDecodeError, KeyError, TypeError):
        raise CampaignError(f"--campaign {d} is not allowed: a campaign folder (with its campaign.json) written "
                            "by stand campaign.") from None
    if isinstance(index, bool) or not 0 <= index < MAX_RUNS:
        raise CampaignError(str(ScenarioError("--case", index, f"a case index from 0 to {MAX_RUNS - 1}")))
    try:
        task = spec.case(index)
    except (CampaignError, ScenarioError):
        raise
    except (TypeError, ValueError, KeyError, AttributeError) as exc:  # a campaign.json edited by hand
        raise CampaignError(f"--campaign {d} is not allowed: the spec in its campaign.json does not rebuild case "
                            f"{index} ({type(exc).__name__}: {exc}); a campaign.json as stand campaign wrote it."
                            ) from None
    sc = parse(task["data"], task["source"])
    return sc, Path(spec.scenario_base), _case_record(d, index)


def _case_record(d: Path, index: int) -> dict | None:
    """The record of case ``index`` to compare a re-run with, checked: a corrupt case.json is one sentence."""
    path = case_dir(d, index) / "case.json"
    redo = f"delete {path.parent} and run the campaign's command again to redo the case"
    try:
        rec = json.loads(path.read_bytes().decode("utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CampaignError(f"{path} is not allowed: a case record (UTF-8 JSON) as stand campaign writes it; it "
                            f"does not read ({exc}): {redo}.") from None
    if not isinstance(rec, dict):
        raise CampaignError(str(ScenarioError("the record", rec, f"a JSON object as stand campaign writes it: {redo}",
                                              str(path))))
    if rec.get("index") != index or isinstance(rec.get("index"), bool):
        raise CampaignError(str(ScenarioError("index", rec.get("index", MISSING), f"this case's own index, {index}: "
                                              + redo, str(path))))
    dig = rec.get("digest")
    if not _is_digest(dig):
        raise CampaignError(str(ScenarioError("digest", dig, f"a SHA-256 in 64 hexadecimal digits, or none: {redo}",
                                              str(path))))
    return rec


def compare_case(rec: dict | None, run_dir: str | Path) -> tuple[bool | None, str]:
    """Does a re-run reproduce the case recorded by the campaign? ``(same, sentence)``; None: nothing recorded."""
    run_dir = Path(run_dir)
    if rec is None or not rec.get("digest"):
        return None, "the campaign has no finished record of this case to compare with"
    summary = json.loads((run_dir / "summary.json").read_text())
    rows = (run_dir / "telemetry" / "rows.f64").read_bytes()
    mine = digest(summary, rows)
    if mine == rec["digest"]:
        return True, f"reproduces campaign case {rec['index']} bit for bit (summary and telemetry, SHA-256 {mine[:16]})"
    return False, (f"DIFFERS from campaign case {rec['index']}: SHA-256 {mine[:16]} against {rec['digest'][:16]} "
                   "recorded")
