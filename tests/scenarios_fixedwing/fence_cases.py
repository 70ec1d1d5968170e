"""The fixed-wing fence approaches, generated: approach angle x speed against the range's east boundary,
plus the notch of the non-convex range (examples/configs/fixedwing_default.yaml).

Each case starts the aircraft far enough from the boundary that the experimental controller (granted at
about 1 s) flies ``LEAD_S`` seconds on its course before the velocity-projected fence trips, and ends
after the recovery turn (a half turn at the bank limit, pi R / V) has had time to finish.
"""

from __future__ import annotations

import math

from merlin.core import geofence
from sims.fixedwing import FixedWingSim
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
#: The start airspeed: the requested one, but below 29.5 m/s, where FixedWingSim's trim does not converge
#: for every start point (30 m/s failed at some positions and headings); the controller then flies v.
MAX_START_AIRSPEED_MPS = 29.0
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


def _trimmable_start(north: float, east: float, heading_deg: float, airspeed_mps: float) -> tuple[float, float, float]:
    """The start point, moved back along the course in 10 m steps until FixedWingSim's trim converges there.

    Its damped Newton trim fails at some start points at 28-30 m/s (reported to its owner); returns
    (north, east, extra seconds of flight to the boundary).
    """
    h = math.radians(heading_deg)
    for k in range(20):
        n, e = float(round(north - 10.0 * k * math.cos(h))), float(round(east - 10.0 * k * math.sin(h)))
        try:
            FixedWingSim(pos_ned_m=(n, e, -HEIGHT_M), heading_rad=h, airspeed_mps=airspeed_mps, rate_hz=1.0 / DT_S)
        except ValueError:
            continue
        return n, e, 10.0 * k / airspeed_mps
    raise ValueError(f"no trimmable start near ({north:.0f}, {east:.0f}) at {airspeed_mps} m/s")


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
    v0 = min(v, MAX_START_AIRSPEED_MPS)
    north, east, extra_s = _trimmable_start(north, east, heading, v0)
    return Scenario(
        name=f"fw_fence_{int(angle_deg)}deg_{int(v)}mps",
        description=f"fixed wing: approach to the boundary at {angle_deg:g} deg to its normal, {v:g} m/s",
        duration_s=round(GRANT_S + LEAD_S + extra_s + _turn_s(params, v) + 2.0, 1),
        seed=seed,
        dt_s=DT_S,
        vehicle="aerosonde",
        config="../configs/fixedwing_default.yaml",
        initial=Initial(pos_ned_m=[north, east, -HEIGHT_M], yaw_deg=heading, airspeed_mps=v0),
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
    v0 = min(v, MAX_START_AIRSPEED_MPS)
    north, east, extra_s = _trimmable_start(north, NOTCH_EAST_SIDE_M + PARALLEL_OFFSET_M, 0.0, v0)
    return Scenario(
        name=f"fw_fence_notch_{int(v)}mps",
        description=f"fixed wing: past the notch's re-entrant corner towards the north boundary at {v:g} m/s",
        duration_s=round(GRANT_S + LEAD_S + extra_s + _turn_s(params, v) + 2.0, 1),
        seed=seed,
        dt_s=DT_S,
        vehicle="aerosonde",
        config="../configs/fixedwing_default.yaml",
        initial=Initial(pos_ned_m=[north, east, -HEIGHT_M], yaw_deg=0.0, airspeed_mps=v0),
        gcs=[{"t": 0.0, "command": "arm"}, {"t": 0.0, "command": "hold"}],  # type: ignore[list-item]
        controller=ControllerSpec(type=CONTROLLER, params={"request_at_s": GRANT_S, "heading_deg": 0.0,
                                                           "speed_mps": v}),
        expectations=EXPECT,
    )
