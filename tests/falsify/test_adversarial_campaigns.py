"""The adversarial campaigns (``examples/campaigns/adversarial_*.yaml``): together at least 1,000 runs can
be planned over both vehicles, and every start they draw is inside its range, clear of the fence's own
margin (a start the fence trips at once would be a run about nothing)."""

from __future__ import annotations

from pathlib import Path

import pytest
from shapely.geometry import Point

from merlin.campaign.scheduler import load_scenarios, plan
from merlin.falsify.space import load_site
from sims.scenario import Scenario

ROOT = Path(__file__).resolve().parents[2]
FILES = sorted((ROOT / "examples" / "campaigns").glob("adversarial_*.yaml"))


def test_both_vehicles_and_a_thousand_runs_plan() -> None:
    scs = load_scenarios([str(f) for f in FILES])
    specs = plan(scs, 1000, 0)
    assert len(specs) == 1000
    # a run carries the fields its file gave (merlin.campaign.spec.derive_run): the vehicle as validated
    vehicles = {Scenario.model_validate(s.scenario).vehicle for s in specs}
    assert vehicles == {"quadrotor_default", "aerosonde"}
    kinds = {s.scenario["controller"]["type"].rsplit(":", 1)[1] for s in specs if s.scenario.get("controller")}
    assert kinds == {"SearchVelocity", "SearchTilt", "SearchPullPush"}
    assert any(s.scenario.get("operator") for s in specs)
    speeds = [s.scenario["controller"]["params"]["speed_mps"] for s in specs
              if (s.scenario.get("controller") or {}).get("type", "").endswith("SearchVelocity")]
    assert max(speeds) > 90.0  # up to the validator's bound


@pytest.mark.parametrize("path", FILES, ids=[f.stem for f in FILES])
def test_every_start_is_inside_its_range_and_clear_of_the_margin(path: Path) -> None:
    (cs,) = load_scenarios([str(path)])
    from merlin.config.models import MerlinConfig

    cfg = MerlinConfig.model_validate(cs.base["config"])
    vehicle = "aerosonde" if cs.base["vehicle"] == "aerosonde" else "multirotor"
    site = load_site(cfg, vehicle, str(path))
    starts = next(d for d in cs.vary if d.path == "initial.pos_ned_m").args
    clear = cfg.geofence.margin_m + cfg.geofence.sigma_k + 3.0
    for n, e, _ in starts:
        p = Point(n, e)
        assert site.allowed.contains(p), (n, e)
        assert site.allowed.boundary.distance(p) >= clear, (n, e)
