"""The MAVLink waypoint mission (MAV_MISSION_TYPE_MISSION): what the items mean to Merlin, and the protocol end.

The transfer (upload, download, clear, retries) is :class:`merlin.link.mission_transfer.ItemTransfer`'s,
shared with the fence. This module decides what a received list means: :func:`decode_mission` turns the
items into a :class:`MissionPlan` for Merlin's trusted mission behaviour (waypoints in the local NED frame
about home, a speed per leg, what to do at the end), or refuses the list naming the item and why, and
:func:`check_legs_against_fence` refuses a plan whose legs leave the fence or enter a keep-out zone.

Items understood (common.xml), as PX4 flies them for a multirotor:

* MAV_CMD_NAV_WAYPOINT (16): fly to x/y at z (frames GLOBAL / GLOBAL_INT: z above mean sea level;
  GLOBAL_RELATIVE_ALT / _INT: z above home). param1 (hold time) and param2 (acceptance radius) are kept
  for download; Merlin accepts a waypoint within ``trusted.mission_acceptance_m`` and does not hold.
* MAV_CMD_NAV_TAKEOFF (22): climb to z; at x/y when given (not 0/0 and finite), above home otherwise.
* MAV_CMD_DO_CHANGE_SPEED (178): param2 m/s for the legs that follow (-1 or NaN: unchanged). Merlin's
  trusted autopilot flies no faster than its cruise speed (``trusted.cruise_speed_mps``), so a faster
  request is flown at cruise speed.
* MAV_CMD_NAV_LAND (21) and MAV_CMD_NAV_RETURN_TO_LAUNCH (20): the last item only (what MAVSDK's
  ``set_return_to_launch_after_mission`` appends is an RTL item). LAND with a position flies there first.

Any other command is refused with MAV_MISSION_UNSUPPORTED and an explanation naming the item, so the
ground station says why instead of flying a mission that silently skips what it asked for.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np
import shapely

from merlin.geodesy import LocalFrame
from merlin.link import outbound as o
from merlin.link.mission_transfer import (
    DEFAULT_MAX_ITEMS,
    MAV_MISSION_ACCEPTED,
    MAV_MISSION_DENIED,
    MAV_MISSION_ERROR,
    MAV_MISSION_INVALID,
    MAV_MISSION_INVALID_PARAM2,
    MAV_MISSION_INVALID_PARAM5_X,
    MAV_MISSION_INVALID_PARAM6_Y,
    MAV_MISSION_INVALID_PARAM7,
    MAV_MISSION_INVALID_SEQUENCE,
    MAV_MISSION_TYPE_MISSION,
    MAV_MISSION_UNSUPPORTED,
    MAV_MISSION_UNSUPPORTED_FRAME,
    ItemTransfer,
    WireItem,
)

MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_DO_CHANGE_SPEED = 178

MAV_FRAME_GLOBAL = 0
MAV_FRAME_MISSION = 2
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3
MAV_FRAME_GLOBAL_INT = 5
MAV_FRAME_GLOBAL_RELATIVE_ALT_INT = 6
_AMSL_FRAMES = frozenset({MAV_FRAME_GLOBAL, MAV_FRAME_GLOBAL_INT})
_RELATIVE_FRAMES = frozenset({MAV_FRAME_GLOBAL_RELATIVE_ALT, MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})
_POSITION_FRAMES = _AMSL_FRAMES | _RELATIVE_FRAMES

_COMMAND_NAMES = {
    MAV_CMD_NAV_WAYPOINT: "NAV_WAYPOINT", MAV_CMD_NAV_RETURN_TO_LAUNCH: "NAV_RETURN_TO_LAUNCH",
    MAV_CMD_NAV_LAND: "NAV_LAND", MAV_CMD_NAV_TAKEOFF: "NAV_TAKEOFF", MAV_CMD_DO_CHANGE_SPEED: "DO_CHANGE_SPEED",
}
#: Heights above home a mission may ask for: below home is underground, above 10 km is no drone's mission.
MAX_HEIGHT_M = 10_000.0
MAX_SPEED_MPS = 100.0


class MissionEnd(Enum):
    """What the trusted autopilot does after the last waypoint (the configuration's ``trusted.mission_end``)."""

    HOLD = "hold"
    RTL = "rtl"
    LAND = "land"


@dataclass(frozen=True, slots=True)
class MissionWaypoint:
    seq: int  # the item it came from
    pos_ned_m: tuple[float, float, float]
    speed_mps: float  # the leg towards it; NaN: cruise speed


@dataclass(frozen=True, slots=True)
class MissionPlan:
    """A mission as Merlin flies it, with the items it came from (served back on download)."""

    items: tuple[WireItem, ...] = ()
    waypoints: tuple[MissionWaypoint, ...] = ()
    end: MissionEnd = MissionEnd.HOLD
    end_seq: int = -1  # the RTL / LAND item, or -1

    @property
    def empty(self) -> bool:
        return not self.waypoints

    def seq_of(self, waypoint_index: int) -> int:
        """The item sequence number being flown at ``waypoint_index`` (past the last: the end item, else the
        last waypoint's)."""
        if 0 <= waypoint_index < len(self.waypoints):
            return self.waypoints[waypoint_index].seq
        if self.end_seq >= 0:
            return self.end_seq
        return self.waypoints[-1].seq if self.waypoints else 0

    def trusted_update(self) -> dict[str, Any]:
        """The configuration's ``trusted`` fields that fly this plan."""
        return {
            "mission_ned_m": [list(w.pos_ned_m) for w in self.waypoints],
            "mission_speed_mps": [0.0 if math.isnan(w.speed_mps) else w.speed_mps for w in self.waypoints],
            "mission_end": self.end.value,
        }


def _name(cmd: int) -> str:
    return _COMMAND_NAMES.get(cmd, f"command {cmd}")


def _has_position(it: WireItem) -> bool:
    return (math.isfinite(it.lat_deg) and math.isfinite(it.lon_deg)
            and not (it.lat_deg == 0.0 and it.lon_deg == 0.0))


def _position(k: int, it: WireItem, frame: LocalFrame) -> tuple[float, float, float] | tuple[int, str]:
    """The item's x/y/z in the local frame, or (MAV_MISSION_RESULT, explanation)."""
    what = f"item {k} ({_name(it.command)})"
    if it.frame not in _POSITION_FRAMES:
        return MAV_MISSION_UNSUPPORTED_FRAME, (f"{what}: frame {it.frame}; allowed: 0/5 (GLOBAL, AMSL) and 3/6 "
                                               f"(GLOBAL_RELATIVE_ALT)")
    if not (math.isfinite(it.lat_deg) and -90.0 <= it.lat_deg <= 90.0):
        return MAV_MISSION_INVALID_PARAM5_X, f"{what}: latitude {it.lat_deg} outside [-90, 90]"
    if not (math.isfinite(it.lon_deg) and -180.0 <= it.lon_deg <= 180.0):
        return MAV_MISSION_INVALID_PARAM6_Y, f"{what}: longitude {it.lon_deg} outside [-180, 180]"
    height = it.z - frame.alt0_amsl_m if it.frame in _AMSL_FRAMES else it.z
    if not (math.isfinite(height) and 0.0 < height <= MAX_HEIGHT_M):
        return MAV_MISSION_INVALID_PARAM7, f"{what}: height {height:.1f} m above home outside (0, {MAX_HEIGHT_M:g}]"
    n, e, _ = frame.to_ned(it.lat_deg, it.lon_deg)
    return n, e, -height


def decode_mission(items: tuple[WireItem, ...], frame: LocalFrame) -> MissionPlan | tuple[int, str]:
    """The plan the items describe (see module doc), or (MAV_MISSION_RESULT, explanation naming the item)."""
    wps: list[MissionWaypoint] = []
    speed = math.nan
    end, end_seq = MissionEnd.HOLD, -1
    for k, it in enumerate(items):
        what = f"item {k} ({_name(it.command)})"
        if end_seq >= 0:
            return MAV_MISSION_INVALID_SEQUENCE, (f"{what} follows item {end_seq} ({_name(items[end_seq].command)}), "
                                                  "which ends the mission")
        c = it.command
        if c in (MAV_CMD_NAV_WAYPOINT, MAV_CMD_NAV_TAKEOFF):
            if c == MAV_CMD_NAV_TAKEOFF and not _has_position(it):
                height = it.z - frame.alt0_amsl_m if it.frame in _AMSL_FRAMES else it.z
                if it.frame not in _POSITION_FRAMES or not (math.isfinite(height) and 0.0 < height <= MAX_HEIGHT_M):
                    return MAV_MISSION_INVALID_PARAM7, f"{what}: take-off height {it.z} (frame {it.frame})"
                # straight up from where the last leg ended (home before any)
                n, e = (wps[-1].pos_ned_m[0], wps[-1].pos_ned_m[1]) if wps else (0.0, 0.0)
                wps.append(MissionWaypoint(k, (n, e, -height), speed))
                continue
            pos = _position(k, it, frame)
            if len(pos) == 2:
                return pos
            wps.append(MissionWaypoint(k, pos, speed))
        elif c == MAV_CMD_DO_CHANGE_SPEED:
            v = it.param2
            if math.isnan(v) or v == -1.0:
                continue
            if not (0.0 < v <= MAX_SPEED_MPS):
                return MAV_MISSION_INVALID_PARAM2, f"{what}: speed {v} m/s outside (0, {MAX_SPEED_MPS:g}] (or -1)"
            speed = v
        elif c == MAV_CMD_NAV_RETURN_TO_LAUNCH:
            end, end_seq = MissionEnd.RTL, k
        elif c == MAV_CMD_NAV_LAND:
            if _has_position(it):
                if not wps:
                    return MAV_MISSION_INVALID_SEQUENCE, f"{what}: a landing needs a waypoint or take-off before it"
                pos = _position(k, WireItem(it.command, 0, 0, it.lat_deg, it.lon_deg, -wps[-1].pos_ned_m[2],
                                            MAV_FRAME_GLOBAL_RELATIVE_ALT), frame)
                if len(pos) == 2:
                    return pos
                wps.append(MissionWaypoint(k, pos, speed))
            end, end_seq = MissionEnd.LAND, k
        else:
            return MAV_MISSION_UNSUPPORTED, (f"{what} is not supported; Merlin flies NAV_WAYPOINT, NAV_TAKEOFF, "
                                             "NAV_LAND, NAV_RETURN_TO_LAUNCH and DO_CHANGE_SPEED")
    if items and not wps:
        return MAV_MISSION_INVALID, "the mission has no waypoint or take-off item"
    return MissionPlan(tuple(items), tuple(wps), end, end_seq)


def plan_from_config(
    mission_ned_m: Sequence[Sequence[float]], speeds_mps: Sequence[float], end: str, frame: LocalFrame
) -> MissionPlan:
    """The configuration's trusted mission (``trusted.mission_ned_m``, ``mission_speed_mps``,
    ``mission_end``) as mission items, so a ground station downloads what the vehicle would fly: a
    DO_CHANGE_SPEED before each leg whose speed changes, a NAV_WAYPOINT (relative altitude) per waypoint,
    then NAV_RETURN_TO_LAUNCH or NAV_LAND for an RTL or LAND end."""
    items: list[WireItem] = []
    wps: list[MissionWaypoint] = []
    current = math.nan
    for k, (n, e, d) in enumerate(mission_ned_m):
        v = float(speeds_mps[k]) if k < len(speeds_mps) and speeds_mps[k] > 0.0 else math.nan
        if not (v == current or (math.isnan(v) and math.isnan(current))):
            items.append(WireItem(MAV_CMD_DO_CHANGE_SPEED, 1.0, v if math.isfinite(v) else -1.0, 0.0, 0.0, 0.0,
                                  MAV_FRAME_MISSION, -1.0, 0.0))
            current = v
        lat, lon, _ = frame.to_geodetic(float(n), float(e))
        wps.append(MissionWaypoint(len(items), (float(n), float(e), float(d)), v))
        items.append(WireItem(MAV_CMD_NAV_WAYPOINT, 0.0, 0.0, lat, lon, -float(d), MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                              0.0, math.nan))
    mission_end, end_seq = MissionEnd(end), -1
    if wps and mission_end is not MissionEnd.HOLD:
        end_seq = len(items)
        cmd = MAV_CMD_NAV_RETURN_TO_LAUNCH if mission_end is MissionEnd.RTL else MAV_CMD_NAV_LAND
        items.append(WireItem(cmd, 0.0, 0.0, 0.0, 0.0, 0.0, MAV_FRAME_MISSION))
    return MissionPlan(tuple(items), tuple(wps), mission_end if wps else MissionEnd.HOLD, end_seq)


def check_legs_against_fence(
    plan: MissionPlan, fence: Any, margin_m: float, ceiling_m: float | None
) -> tuple[int, str] | None:
    """Why ``plan`` must be refused against ``fence`` (a :class:`merlin.core.geofence.Fence`, or None for no
    fence), or None. Each leg (home to the first waypoint, then waypoint to waypoint, and back home for RTL)
    must stay ``margin_m`` inside the inclusion zones and ``margin_m`` clear of every exclusion zone; each
    waypoint ``margin_m`` below the ceiling. The trusted autopilot flies straight legs, so a leg that passes
    this check is flown inside the fence; one that fails would trip the geofence monitor on the way."""
    if fence is None or plan.empty:
        return None
    points = [(0.0, 0.0)] + [(w.pos_ned_m[0], w.pos_ned_m[1]) for w in plan.waypoints]
    seqs = [-1] + [w.seq for w in plan.waypoints]
    if plan.end is MissionEnd.RTL:
        points.append((0.0, 0.0))
        seqs.append(plan.end_seq)
    allowed = fence.allowed_area if fence.has_inclusion else None  # inclusion zones less the keep-outs
    inner = shapely.buffer(allowed, -margin_m) if allowed is not None and margin_m > 0.0 else allowed
    if inner is not None:
        shapely.prepare(inner)
    excl = fence.exclusion_area
    # every leg at once (shapely's vectorised predicates, one C loop), then the first failing one is named
    legs = np.array([shapely.LineString([points[j - 1], points[j]]) if points[j - 1] != points[j]
                     else shapely.Point(points[j]) for j in range(1, len(points))], dtype=object)
    bad_excl = (shapely.dwithin(excl, legs, margin_m) | shapely.intersects(excl, legs)
                if excl is not None else np.zeros(len(legs), dtype=bool))
    bad_incl = ~shapely.covers(inner, legs) if inner is not None else np.zeros(len(legs), dtype=bool)
    for j in np.flatnonzero(bad_excl | bad_incl) + 1:
        seq = seqs[j]
        name = _name(plan.items[seq].command) if 0 <= seq < len(plan.items) else "leg"
        frm = "home" if seqs[j - 1] < 0 else f"item {seqs[j - 1]}"
        where = f"item {seq} ({name}): the leg from {frm}"
        if bad_excl[j - 1]:
            return MAV_MISSION_ERROR, f"{where} enters a keep-out zone (or passes within {margin_m:g} m of one)"
        return MAV_MISSION_ERROR, f"{where} leaves the fence (or passes within its {margin_m:g} m margin)"
    if ceiling_m is not None:
        for w in plan.waypoints:
            if -w.pos_ned_m[2] > ceiling_m - margin_m:
                return MAV_MISSION_ERROR, (f"item {w.seq} ({_name(plan.items[w.seq].command)}): height "
                                           f"{-w.pos_ned_m[2]:.1f} m is above the fence ceiling {ceiling_m:g} m "
                                           f"less its {margin_m:g} m margin")
    return None


def waypoint_at_or_after(plan: MissionPlan, seq: int) -> int:
    """The waypoint Merlin flies for item ``seq``: the first waypoint at or after it (an item between
    waypoints, DO_CHANGE_SPEED say, leads to the next one); past the last waypoint, the end (its length)."""
    for k, w in enumerate(plan.waypoints):
        if w.seq >= seq:
            return k
    return len(plan.waypoints)


def check_jump_against_fence(
    plan: MissionPlan, index: int, from_ne: tuple[float, float], fence: Any, margin_m: float
) -> str | None:
    """Why flying from ``from_ne`` straight to waypoint ``index`` of ``plan`` (MISSION_SET_CURRENT: a leg the
    upload check never saw) must be refused against ``fence``, or None. The end (``index`` past the last
    waypoint) is checked as the leg home for RTL; a LAND or HOLD end is flown where the vehicle is."""
    if fence is None or plan.empty:
        return None
    if index < len(plan.waypoints):
        w = plan.waypoints[index]
        to, seq = (w.pos_ned_m[0], w.pos_ned_m[1]), w.seq
    elif plan.end is MissionEnd.RTL:
        to, seq = (0.0, 0.0), plan.end_seq
    else:
        return None
    leg = shapely.LineString([from_ne, to]) if tuple(from_ne) != to else shapely.Point(to)
    name = _name(plan.items[seq].command) if 0 <= seq < len(plan.items) else "leg"
    where = f"item {seq} ({name}): the leg from ({from_ne[0]:.1f}, {from_ne[1]:.1f}) m"
    excl = fence.exclusion_area
    if excl is not None and (shapely.dwithin(excl, leg, margin_m) or shapely.intersects(excl, leg)):
        return f"{where} enters a keep-out zone (or passes within {margin_m:g} m of one)"
    allowed = fence.allowed_area if fence.has_inclusion else None
    if allowed is not None:
        inner = shapely.buffer(allowed, -margin_m) if margin_m > 0.0 else allowed
        if not shapely.covers(inner, leg):
            return f"{where} leaves the fence (or passes within its {margin_m:g} m margin)"
    return None


@dataclass(frozen=True, slots=True)
class MissionTransferResult:
    """How the latest transfer ended: ``result`` is a MAV_MISSION_RESULT, ``detail`` names the item at fault;
    ``plan`` the accepted mission (an upload to us, or a clear: an empty plan)."""

    upload: bool
    result: int
    detail: str = ""
    plan: MissionPlan | None = None


class MissionProtocol(ItemTransfer):
    """The vehicle's end of the waypoint mission protocol (and a client's, for tests and tools).

    ``check`` (set by the serve process) judges a decoded plan against what the vehicle knows now (the
    fence): None accepts it, (result, explanation) refuses it."""

    mission_type = MAV_MISSION_TYPE_MISSION

    def __init__(
        self,
        system_id: int,
        component_id: int,
        frame: LocalFrame,
        plan: MissionPlan | None = None,
        max_items: int = DEFAULT_MAX_ITEMS,
        timeout_s: float = 1.5,
        max_retries: int = 4,
    ) -> None:
        super().__init__(system_id, component_id, max_items, timeout_s, max_retries)
        self.frame = frame
        self.plan = plan or MissionPlan()
        self.check: Callable[[MissionPlan], tuple[int, str] | None] | None = None
        self.denied_reason = "while armed"
        self.results: list[MissionTransferResult] = []

    def take_results(self) -> list[MissionTransferResult]:
        out, self.results = self.results, []
        return out

    def start_upload(self, items: list[WireItem], target: tuple[int, int], t_s: float) -> list[o.OutMessage]:
        return self._start_upload_items(list(items), target, t_s)

    # the hooks of ItemTransfer

    def _items(self) -> list[WireItem]:
        return list(self.plan.items)

    def _decode(self, items: tuple[WireItem, ...]) -> tuple[int, str, object]:
        plan = decode_mission(items, self.frame)
        if not isinstance(plan, MissionPlan):
            return plan[0], plan[1], None
        if self.check is not None:
            refused = self.check(plan)
            if refused is not None:
                return refused[0], refused[1], None
        return MAV_MISSION_ACCEPTED, "", plan

    def _install(self, payload: object) -> None:
        assert isinstance(payload, MissionPlan)
        self.plan = payload

    def _clear(self, detail: str) -> None:
        self.plan = MissionPlan()
        self.results.append(MissionTransferResult(True, MAV_MISSION_ACCEPTED, detail, self.plan))

    def _record(self, upload: bool, result: int, detail: str, payload: object = None) -> None:
        plan = payload if isinstance(payload, MissionPlan) else None
        self.results.append(MissionTransferResult(upload, result, detail, plan))

    def _denied_detail(self) -> str:
        return f"mission uploads are refused {self.denied_reason}"


__all__ = [
    "MAV_CMD_DO_CHANGE_SPEED", "MAV_CMD_NAV_LAND", "MAV_CMD_NAV_RETURN_TO_LAUNCH", "MAV_CMD_NAV_TAKEOFF",
    "MAV_CMD_NAV_WAYPOINT", "MAV_MISSION_DENIED", "MissionEnd", "MissionPlan", "MissionProtocol",
    "MissionTransferResult", "MissionWaypoint", "check_jump_against_fence", "check_legs_against_fence",
    "decode_mission", "plan_from_config", "waypoint_at_or_after",
]
