"""The spec: what fixes every case of a campaign, and the validation of all cases before the first run."""

from __future__ import annotations

import copy
import dataclasses
import functools
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from .. import scenario as scenario_mod
from ..errors import ScenarioError, shown
from .dispersions import Dispersions, apply, case_values, parse_dispersions
from .errors import CampaignError
from .fault_groups import case_faults

MAX_RUNS = 100_000

@dataclass(frozen=True)
class Spec:
    """What fixes every case of a campaign (kept in campaign.json; a resumed campaign must match it)."""

    scenario_text: str
    scenario_name: str
    scenario_base: str  # the folder plug-in paths are relative to
    dispersions_text: str
    dispersions_source: str
    seed: int
    overrides: tuple[str, ...] = ()
    duration_s: float | None = None

    @property
    def key(self) -> str:
        blob = json.dumps([self.scenario_text, self.dispersions_text, self.seed, list(self.overrides),
                           self.duration_s])
        return hashlib.sha256(blob.encode()).hexdigest()[:16]

    def scenario_dict(self) -> dict:
        """The scenario's TOML with the overrides applied: a copy the caller may change."""
        return copy.deepcopy(_base_dict(self.scenario_text, self.scenario_name, self.overrides))

    def dispersions(self) -> Dispersions:
        return parse_dispersions(self.dispersions_text, self.scenario_dict(), self.dispersions_source)

    def case(self, index: int, dispersions: Dispersions | None = None) -> dict:
        """The task of case ``index``: its scenario dict (dispersed, seeded), values and seed."""
        disp = dispersions or dispersions_of(self)
        run_seed, values = case_values(disp, self.seed, index)
        # ``apply`` deep-copies: the parsed base is shared, never changed.
        data = apply(_base_dict(self.scenario_text, self.scenario_name, self.overrides), values, run_seed,
                     self.duration_s, disp.faults)
        scalars: dict[str, float] = {}
        for d in disp.items:
            scalars.update(d.scalars(values[d.field]))
        return {"index": index, "seed": run_seed, "values": values, "scalars": scalars, "data": data,
                "faults": case_faults(data), "source": f"{self.scenario_name}#case{index}",
                "base": self.scenario_base}

    def to_json(self) -> dict:
        return {**dataclasses.asdict(self), "overrides": list(self.overrides), "key": self.key}

    @classmethod
    def from_json(cls, d: dict) -> Spec:
        fields = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: (tuple(v) if k == "overrides" else v) for k, v in d.items() if k in fields})


@functools.lru_cache(maxsize=4)
def _base_dict(text: str, name: str, overrides: tuple[str, ...]) -> dict:
    """The scenario's TOML parsed once per process (a campaign's cases all start from it; parsing the text again
    for each case was half of its validation). Callers copy it before changing anything."""
    data = scenario_mod.loads(text, name)
    for item in overrides:
        scenario_mod.set_value(data, item)
    return data


@functools.lru_cache(maxsize=4)
def dispersions_of(spec: Spec) -> Dispersions:
    """The spec's dispersion file parsed once per process (every case of a worker draws from it; never changed)."""
    return spec.dispersions()


def make_spec(scenario: str, dispersions_path: str | Path, seed: int | None = None,
              overrides: list[str] | None = None, duration_s: float | None = None) -> Spec:
    path = scenario_mod.find(scenario)
    text = path.read_text(encoding="utf-8")
    dpath = Path(dispersions_path)
    try:
        dtext = dpath.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise CampaignError(f"--dispersions {dpath} is not allowed: a readable UTF-8 TOML file is required "
                            f"({getattr(exc, 'strerror', None) or exc}).") from None
    data = scenario_mod.loads(text, str(path))
    for item in overrides or []:
        scenario_mod.set_value(data, item)
    nominal = scenario_mod.parse(json.loads(json.dumps(data)), path.name)
    if nominal.wall_time_links:
        raise CampaignError(f"SCENARIO {path.name} is not allowed in a campaign: its devices "
                            f"{', '.join(nominal.wall_time_links)} are on hardware or served links, which run in wall "
                            "time on one bench; a campaign runs emulated devices (--set devices.NAME.link=emulated).")
    disp = parse_dispersions(dtext, data, dpath.name)
    if duration_s is not None and not (nominal.step_s <= duration_s <= 30 * 86400):
        raise CampaignError(str(ScenarioError("--duration", duration_s, f"seconds from the step "
                                              f"({nominal.step_s:g} s) to 30 days")))
    if seed is None:
        seed = disp.seed if disp.seed is not None else nominal.seed
    if not 0 <= seed < 2**63:
        raise CampaignError(str(ScenarioError("--seed", seed, "a whole number from 0 to 2**63 - 1")))
    return Spec(text, path.name, str(path.parent.resolve()), dtext, dpath.name, int(seed), tuple(overrides or ()),
                duration_s)


def validate(spec: Spec, runs: int) -> list[dict]:
    """Every case's task, each scenario parsed before the first run; CampaignError names the dispersion and
    the case whose value the scenario refuses."""
    disp = dispersions_of(spec)
    _check_each_choice(spec, disp)
    tasks = []
    for k in range(runs):
        task = spec.case(k, disp)
        parse_case(spec, {**task, "data": json.loads(json.dumps(task["data"]))}, disp)
        tasks.append(task)
    return tasks


def parse_case(spec: Spec, task: dict, disp: Dispersions | None = None) -> scenario_mod.Scenario:
    """A case's scenario through the scenario's own validation (``stand.scenario.parse``); a value it refuses is a
    CampaignError naming the case, the dispersion that drew it and the scenario's sentence. The campaign checks
    its first case so before anything runs, and every worker each case it runs (the parse that runs it)."""
    try:
        return scenario_mod.parse(task["data"], task["source"])
    except ScenarioError as exc:
        raise CampaignError(f"case {task['index']}: {_culprit(spec, disp or dispersions_of(spec), task, exc)}"
                            ) from None


def _check_each_choice(spec: Spec, disp: Dispersions) -> None:
    """The dispersion file's ``[[faults]]`` on the nominal scenario, then every value of every choice alone, through
    the scenario's validation: a bad entry of a long list (one fault table among thirty) is named before the first
    run, whether or not a case draws it."""
    base, source = spec.scenario_dict(), f"{spec.scenario_name} with the [[faults]] of {disp.source}"
    seed = spec.seed  # any seed: validation does not draw
    try:
        scenario_mod.parse(apply(base, {}, seed, spec.duration_s, disp.faults), source)
    except ScenarioError as exc:
        raise CampaignError(f"{disp.source}: its [[faults]] are refused by the scenario: {exc}") from None
    for k, d in enumerate(disp.items):
        for i, value in enumerate(d.params["values"] if d.distribution == "choice" else ()):
            try:
                scenario_mod.parse(apply(base, {d.field: value}, seed, spec.duration_s, disp.faults), source)
            except ScenarioError as exc:
                raise CampaignError(f"dispersions[{k}] ({d.field}, choice, in {disp.source}): values[{i}] = "
                                    f"{shown(value)} is refused by the scenario, so no case may draw it: {exc}"
                                    ) from None


def _culprit(spec: Spec, disp: Dispersions, task: dict, exc: ScenarioError) -> str:
    """Which dispersion (alone) makes the scenario refuse a case's values, with the scenario's sentence."""
    base = spec.scenario_dict()
    for k, d in enumerate(disp.items):
        data = apply(base, {d.field: task["values"][d.field]}, task["seed"], spec.duration_s, disp.faults)
        try:
            scenario_mod.parse(data, task["source"])
        except ScenarioError as alone:
            return (f"dispersions[{k}] ({d.field}, {d.distribution}, in {disp.source}) drew "
                    f"{shown(task['values'][d.field])}, which the scenario refuses (a value it does not allow, or a "
                    f"key its other settings leave unused, which would not be applied): {alone}")
    return (f"the values of dispersions {', '.join(d.field for d in disp.items)} (in {disp.source}) are refused "
            f"together by the scenario: {exc}")
