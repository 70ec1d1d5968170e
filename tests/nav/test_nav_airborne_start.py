"""A multirotor started in the air on the fusion EKF, near a corner of the range (scenario-level).

The start is GPS-aided (``sims.multirotor_loop``: the filter starts at the receiver's fix, the truth plus the
receiver's slow wander, at its accuracy). Arming judges the estimated position itself, never the fence
widened by the estimate's sigma: a start whose estimate is inside arms at once, with its first, unconverged
sigma; one whose fix lies outside is refused, and the refusal says by how much and how sure the estimate was.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from merlin.config.models import MerlinConfig
from sims.runner import RunResult, run_scenario
from sims.scenario import Scenario

HALF = 300.0  # the square range's half side, m


def _corner_range() -> MerlinConfig:
    data = MerlinConfig().model_dump(mode="json")
    data["geofence"].update(
        margin_m=3.0, sigma_k=2.0, altitude_ceiling_m=120.0, altitude_floor_m=20.0, inclusion_circles=[],
        exclusion_circles=[], exclusion_polygons=[],
        inclusion_polygons=[{"name": "r", "vertices_ne_m": [[-HALF, -HALF], [HALF, -HALF], [HALF, HALF], [-HALF, HALF]]}],
    )
    return MerlinConfig.model_validate(data)


def _start_in_the_corner(inside_m: float, duration_s: float) -> RunResult:
    sc = Scenario.model_validate({
        "name": "airborne_corner", "duration_s": duration_s, "seed": 5, "estimator": "ekf",
        "initial": {"pos_ned_m": [HALF - inside_m, HALF - inside_m, -30.0], "yaw_deg": 0.0},
        "gcs": [{"t": 0.0, "command": "arm"}, {"t": 0.0, "command": "hold"}], "log_rate_hz": 50.0,
    })
    return run_scenario(sc, _corner_range())


def _arm_ack(r: RunResult) -> dict[str, Any]:
    return next(e for e in r.events if e["type"] == "command_ack" and e["command"] == "ARM")


def test_a_fix_outside_the_corner_is_refused_naming_how_far_out_and_the_sigma() -> None:
    # 1 m inside both edges: the receiver's wander (seed 5) puts the fix 1.01 m east, just past the east edge
    r = _start_in_the_corner(1.0, 0.5)
    ack = _arm_ack(r)
    assert not ack["accepted"] and ack["reason"] == "outside_fence", ack
    est_out_m = float(r.log["est_e"][0]) - HALF
    assert r.log["truth_e"][0] < HALF and est_out_m > 0.0  # the truth inside, the estimate outside
    detail = ack["reason_detail"]
    assert detail["parameter"] == "position"
    assert abs(detail["value"] - est_out_m) < 0.01, (detail, est_out_m)
    assert f"{est_out_m:.2f} m outside" in detail["text"] and "position sigma 1.01 m" in detail["text"], detail


def test_an_estimate_inside_arms_with_its_first_unconverged_sigma_and_holds_above_the_floor() -> None:
    # 2 m inside: the fix is inside by 0.99 m, less than the fence's margin plus two sigmas (3 + 2 x 1.01 m):
    # the arming is not judged against that widening (the geofence monitor is, and takes the vehicle inward)
    r = _start_in_the_corner(2.0, 3.0)
    ack = _arm_ack(r)
    assert ack["accepted"], ack
    assert float(r.log["sigma_h"][0]) > 1.0  # armed before the covariance converged
    assert bool(np.all(np.asarray(r.log["armed"]) > 0.5))
    assert float(np.nanmin(r.log["fence_margin"])) > 0.0  # never below the floor nor past an edge
