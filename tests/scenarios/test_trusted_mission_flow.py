"""The trusted mission as PX4 flies one: started on the ground, paused and resumed where it paused, a slowed
leg, and RTL after the last waypoint (scenario ``trusted_mission_from_ground``)."""

from __future__ import annotations

import math
from functools import cache
from pathlib import Path

import numpy as np

from sims.runner import RunResult, run_scenario
from sims.scenario import load_scenario

SCENARIO = Path(__file__).resolve().parents[2] / "examples" / "scenarios" / "trusted_mission_from_ground.yaml"


@cache
def _run() -> RunResult:
    sc, cfg = load_scenario(str(SCENARIO))
    return run_scenario(sc, cfg, source=str(SCENARIO))


def _behaviour_times(r: RunResult) -> list[tuple[float, str]]:
    return [(e["t"], e["behavior"]) for e in r.events if e["type"] == "behavior"]


def test_mission_on_the_ground_takes_off_then_flies_it_then_returns() -> None:
    seq = [b for _, b in _behaviour_times(_run())]
    assert seq == ["TAKEOFF", "MISSION", "HOLD", "MISSION", "RTL", "IDLE"], seq


def test_resumed_mission_continues_from_the_waypoint_it_paused_at() -> None:
    r = _run()
    t = np.asarray(r.log["t"])
    n, e = np.asarray(r.log["truth_n"]), np.asarray(r.log["truth_e"])
    times = _behaviour_times(r)
    paused = next(tt for tt, b in times if b == "HOLD")
    resumed = next(tt for tt, b in times if b == "MISSION" and tt > paused)
    ended = next(tt for tt, b in times if b == "RTL")
    # paused on the leg from (30, 30) to (0, 30): starting again from the first waypoint would fly back to (30, 0)
    at_pause = (t >= paused) & (t <= resumed)
    assert float(np.min(e[at_pause])) > 25.0
    after = (t >= resumed) & (t <= ended)
    assert float(np.min(e[after])) > 25.0, "the resumed mission flew back towards its first waypoint"
    # and it reached the last waypoint (0, 30) before RTL
    k = int(np.searchsorted(t, ended))
    assert math.hypot(n[k], e[k] - 30.0) < 3.0


def test_the_slowed_leg_is_flown_at_its_own_speed() -> None:
    r = _run()
    t = np.asarray(r.log["t"])
    vn, ve = np.asarray(r.log["truth_vn"]), np.asarray(r.log["truth_ve"])
    times = _behaviour_times(r)
    resumed = [tt for tt, b in times if b == "MISSION"][1]
    ended = next(tt for tt, b in times if b == "RTL")
    leg = (t >= resumed + 2.0) & (t <= ended)
    assert float(np.max(np.hypot(vn[leg], ve[leg]))) < 2.3  # mission_speed_mps 2 on that leg (cruise: 6)
    first_leg = (t >= 7.0) & (t <= 10.0)
    assert float(np.max(np.hypot(vn[first_leg], ve[first_leg]))) > 4.0
