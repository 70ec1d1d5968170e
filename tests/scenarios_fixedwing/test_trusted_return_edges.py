"""Merlin's own return after a revocation next to an edge of the range (fixed wing): the scenarios
``merlin falsify`` found, where the trusted escape or RTL (not the experimental controller) left the range.
Each failed before the fix it names and must stay inside the range after it."""

from __future__ import annotations

from pathlib import Path

from sims.expectations import evaluate_all
from sims.runner import run_scenario
from sims.scenario import load_scenario

SCENARIOS = Path(__file__).resolve().parents[2] / "examples" / "scenarios"


def _run(name: str):  # type: ignore[no-untyped-def]
    sc, cfg = load_scenario(SCENARIOS / name)
    r = run_scenario(sc, cfg, source=name)
    return r, evaluate_all(sc.expectations, r.events, r.log, r.metrics)


def test_floor_trip_near_the_south_edge_turns_the_clear_way() -> None:
    """A floor revocation 113 m from the south edge, heading south-west in a tailwind: RTL's first turn goes
    the side the fence projection finds clear (right, away from the edge), not guidance's short way."""
    r, results = _run("fw_adv_floor_trip_south_edge.yaml")
    assert all(x.passed for x in results), [(x.name, x.detail) for x in results]
    revoked = [e for e in r.events if e["type"] == "revoked"]
    assert revoked and revoked[0]["reason_detail"]["parameter"] == "floor"
    t_rev = revoked[0]["t"]
    escapes = [e for e in r.events if e["type"] == "fixed_wing_escape_turn" and e["t"] >= t_rev]
    assert escapes and escapes[0]["t"] == t_rev and escapes[0]["side"] == "right"


def test_escape_turn_is_not_cut_short_by_a_flickering_monitor() -> None:
    """Towards the notch's west wall: the escape turn starts at the revocation and goes on until both of the
    projection's turns are clear, not one tick after the monitor first clears."""
    r, results = _run("fw_adv_notch_west_wall.yaml")
    assert all(x.passed for x in results), [(x.name, x.detail) for x in results]
    start = next(e for e in r.events if e["type"] == "fixed_wing_escape_turn")
    end = next(e for e in r.events if e["type"] == "fixed_wing_escape_turn_end")
    assert end["t"] - start["t"] > 1.0
    assert end["turned_deg"] > 20.0
