"""The panorama PNG export (``stand view RUN --export DIR``): degree labels on both axes, a legend, labels that
neither overlap nor leave the map, the Hammer map whole, and a sun sensor coloured by whether it sees the Sun."""

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg

from stand.cli import main
from stand.devices.sun_sensor import SunSensorKind
from stand.telemetry import load
from stand.view import export, state


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """40 s of detumble_igrf: a fine sun sensor (fss) that sees the Sun only now and then, and a coarse one."""
    out = tmp_path_factory.mktemp("pano") / "run"
    # exit 1: 40 s does not detumble (a FAIL verdict); the recording is what is drawn
    assert main(["run", "detumble_igrf", "--duration", "40", "--out", str(out), "--no-progress"]) in (0, 1)
    assert (out / "view.json").is_file()
    meta = state.load_meta(out)
    tel = load(out)
    return out, meta, state.Sky(meta).derive(tel)


def _rendered(fig) -> np.ndarray:
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].astype(float) / 255


def test_sun_sensor_without_the_sun_is_never_drawn_in_the_sun_in_field_colour(run):
    _, meta, s = run
    fss = next(d for d in meta["devices"] if d["name"] == "fss")
    valid = np.asarray(s["fss.valid"])
    assert (valid == 1).any() and (valid == 0).any()  # both states occur, so the test can fail
    keys = {float(v): export.device_state(s, fss, i)[0] for i, v in enumerate(valid)}
    assert keys == {1.0: "valid", 0.0: "none"}
    assert SunSensorKind.view_state["invalid"][0] != "sun_flag"  # the page reads the same declaration


@pytest.mark.parametrize("kind", ["hammer", "equirectangular"])
def test_export_has_degree_labels_a_legend_and_the_whole_map(run, kind):
    _, meta, s = run
    fig = export.panorama_figure(s, meta, len(s["t_s"]) // 2, kind=kind)
    ax = fig.axes[0]
    x_labels = [t.get_text() for t in ax.get_xticklabels()]
    y_labels = [t.get_text() for t in ax.get_yticklabels()]
    assert {"180°", "90°", "0°", "-90°", "-180°"} <= set(x_labels)
    assert {"+90°", "+30°", "0°", "-30°", "-90°"} <= set(y_labels)
    assert "deg" in ax.get_xlabel() and "deg" in ax.get_ylabel()
    legend = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert {"Sun", "field of view: valid", "field: no solution / no Sun", "sun sensor head: lit"} <= set(legend)
    img = _rendered(fig)
    h_px = img.shape[0]
    # the map's top and bottom (Hammer: the ellipse's poles) lie inside the axes with a margin, and the outline
    # is drawn there: a light pixel within 2 pixels of each
    box = ax.get_window_extent()
    for y_data in (0.0, 600.0):
        x_px, y_px = ax.transData.transform((600.0, y_data))
        assert box.y0 + 3 < y_px < box.y1 - 3
        row = int(round(h_px - y_px))
        patch = img[row - 2:row + 3, int(x_px) - 40:int(x_px) + 40]
        assert patch.max() > 0.5, f"no outline at y = {y_data:g} of the {kind} map"


def test_export_labels_do_not_overlap_or_leave_the_figure(run):
    _, meta, s = run
    for i in (0, len(s["t_s"]) // 2, len(s["t_s"]) - 1):
        fig = export.panorama_figure(s, meta, i, kind="hammer")
        _rendered(fig)
        ax = fig.axes[0]
        renderer = fig.canvas.get_renderer()
        boxes = [a.get_window_extent(renderer) for a in ax.texts]
        assert len(boxes) >= 10  # Sun, Moon, six body axes, +v, nadir, devices
        fig_box = fig.bbox
        for k, b in enumerate(boxes):
            assert fig_box.x0 <= b.x0 and b.x1 <= fig_box.x1 and fig_box.y0 <= b.y0 and b.y1 <= fig_box.y1
            for other in boxes[k + 1:]:
                assert not b.overlaps(other), f"{ax.texts[k].get_text()!r} overlaps another label at sample {i}"
