"""The fixed-wing fence approaches, generated: approach angle x speed against the range's east boundary,
plus the notch of the non-convex range (examples/configs/fixedwing_default.yaml).

Each case starts the aircraft far enough from the boundary that the experimental controller (granted at
about 1 s) flies ``LEAD_S`` seconds on its course before the velocity-projected fence trips, and ends
after the recovery turn (a half turn at the bank limit, pi R / V) has had time to finish.
"""

from __future__ import annotations

import math

from merlin.core import geofence
from sims.scenario import ControllerSpec, Expectation, Initial, Scenario

EAST_WALL_M = 1000.0
#: The notch's east side (E = 300 m, north of N = 1000 m) and the range's north side (N = 1500 m).
NOTCH_EAST_SIDE_M = 300.0
NORTH_WALL_M = 1500.0
HEIGHT_M = 120.0
LEAD_S = 4.0
GRANT_S = 1.0
ANGLES_DEG = (0.0, 30.0, 60.0, 90.0)
SPEEDS_MPS = (22.0, 30.0)  # the seed thesis's cruise; the autopilot's maximum airspeed
PARALLEL_OFFSET_M = 50.0
DT_S = 0.005  # 200 Hz: the core, JSBSim and the log agree with 400 Hz on these runs (docs/fixed-wing.md)
CONTROLLER = "experimental_controllers.fixedwing_examples:FwFlyaway"

EXPECT = [
    Expectation(type="granted", name="the flyaway is granted authority"),
    Expectation(type="revoked", reason="geofence", name="the fence takes control back"),
    Expectation(type="no_fence_breach", name="the fixed wing turns back inside the range"),
]


def _turn_s(params: geofence.FenceParams, speed_mps: float) -> float:
    radius = speed_mps**2 / (params.gravity_mps2 * math.tan(params.bank_limit_rad))
    return math.pi * radius / speed_mps


def approach_case(params: geofence.FenceParams, angle_deg: float, speed_mps: float, seed: int = 7) -> Scenario:
    """Fly at ``angle_deg`` to the east boundary's outward normal (0: head on; 90: parallel to it, 50 m
    inside, into the range's north-east corner) at ``speed_mps``."""
    v = speed_mps
    trip_m = geofence.trigger_distance_m(params, v, math.radians(angle_deg), 0.6)
    if angle_deg >= 89.9:
        # parallel to the east wall: the north wall ahead is the one met head on
        east = EAST_WALL_M - PARALLEL_OFFSET_M
        north = NORTH_WALL_M - geofence.trigger_distance_m(params, v, 0.0, 0.6) - v * (LEAD_S + GRANT_S)
        heading = 0.0
    else:
        a = math.radians(angle_deg)
        east = EAST_WALL_M - trip_m - v * math.cos(a) * (LEAD_S + GRANT_S)
        north = -v * math.sin(a) * (LEAD_S + GRANT_S)  # the trip comes near N = 0, far from any corner
        heading = 90.0 - angle_deg
    return Scenario(
        name=f"fw_fence_{int(angle_deg)}deg_{int(v)}mps",
        description=f"fixed wing: approach to the boundary at {angle_deg:g} deg to its normal, {v:g} m/s",
        duration_s=round(GRANT_S + LEAD_S + _turn_s(params, v) + 2.0, 1),
        seed=seed,
        dt_s=DT_S,
        vehicle="aerosonde",
        config="../configs/fixedwing_default.yaml",
        initial=Initial(pos_ned_m=[float(round(north)), float(round(east)), -HEIGHT_M], yaw_deg=heading,
                        airspeed_mps=v),
        gcs=[{"t": 0.0, "command": "arm"}, {"t": 0.0, "command": "hold"}],  # type: ignore[list-item]
        controller=ControllerSpec(type=CONTROLLER, params={"request_at_s": GRANT_S, "heading_deg": heading,
                                                           "speed_mps": v}),
        expectations=EXPECT,
    )


def notch_case(params: geofence.FenceParams, speed_mps: float, seed: int = 7) -> Scenario:
    """North past the re-entrant corner (1000, 300), 50 m east of the notch's side, towards the north
    boundary: the left turn (the short way home) is blocked by the notch, only the right turn is clear."""
    v = speed_mps
    north = NORTH_WALL_M - geofence.trigger_distance_m(params, v, 0.0, 0.6) - v * (LEAD_S + GRANT_S)
    east = NOTCH_EAST_SIDE_M + PARALLEL_OFFSET_M
    return Scenario(
        name=f"fw_fence_notch_{int(v)}mps",
        description=f"fixed wing: past the notch's re-entrant corner towards the north boundary at {v:g} m/s",
        duration_s=round(GRANT_S + LEAD_S + _turn_s(params, v) + 2.0, 1),
        seed=seed,
        dt_s=DT_S,
        vehicle="aerosonde",
        config="../configs/fixedwing_default.yaml",
        initial=Initial(pos_ned_m=[float(round(north)), east, -HEIGHT_M], yaw_deg=0.0, airspeed_mps=v),
        gcs=[{"t": 0.0, "command": "arm"}, {"t": 0.0, "command": "hold"}],  # type: ignore[list-item]
        controller=ControllerSpec(type=CONTROLLER, params={"request_at_s": GRANT_S, "heading_deg": 0.0,
                                                           "speed_mps": v}),
        expectations=EXPECT,
    )


# ------------------------------------------------------------------------------- the 0-330 deg sweeps

#: Courses of the sweeps: every 30 degrees.
COURSES_DEG = tuple(float(c) for c in range(0, 360, 30))
#: The notch's south-east inner corner, a re-entrant corner of the allowed area.
NOTCH_CORNER_NE_M = (1000.0, 300.0)
#: The corner cases aim this far past the corner into the notch (along its diagonal).
CORNER_AIM_INSIDE_M = 20.0


def _lead_in_m(params: geofence.FenceParams, v: float) -> float:
    """How far before the point it flies at a case starts: the head-on trigger distance (the largest), the
    grant and ``LEAD_S`` of flight on the course, and 20 m."""
    return geofence.trigger_distance_m(params, v, 0.0, 0.6) + v * (LEAD_S + GRANT_S) + 20.0


def _course_scenario(name: str, description: str, params: geofence.FenceParams, start_ne: tuple[float, float],
                     course_deg: float, v: float) -> Scenario:
    return Scenario(
        name=name, description=description,
        duration_s=round(GRANT_S + _lead_in_m(params, v) / v + _turn_s(params, v) + 2.0, 1),
        seed=7, dt_s=DT_S, vehicle="aerosonde", config="../configs/fixedwing_default.yaml",
        initial=Initial(pos_ned_m=[float(round(start_ne[0])), float(round(start_ne[1])), -HEIGHT_M],
                        yaw_deg=course_deg, airspeed_mps=v),
        gcs=[{"t": 0.0, "command": "arm"}, {"t": 0.0, "command": "hold"}],  # type: ignore[list-item]
        controller=ControllerSpec(type=CONTROLLER, params={"request_at_s": GRANT_S, "heading_deg": course_deg,
                                                           "speed_mps": v}),
        expectations=EXPECT,
    )


def course_case(fence: geofence.Fence, course_deg: float, speed_mps: float) -> Scenario:
    """A course from home, every direction: the case starts on the ray from home at the lead-in distance
    before the first boundary the ray meets (home itself when that is closer), so each of the range's sides,
    its corners, the notch (0 deg: its bottom, between the two re-entrant corners) and the mast's exclusion
    circle's neighbourhood (210, 240 deg) are approached at the angle the geometry gives."""
    import shapely

    v = speed_mps
    c = math.radians(course_deg)
    ray = shapely.LineString([(0.0, 0.0), (10_000.0 * math.cos(c), 10_000.0 * math.sin(c))])
    hits = shapely.intersection(ray, shapely.boundary(fence.allowed_area))
    hit_m = float(shapely.distance(shapely.Point(0.0, 0.0), hits))
    back = max(0.0, hit_m - _lead_in_m(fence.params, v))
    start = (back * math.cos(c), back * math.sin(c))
    return _course_scenario(f"fw_fence_course_{int(course_deg)}deg_{int(v)}mps",
                            f"fixed wing: course {course_deg:g} deg from home to the range's edge at {v:g} m/s",
                            fence.params, start, course_deg, v)


def corner_case(fence: geofence.Fence, course_deg: float, speed_mps: float) -> Scenario | None:
    """A course at the notch's re-entrant corner (1000, 300), from the lead-in distance before it, aimed
    ``CORNER_AIM_INSIDE_M`` into the notch past the corner (so the course really cuts the corner, whatever
    small drift the flyaway's start leaves: aimed exactly at the corner, a north course flies along the
    notch's side, 16 m off it, and correctly never trips). None for courses that would have to start inside
    the notch or cross it (the allowed area offers 270 degrees around the corner)."""
    import shapely

    v = speed_mps
    c = math.radians(course_deg)
    un, ue = math.cos(c), math.sin(c)
    back = _lead_in_m(fence.params, v)
    an = NOTCH_CORNER_NE_M[0] + CORNER_AIM_INSIDE_M / math.sqrt(2.0)
    ae = NOTCH_CORNER_NE_M[1] - CORNER_AIM_INSIDE_M / math.sqrt(2.0)
    start = (an - back * un, ae - back * ue)
    # the approach up to 60 m short of the aim point must lie inside, with room for the widening
    approach = shapely.LineString([start, (an - 60.0 * un, ae - 60.0 * ue)])
    if not shapely.contains(shapely.buffer(fence.allowed_area, -5.0), approach):
        return None
    return _course_scenario(f"fw_fence_corner_{int(course_deg)}deg_{int(v)}mps",
                            f"fixed wing: course {course_deg:g} deg across the notch's re-entrant corner, {v:g} m/s",
                            fence.params, start, course_deg, v)


# ------------------------------------------------------------------------- the ceiling and the floor

#: The range's ceiling and floor (examples/configs/fixedwing_default.yaml), heights above home.
CEILING_M = 250.0
FLOOR_M = 30.0
#: The autopilot's maximum climb and sink rates (merlin.autopilot.fixedwing_control: climb_max_mps,
#: sink_max_mps): the steepest a VELOCITY command is flown.
CLIMB_RATES_MPS = (2.0, 4.0)
#: How far below the ceiling (above the floor) an altitude case starts: 10 s of climb at the highest rate.
ALTITUDE_LEAD_M = 40.0
EXPECT_ALTITUDE = [
    Expectation(type="granted", name="the flyaway is granted authority"),
    Expectation(type="revoked", reason="geofence", name="the fence takes control back"),
    Expectation(type="no_fence_breach", name="the fixed wing levels off inside the range"),
]


def altitude_case(params: geofence.FenceParams, limit: str, speed_mps: float, climb_mps: float = 4.0,
                  seed: int = 7) -> Scenario:
    """Towards the ceiling (``limit`` "ceiling": climbing at ``climb_mps``) or the floor ("floor": descending
    at it), on a course north from 600 m south of home, far from every horizontal boundary: the projection's
    vertical part (the climb or descent over the reaction time plus the vertical stopping distance) must trip
    and the recovery level off inside the range."""
    v = speed_mps
    if limit not in ("ceiling", "floor"):
        raise ValueError(f"limit must be 'ceiling' or 'floor', got {limit!r}")
    up = limit == "ceiling"
    # above the floor, the lead starts above where the floor trips when level: the fixed wing's floor counts
    # its stall recovery's height bound (FenceParams.recovery_height_m), so the descent still spans the lead
    start_h = CEILING_M - ALTITUDE_LEAD_M if up else FLOOR_M + ALTITUDE_LEAD_M + math.ceil(params.recovery_height_m)
    rate = climb_mps if up else -climb_mps
    rate_name = f"{climb_mps:g}".replace(".", "p")
    return Scenario(
        name=f"fw_fence_{limit}_{int(v)}mps" if climb_mps == 4.0 else f"fw_fence_{limit}_{int(v)}mps_{rate_name}",
        description=f"fixed wing: {'climbing' if up else 'descending'} at {climb_mps:g} m/s towards the range's"
                    f" {limit} at {v:g} m/s",
        duration_s=round(GRANT_S + ALTITUDE_LEAD_M / climb_mps + 15.0, 1),
        seed=seed,
        dt_s=DT_S,
        vehicle="aerosonde",
        config="../configs/fixedwing_default.yaml",
        initial=Initial(pos_ned_m=[-600.0, 0.0, -start_h], yaw_deg=0.0, airspeed_mps=v),
        gcs=[{"t": 0.0, "command": "arm"}, {"t": 0.0, "command": "hold"}],  # type: ignore[list-item]
        controller=ControllerSpec(type=CONTROLLER, params={"request_at_s": GRANT_S, "heading_deg": 0.0,
                                                           "speed_mps": v, "climb_mps": rate}),
        expectations=EXPECT_ALTITUDE,
    )


# --------------------------------------------------------------------------- the tables of the docs


def _measure(sc: Scenario) -> dict[str, object]:
    from pathlib import Path

    from sims.runner import run_scenario
    from sims.scenario import resolve_config

    base = Path(__file__).resolve().parents[2] / "examples" / "scenarios"
    r = run_scenario(sc, resolve_config(sc, base, "<generated>"), source=sc.name)
    turns = [e for e in r.events if e["type"] == "fixed_wing_escape_turn"]
    return {"name": sc.name, "revoked": [e["reason"] for e in r.events if e["type"] == "revoked"],
            "min_margin_m": round(r.metrics["min_fence_margin_m"], 1),
            "max_breach_m": round(r.metrics["max_fence_breach_m"], 2),
            "side": turns[0]["side"] if turns else "-"}


def main() -> None:
    """Print every generated case's minimum margin, breach and escape side (docs/fixed-wing.md's tables):
    ``.venv/bin/python -m tests.scenarios_fixedwing.fence_cases``."""
    from merlin.config.loader import load_config
    from merlin.config.runtime import build_core_config

    root = __import__("pathlib").Path(__file__).resolve().parents[2]
    fence = build_core_config(load_config(root / "examples" / "configs" / "fixedwing_default.yaml")).fence
    assert fence is not None
    cases: list[Scenario] = [approach_case(fence.params, a, v) for a in ANGLES_DEG for v in SPEEDS_MPS]
    cases += [notch_case(fence.params, v) for v in SPEEDS_MPS]
    cases += [course_case(fence, c, v) for c in COURSES_DEG for v in SPEEDS_MPS]
    cases += [sc for c in COURSES_DEG for v in SPEEDS_MPS if (sc := corner_case(fence, c, v)) is not None]
    cases += [altitude_case(fence.params, lim, v, r) for lim in ("ceiling", "floor") for v in SPEEDS_MPS
              for r in CLIMB_RATES_MPS]
    for sc in cases:
        print(_measure(sc), flush=True)


if __name__ == "__main__":
    main()
