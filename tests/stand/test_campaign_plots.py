"""The campaign report's scatter plots: a title saying what is plotted, a legend for the pass and fail colours
and the limit, and tick labels that do not run into each other."""

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg

from stand.campaign.summary_report import scatter_figure


def _campaign(n: int = 30):
    """Records of n cases with five dispersed inputs (long decimals such as a 0.0195 kg m^2 inertia) and one
    criterion, final rate <= 0.5 deg/s, that a third of them pass."""
    rng = np.random.default_rng(3)
    rate = rng.uniform(0.0, 4.5, n)
    rate[: n // 3] = rng.uniform(0.0, 0.45, n // 3)
    records = [{"index": k, "scalars": {"spacecraft.inertia_kg_m2[0]": float(rng.normal(0.0198, 0.001)),
                                        "spacecraft.inertia_kg_m2[2]": float(rng.normal(0.00995, 0.0004)),
                                        "spacecraft.omega_BN_B_deg_s[0]": float(rng.uniform(-12, 12)),
                                        "devices.mtq.mag_bias_nT[1]": float(rng.normal(0, 200)),
                                        "environment.era0_deg": float(rng.uniform(0, 360))},
                "criteria": [{"name": "detumbled", "value": float(rate[k]), "pass": bool(rate[k] <= 0.5),
                              "limit": {"max": 0.5}}]} for k in range(n)]
    info = {"metric": "final_rate_deg_s", "unit": "deg/s", "limit": {"max": 0.5}}
    result = {"spec": {"scenario_name": "detumble.toml"}, "criteria": {"detumbled": info}}
    return result, records, info, int((rate <= 0.5).sum())


def test_scatter_has_a_title_a_colour_legend_and_readable_ticks():
    result, records, info, n_pass = _campaign()
    fig = scatter_figure(result, records, "detumbled", info)
    title = fig.get_suptitle()
    assert "detumbled" in title and "final_rate_deg_s" in title and "30 runs" in title
    legend = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert legend == [f"pass ({n_pass})", f"fail ({30 - n_pass})", "pass limit: max 0.5 (deg/s)"]
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    panels = [ax for ax in fig.axes if ax.get_visible()]
    assert len(panels) == 5
    for ax in panels:
        assert ax.xaxis.get_offset_text().get_text() == ""  # every tick reads its own value
        boxes = [t.get_window_extent(renderer) for t in ax.get_xticklabels() if t.get_visible() and t.get_text()]
        assert len(boxes) >= 2
        for k, b in enumerate(boxes):
            assert not any(b.overlaps(o) for o in boxes[k + 1:]), f"tick labels overlap under {ax.get_xlabel()}"
    # passes and failures are told apart by colour and marker
    colours = {tuple(np.round(c.get_facecolor()[0], 3)) for c in panels[0].collections if len(c.get_offsets())}
    assert len(colours) == 2


def test_scatter_of_a_constant_metric_has_a_plain_axis():
    result, records, info, _ = _campaign()
    for r in records:
        r["criteria"][0].update(value=0.0, passed=True)
    fig = scatter_figure(result, records, "detumbled", info)
    lo, hi = fig.axes[0].get_ylim()
    assert lo <= -0.5 and hi >= 0.5
