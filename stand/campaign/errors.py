"""The error of a campaign's inputs (dispersion file, output folder, options)."""

from __future__ import annotations


class CampaignError(ValueError):
    """A campaign's inputs are wrong (dispersion file, output folder, options): one sentence, as ScenarioError."""
