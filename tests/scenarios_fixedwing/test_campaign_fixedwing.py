"""The fixed wing in the campaign mix: ``examples/campaigns/fixed_wing.yaml`` (flyaway on a random course,
speed and climb rate towards a non-convex range, its ceiling or floor), ``fixed_wing_stall.yaml`` (a random
pull-up) and ``fixed_wing_lap.yaml`` (the seed thesis's lap in a random wind), three runs: one of each.

Also the ``max_height_loss_after_revocation`` expectation type on hand-made logs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from merlin.campaign.scheduler import CampaignOptions, run_campaign
from sims.expectations import evaluate
from sims.scenario import Expectation

ROOT = Path(__file__).resolve().parents[2]
CAMPAIGNS = (str(ROOT / "examples" / "campaigns" / "fixed_wing.yaml"),
             str(ROOT / "examples" / "campaigns" / "fixed_wing_stall.yaml"),
             str(ROOT / "examples" / "campaigns" / "fixed_wing_lap.yaml"))


@pytest.mark.slow
def test_fixed_wing_campaigns_pass(tmp_path: Path) -> None:
    o = run_campaign(CampaignOptions(scenarios=CAMPAIGNS, runs=3, out=tmp_path, seed=5, workers=1))
    assert o.flown_now == 3 and len(o.records) == 3
    by_file = {Path(r["scenario_file"]).name: r for r in o.records.values()}
    assert set(by_file) == {"fixed_wing.yaml", "fixed_wing_stall.yaml", "fixed_wing_lap.yaml"}
    for r in o.records.values():
        failed = [x for x in r["expectations"] if not x["passed"]]
        assert r["passed"] and not failed, (r["run_id"], r["samples"], failed)
        assert r["metrics"]["max_fence_breach_m"] == 0.0
    fence, stall = by_file["fixed_wing.yaml"], by_file["fixed_wing_stall.yaml"]
    assert [v["reason"] for v in fence["revocations"]] == ["geofence"]
    assert [v["reason"] for v in stall["revocations"]] == ["envelope"]
    # the samples are the campaign's: a random course and speed, a random pull-up
    assert 22.0 <= fence["samples"]["controller.params.speed_mps"] <= 30.0
    assert 1.0 <= stall["samples"]["controller.params.pitch_rate_degps"] <= 5.0
    assert -4.0 <= fence["samples"]["controller.params.climb_mps"] <= 4.0
    lap = by_file["fixed_wing_lap.yaml"]
    assert lap["revocations"] == [] and "wind.steady_ned_mps.0" in lap["samples"]
    assert sum("after capture" in x["detail"] for x in lap["expectations"]) == 2


def _log(heights: list[float]) -> dict[str, np.ndarray]:
    return {"t": np.arange(len(heights), dtype=float), "truth_d": -np.asarray(heights, dtype=float)}


REVOKED = [{"t": 2.0, "type": "revoked", "reason": "envelope", "reason_detail": {"parameter": "airspeed_mps"}}]


@pytest.mark.parametrize(("heights", "m", "within_s", "passed"), [
    ([160, 161, 160, 155, 152, 158, 160], 8.0, None, True),  # 160 at the revocation, lowest 152: 8 m
    ([160, 161, 160, 155, 151.9, 158, 160], 8.0, None, False),
    ([160, 161, 160, 159, 140, 140, 140], 8.0, 1.0, True),  # only the first second after the revocation
    ([100, 90, 160, 161, 162, 163, 164], 0.0, None, True),  # a climb loses nothing; before it does not count
])
def test_height_loss_after_revocation(heights: list[float], m: float, within_s: float | None, passed: bool) -> None:
    x = Expectation(type="max_height_loss_after_revocation", m=m, within_s=within_s, reason="envelope")
    v = evaluate(x, REVOKED, _log(heights), {})
    assert v.passed is passed, v


def test_height_loss_needs_a_revocation_and_a_bound() -> None:
    log = _log([160.0] * 5)
    assert not evaluate(Expectation(type="max_height_loss_after_revocation", m=8.0), [], log, {}).passed
    other = Expectation(type="max_height_loss_after_revocation", m=8.0, reason="geofence")
    assert not evaluate(other, REVOKED, log, {}).passed
    assert not evaluate(Expectation(type="max_height_loss_after_revocation"), REVOKED, log, {}).passed
