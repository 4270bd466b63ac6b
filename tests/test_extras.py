"""The optional extras install what the features behind them need."""

import tomllib
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parent.parent


def _extra(name: str) -> dict[str, Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    reqs = [Requirement(r) for r in project["optional-dependencies"][name]]
    return {r.name: r for r in reqs}


def test_the_campaign_extra_installs_bokeh_for_the_dask_dashboard():
    # distributed serves no dashboard without bokeh (it only logs that); the extra must bring it, in a range
    # that distributed accepts (>= 3.1) and that installs here.
    reqs = _extra("campaign")
    assert "bokeh" in reqs, "the campaign extra does not install bokeh: the Dask dashboard would be missing"
    bokeh = reqs["bokeh"]
    assert bokeh.specifier, "bokeh is not pinned to a range"
    assert not bokeh.specifier.contains("3.0.3") and bokeh.specifier.contains("3.9.2")
    try:
        installed = version("bokeh")
    except PackageNotFoundError:  # the test extra installs the campaign extra: bokeh must be here
        raise AssertionError("bokeh is not installed although the campaign extra names it") from None
    assert bokeh.specifier.contains(installed)
