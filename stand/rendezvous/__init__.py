"""Shadows on the docking target during a rendezvous: the ``[rendezvous]`` scenario section.

A chaser approaches a target vehicle whose docking target (circular marks on a base plate) its
camera must read. This module validates the section (``parse_rendezvous``), builds the approach
geometry over time (:class:`Approach`), evaluates how much of the marks is in shadow
(:meth:`Approach.evaluate`), finds the obscuration intervals (:func:`find_intervals`, the ends
refined by bisection or left to one sample) and writes the outputs (:func:`run_shadow`):
``obscuration.csv``, ``summary.json``, ``obscured.png``, ``tracks.png``, ``report.md`` and one
``camera_<t>s.png`` per requested time (:func:`render_camera`).

Frames (all right-handed; ``dcm_XY`` maps Y components to X components):

* N: GCRS. L: the target's LVLH (z nadir, y negative orbit normal, x along-track).
* T: target body, LVLH-fixed: ``dcm_TL = dcm(q_TL)``.
* P: plate, fixed in T at ``center_m`` with ``dcm_PT = dcm(q_PT)``; +z_P is the plate normal facing
  the approaching chaser, marks lie in z_P = 0 at ``marks_m`` = [x_P, y_P].
* C: chaser, origin at its docking port, +x_C the docking axis, pointed at the plate centre at every
  instant, +z_C as near nadir as it can be (then ``roll_deg`` about +x_C).
* K: docking camera at ``position_m`` in C, looking along +x_C: +z_K = +x_C (boresight),
  +x_K = +y_C (image right), +y_K = +z_C (image down).

The target flies a two-body orbit from ``[orbit]`` (J2 moves the LVLH frame by well under a
degree over an approach). The Sun comes from the ERFA ephemeris (:class:`sim.ephemeris.EphemerisTrack`),
the Earth's shadow from :func:`sim.environment.shadow_fraction` (conical, with penumbra). Shadows
on the plate are exact ray tests (:mod:`sim.obscuration`) against the plate itself (a Sun below its
horizon), the target's bodies and the chaser's bodies, with the Sun as a sampled disk or a point.

``obscured_percent`` is the shadowed share of the marks' area: the mean over marks of the area-
weighted fraction of the solar disk hidden from each mark point (a mark point half in penumbra
counts half). The Earth's shadow is reported beside it (``earth_lit_fraction``, eclipse intervals),
not mixed into it: it darkens everything at once and is not a shadow on the plate.
"""

from .approach import Approach, Interval, ShadowResult, compute, find_intervals, render_camera, sample_times
from .outputs import run_shadow, write_png
from .spec import (
    BODY_KINDS,
    SUN_MODELS,
    TRAJECTORIES,
    CameraSpec,
    PlateSpec,
    RendezvousSpec,
    describe,
    parse_rendezvous,
)

__all__ = ["BODY_KINDS", "SUN_MODELS", "TRAJECTORIES", "Approach", "CameraSpec", "Interval", "PlateSpec",
           "RendezvousSpec", "SECTION", "ShadowResult", "compute", "describe", "find_intervals", "parse_rendezvous",
           "render_camera", "run_shadow", "sample_times", "write_png"]


class _Section:
    """The ``[rendezvous]`` scenario section as the scenario loader finds it (``stand.scenario.SECTIONS``): the core
    never imports this package; a scenario with the section reaches it by name."""

    model = "rendezvous.shadow"

    @staticmethod
    def parse(t, parts: dict) -> RendezvousSpec:
        return parse_rendezvous(t, parts["duration_s"], parts["orbit"], t.source)

    @staticmethod
    def describe(spec: RendezvousSpec) -> str:
        return describe(spec)


SECTION = _Section()
