"""A controller's request while Merlin's fixed-wing fence escape is flying (scenario ``fw_adv_grant_during_escape``,
found by ``merlin falsify``): the grant waits for the monitors to stay clear, and a revocation in the middle
of the escape gives the turn back the bank the fence projection assumes. Both failed before (2.28 m outside
the range: a grant on a one-tick clear of the fence monitor, then an escape turn flown 10 deg short of its
bank because the roll loop's integrator inherited the adversary's aileron)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sims.expectations import evaluate_all
from sims.runner import run_scenario
from sims.scenario import load_scenario

SCENARIO = Path(__file__).resolve().parents[2] / "examples" / "scenarios" / "fw_adv_grant_during_escape.yaml"


def _run(clear_min_s: float | None = None):  # type: ignore[no-untyped-def]
    sc, cfg = load_scenario(SCENARIO)
    if clear_min_s is not None:
        cfg = cfg.model_copy(update={"handover": cfg.handover.model_copy(update={"monitors_clear_min_s": clear_min_s})})
    r = run_scenario(sc, cfg, source=SCENARIO.name)
    return r, evaluate_all(sc.expectations, r.events, r.log, r.metrics), cfg


def test_no_grant_until_the_fence_monitor_has_stayed_clear() -> None:
    """The request at 1.0 s comes while the escape turn flies and the fence monitor flickers clear for single
    ticks: refused on the probation (handover.monitors_clear_min_s), and no grant is given while the
    geofence was tripped within that time."""
    r, results, cfg = _run()
    assert all(x.passed for x in results), [(x.name, x.detail) for x in results]
    denied = [e for e in r.events if e["type"] == "denied"]
    assert denied and denied[0]["t"] == 1.0 and denied[0]["reason_detail"]["parameter"] == "clear_s"
    assert denied[0]["reason_detail"]["monitor"] == "geofence"
    need = cfg.handover.monitors_clear_min_s
    trips = [e["t"] for e in r.events if e["type"] == "monitor_tripped" and e["reason"] == "geofence"]
    clears = [e["t"] for e in r.events if e["type"] == "monitor_cleared"]
    for g in (e["t"] for e in r.events if e["type"] == "granted"):
        last_trip = max(t for t in trips if t <= g)
        # tripped until the tick before it cleared (reported once per trip, cleared once)
        last_clear = max(t for t in clears if last_trip < t <= g)
        assert g - last_clear >= need - 0.005 - 1e-9, (g, last_trip, last_clear)
    assert r.metrics["min_fence_margin_m"] > 5.0


def test_a_revocation_mid_escape_flies_the_bank_the_projection_assumes() -> None:
    """With the probation off (a grant as soon as the monitor is clear, as before), the controller is granted
    in the middle of the escape and revoked on the fence: the takeover starts the roll loop's integrator at
    trim, so the escape turn holds at least the fence's bank limit from the end of the reaction time to the
    end of the turn (it flew 25 deg for seconds when the integrator inherited the adversary's left aileron),
    and the aircraft stays inside."""
    r, results, cfg = _run(clear_min_s=0.0)
    assert all(x.passed for x in results), [(x.name, x.detail) for x in results]
    revoked = [e for e in r.events if e["type"] == "revoked" and e["reason"] == "geofence"]
    assert revoked, [e["type"] for e in r.events]
    t_rev = revoked[0]["t"]
    ends = [e["t"] for e in r.events if e["type"] == "fixed_wing_escape_turn_end" and e["t"] > t_rev]
    escape = [e for e in r.events if e["type"] == "fixed_wing_escape_turn" and e["t"] == t_rev]
    assert ends and escape
    side = 1.0 if escape[0]["side"] == "right" else -1.0
    t = np.asarray(r.log["t"])
    roll_deg = side * np.degrees(np.asarray(r.log["truth_roll"]))
    turn = (t >= t_rev + cfg.vehicle.reaction_time_s) & (t < ends[0])
    assert turn.any() and float(roll_deg[turn].min()) >= cfg.vehicle.bank_limit_deg, float(roll_deg[turn].min())
    assert math.isfinite(r.metrics["min_fence_margin_m"]) and r.metrics["min_fence_margin_m"] > 5.0
