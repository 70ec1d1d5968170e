"""The fixed wing's waypoint mission and reposition, as PX4's fixed wing flies them, for the actuator stage.

PX4's fixed wing flies an uploaded mission leg by leg, reports each item reached, resumes a paused mission at
the item it was flying, ends with the mission's RTL or LAND item, answers a reposition (MAVSDK's
``goto_location``) with a loiter circle about the point and an orbit (``do_orbit``) with a loiter circle of the
radius asked, never tighter than it can turn. The actuator stage (:mod:`merlin.autopilot.fixedwing_behaviours`)
flies the core's behaviours; this module holds what those behaviours need beyond the core's decision, in
:class:`FixedWingMission` (the stage's ``fw_mission``): where the mission goes on from, whether it was flown
to its end, and where the core's GOTO or ORBIT target is. The core stays the judge: a GOTO or ORBIT reaches
the stage only once the core accepted it (and, for a fixed wing, the driver checked the whole loiter circle
against the fence first, :func:`circle_block`), and the mission's end item is a command to the core.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from merlin.autopilot import fixedwing_guidance as fg
from merlin.core import geofence
from merlin.core.types import Behavior, VehicleState

#: Points of a loiter circle checked against the fence (as the core checks an ORBIT's circle).
CIRCLE_POINTS = 32


@dataclass
class FixedWingMission:
    """What the stage reads when the core's MISSION, HOLD or ORBIT starts. ``arbiter`` returns the core's
    arbiter state (its GOTO/ORBIT target and radius); the driver keeps ``resume_index`` (the waypoint a
    started or resumed MISSION flies first) from :func:`progress`."""

    arbiter: Callable[[], Any] | None = None
    resume_index: int = 0
    start_index: int = 0  # the waypoint the mission being flown started at (the stage's wp_index counts from it)


def _of(stage: Any) -> FixedWingMission | None:
    fm = getattr(stage, "fw_mission", None)
    return fm if isinstance(fm, FixedWingMission) else None


def start_mission(stage: Any, gs: fg.GuidanceState, s: VehicleState) -> fg.GuidanceState:
    """MISSION for the stage: the stage's waypoints from the resume index on (the first leg from where the
    aircraft is), then a loiter at the last one."""
    wps = stage.mission
    fm = _of(stage)
    k = fm.resume_index if fm is not None and 0 < fm.resume_index < len(wps) else 0
    if fm is not None:
        fm.start_index = k
    return fg.start_mission(gs, s, tuple(wps[k:]), loop=False)


def reposition(stage: Any, gs: fg.GuidanceState, behavior: Behavior) -> fg.GuidanceState | None:
    """HOLD after a GOTO, or ORBIT: the loiter circle about the core's target (GOTO: the stage's loiter radius,
    clockwise; ORBIT: its radius, never below the loiter radius, clockwise for a positive one), at the target's
    height and the cruise airspeed. None when the core has no target (a plain HOLD)."""
    fm = _of(stage)
    if fm is None or fm.arbiter is None or behavior not in (Behavior.HOLD, Behavior.ORBIT):
        return None
    arb = fm.arbiter()
    target = arb.target_ned_m
    if target is None:
        return None
    radius, clockwise = stage.gp.loiter_radius_m, True
    if behavior is Behavior.ORBIT:
        radius, clockwise = max(abs(arb.orbit_radius_m), radius), arb.orbit_radius_m >= 0.0
    circle = fg.LoiterCircle((target[0], target[1]), radius, clockwise, -target[2], stage.cp.airspeed_cruise_mps)
    return fg.start_loiter(gs, circle)


def progress(stage: Any) -> tuple[int, bool]:
    """(the waypoint being flown, counted in the whole mission; whether the mission was flown to its end) from
    the stage's guidance: past its last waypoint the guidance loiters there (its lap counted)."""
    fm = _of(stage)
    gs = stage.gstate
    start = fm.start_index if fm is not None else 0
    n = len(stage.mission)
    if gs.mode is fg.GuidanceMode.MISSION and gs.mission:
        return start + gs.wp_index, False
    if gs.mode is fg.GuidanceMode.LOITER and gs.mission and gs.laps_completed >= 1:
        return n, True
    return start, False


def orbit_radius_m(stage: Any, radius_m: float) -> float:
    """The radius a fixed wing flies for an orbit of ``radius_m`` (its sign kept: the direction): never
    tighter than the stage's loiter radius, the tightest circle its bank limit holds at cruise airspeed."""
    return math.copysign(max(abs(radius_m), stage.gp.loiter_radius_m), radius_m)


def circle_block(fence: geofence.Fence | None, center_ned_m: tuple[float, float, float], radius_m: float) -> str | None:
    """Why a loiter circle about ``center_ned_m`` must be refused: a point of it outside the fence, or closer
    to its boundary than the fence's margin. None when it is clear (or there is no fence)."""
    if fence is None or not fence.params.enabled:
        return None
    margin = fence.params.margin_m
    n0, e0, d0 = center_ned_m
    r = abs(radius_m)
    for j in range(CIRCLE_POINTS):
        a = 2.0 * math.pi * j / CIRCLE_POINTS
        p = (n0 + r * math.cos(a), e0 + r * math.sin(a), d0)
        near = geofence.nearest_boundary_ne(fence, p[0], p[1])
        if not geofence.contains(fence, p) or (near is not None and near[0] < margin):
            return (f"the fixed wing's {r:g} m loiter circle about ({n0:.1f}, {e0:.1f}) m passes ({p[0]:.1f},"
                    f" {p[1]:.1f}) m, not inside the fence by its {margin:g} m margin")
    return None
