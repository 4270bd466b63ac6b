"""report.md of a campaign, with its plots (pass rates, metric histograms, inputs against metrics)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .fault_groups import report_lines
from .results import _inputs, metric_table
from .store import finished


# ----------------------------------------------------------------------------------------------- report
def write_report(out: str | Path, result: dict) -> list[str]:
    """report.md with pass rates, metric distributions, worst cases and the plots."""
    # lazy: matplotlib, which only drawing a report needs
    from .. import plots as _plots  # noqa: F401 - the stand's matplotlib settings (Agg figures)

    out = Path(out)
    records = [r for k, r in sorted(finished(out).items()) if k < result["runs"]]
    made = [_plot_pass_rates(result, out), _plot_metrics(result, records, out)]
    made += _plot_scatter(result, records, out)
    made = [m for m in made if m]
    spec, ex = result["spec"], result["execution"]
    lines = [f"# Campaign: {Path(spec['scenario_name']).stem}", "",
             f"{result['finished']} of {result['runs']} runs finished, seed {spec['seed']}, dispersions "
             f"{spec['dispersions_source']}" + (f", {spec['duration_s']:g} s per run" if spec["duration_s"] else "")
             + ".", "",
             f"**Pass rate {_pct(result['pass_rate'])}** (95 % interval {_pct(result['pass_rate_ci95'][0])} to "
             f"{_pct(result['pass_rate_ci95'][1])}, Clopper-Pearson): {result['passed']} passed, "
             f"{result['failed']} failed ({result['errors']} errors).", ""]
    if ex.get("runs_per_min"):
        lines += [f"Ran on {ex['executor']} with {ex['workers']} workers: {ex['runs_per_min']:g} runs per minute, "
                  f"{ex['overhead_per_run_s']:g} s per run beyond the run itself.", ""]
    lines += ["| criterion | limit | passed | rate | 95 % interval |", "|---|---|---|---|---|"]
    for name, c in result["criteria"].items():
        lim = " and ".join(f"{k} {v:g}" for k, v in c["limit"].items())
        lines.append(f"| {name} | {lim} | {c['passed']}/{c['runs']} | {_pct(c['rate'])} | "
                     f"{_pct(c['ci95'][0])} to {_pct(c['ci95'][1])} |")
    lines += report_lines(result)
    for title, table in (("Metrics", result["metrics"]), ("Dispersed inputs", result["inputs"])):
        lines += ["", f"## {title}", "", "| name | n | mean | std | min | p5 | p50 | p95 | max |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for name, s in table.items():
            if s.get("n"):
                lines.append(f"| {name} | {s['n']} | " + " | ".join(f"{s[k]:.5g}" for k in
                                                                    ("mean", "std", "min", "p5", "p50", "p95", "max"))
                             + " |")
    lines += ["", "## Worst cases", "", "| case | criterion | margin to the limit | error |", "|---|---|---|---|"]
    for w in result["worst_cases"]:
        m = "-" if w["margin"] is None else f"{w['margin']:+.5g}"
        lines.append(f"| {w['case']} | {w['criterion']} | {m} | {w['error'] or ''} |")
    lines += ["", f"Re-run one case alone: `stand run --campaign {out} --case K --out DIR`.", "", "## Plots", ""]
    lines += [f"![{m}]({m})" for m in made]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    return made


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def _plot_pass_rates(result: dict, out: Path) -> str | None:
    from matplotlib.figure import Figure

    crit = result["criteria"]
    if not crit:
        return None
    fig = Figure(figsize=(8, 1.2 + 0.5 * len(crit)))
    ax = fig.add_subplot()
    names = list(crit)
    rate = np.array([100 * (crit[n]["rate"] or 0) for n in names])
    lo = np.array([100 * crit[n]["ci95"][0] for n in names])
    hi = np.array([100 * crit[n]["ci95"][1] for n in names])
    y = np.arange(len(names))
    ax.barh(y, rate, color="tab:green", alpha=0.6)
    ax.errorbar(rate, y, xerr=[rate - lo, hi - rate], fmt="none", ecolor="black", capsize=4)
    ax.set_yticks(y, names)
    ax.set_xlim(0, 100)
    ax.set_xlabel("pass rate (%), 95 % Clopper-Pearson interval")
    ax.set_title(f"Pass rate of each criterion over {result['finished']} runs (bar: rate; whisker: 95 % interval)",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(out / "pass_rates.png", dpi=100)
    return "pass_rates.png"


def _plot_metrics(result: dict, records: list[dict], out: Path) -> str | None:
    from matplotlib.figure import Figure

    table = {k: v for k, v in metric_table(records).items() if result["metrics"].get(k, {}).get("n")}
    if not table:
        return None
    cols = min(3, len(table))
    rows = math.ceil(len(table) / cols)
    fig = Figure(figsize=(4 * cols, 3 * rows))
    for i, (name, vals) in enumerate(table.items()):
        ax = fig.add_subplot(rows, cols, i + 1)
        a = np.asarray([v for v in vals if v is not None and math.isfinite(v)], dtype=float)
        ax.hist(a, bins=min(30, max(5, a.size // 5)), color="tab:blue", alpha=0.7)
        lim = result["criteria"].get(name, {}).get("limit", {})
        for v in lim.values():
            ax.axvline(v, color="black", linestyle="--")
        unit = result["criteria"].get(name, {}).get("unit") or ("deg/s" if name.startswith("rate_deg_s") else "")
        ax.set_title(f"{name} ({unit})" if unit else name, fontsize=9)
        ax.set_ylabel("runs")
    fig.suptitle(f"Distribution of each metric over {len(records)} runs (dashed: the pass limit)", fontsize=10)
    fig.tight_layout()
    fig.savefig(out / "metrics.png", dpi=100)
    return "metrics.png"


#: Pass and fail colours of the scatter plots (told apart by marker too, for readers who cannot tell red from green).
PASS_STYLE = {"color": "tab:green", "marker": "o"}
FAIL_STYLE = {"color": "tab:red", "marker": "x"}


def scatter_figure(result: dict, records: list[dict], name: str, info: dict):
    """Every dispersed input against criterion ``name``'s metric, one panel each: a title that says what is
    plotted, a legend for the pass and fail colours and the limit, and at most four ticks per axis."""
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator

    inputs = _inputs(records)
    y = np.asarray([np.nan if v is None else v for v in metric_table(records).get(name, [])], dtype=float)
    ok = np.asarray([any(c["name"] == name and c["pass"] for c in r.get("criteria", [])) for r in records])
    cols = min(4, len(inputs))
    rows = math.ceil(len(inputs) / cols)
    fig = Figure(figsize=(3.4 * cols, 2.7 * rows + 0.9), layout="constrained")
    unit = f" ({info['unit']})" if info.get("unit") else ""
    axes = fig.subplots(rows, cols, sharey=True, squeeze=False).ravel()
    for i, (label, xs) in enumerate(inputs.items()):
        ax = axes[i]
        x = np.asarray([np.nan if v is None else v for v in xs], dtype=float)
        ax.scatter(x[ok], y[ok], s=14, **PASS_STYLE, linewidths=1.0)
        ax.scatter(x[~ok], y[~ok], s=14, **FAIL_STYLE, linewidths=1.0)
        for v in info["limit"].values():
            ax.axhline(v, color="black", linestyle="--", linewidth=0.8)
        ax.set_xlabel(label, fontsize=8)
        if i % cols == 0:
            ax.set_ylabel(f"{name}{unit}", fontsize=8)
        # few ticks, no offset text: long values (0.0195 kg m^2) stay apart and readable
        ax.xaxis.set_major_locator(MaxNLocator(nbins=4))
        ax.ticklabel_format(axis="x", useOffset=False, style="sci", scilimits=(-3, 4))
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    for ax in axes[len(inputs):]:
        ax.set_visible(False)
    finite = y[np.isfinite(y)]
    if len(finite) and np.ptp(finite) == 0:
        # one value in every run (0 rejected frames): a unit-wide axis around it, not a 1e-16 scale
        half = max(1.0, 0.5 * abs(float(finite[0])))
        axes[0].set_ylim(finite[0] - half, finite[0] + half)
    n_pass = int(ok.sum())
    fig.suptitle(f"{Path(result['spec']['scenario_name']).stem}: criterion '{name}' (metric "
                 f"{info.get('metric', name)}{', ' + info['unit'] if info.get('unit') else ''}) against each "
                 f"dispersed input, {len(records)} runs ({n_pass} passed, "
                 f"{len(records) - n_pass} failed)", fontsize=10)
    lim = " and ".join(f"{k} {v:g}" for k, v in info["limit"].items())
    handles = [Line2D([], [], ls="none", ms=6, label=f"pass ({n_pass})", **PASS_STYLE),
               Line2D([], [], ls="none", ms=6, label=f"fail ({len(records) - n_pass})", **FAIL_STYLE),
               Line2D([], [], color="black", ls="--", lw=0.8, label=f"pass limit: {lim}{unit}")]
    fig.legend(handles=handles, loc="outside lower center", ncol=3, fontsize=8, frameon=False)
    return fig


def _plot_scatter(result: dict, records: list[dict], out: Path) -> list[str]:
    """One figure per criterion metric: every dispersed input against it, passes and failures coloured."""
    if not _inputs(records):
        return []
    made = []
    for k, (name, info) in enumerate(result["criteria"].items()):
        fname = f"scatter_{k}.png"
        scatter_figure(result, records, name, info).savefig(out / fname, dpi=90)
        made.append(fname)
    return made
