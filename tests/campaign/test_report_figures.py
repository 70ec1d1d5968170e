"""A campaign report's figures: one that cannot be drawn becomes a note, and the report is still written."""

from __future__ import annotations

from merlin.campaign import plots
from merlin.campaign.html import figure


def _records(value: float) -> list[dict[str, object]]:
    return [{"status": "ok", "passed": True, "samples": {"faults.0.amplitude_ned_mps.1": value, "mode": "x"},
             "metrics": {"min_fence_margin_m": 12.0}}]


def test_a_varied_value_near_the_largest_float_leaves_a_note_not_a_crash() -> None:
    """A campaign whose sampled gust amplitude was 1e308 flew and stored its run, then stopped writing its
    report: matplotlib cannot place such a value on an axis."""
    html = figure(plots.samples_vs_margin, "samples against margin", _records(1e308))
    assert 'The figure "samples against margin" could not be drawn (ValueError' in html
    assert "<img" not in html


def test_an_ordinary_varied_value_is_drawn() -> None:
    html = figure(plots.samples_vs_margin, "samples against margin", _records(3.5))
    assert html.startswith('<img alt="samples against margin" src="data:image/png;base64,')
    assert plots.varied_keys(_records(3.5)) == ["faults.0.amplitude_ned_mps.1"]
