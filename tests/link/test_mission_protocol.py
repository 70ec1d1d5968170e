"""The waypoint mission protocol: what items mean to Merlin, uploads and downloads over real MAVLink frames,
refusals that name the item, and the legs judged against the fence."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core import geofence
from merlin.geodesy import LocalFrame
from merlin.link import outbound as o
from merlin.link.link import MavlinkLink
from merlin.link.mission_protocol import (
    MAV_CMD_DO_CHANGE_SPEED,
    MAV_CMD_NAV_LAND,
    MAV_CMD_NAV_RETURN_TO_LAUNCH,
    MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_NAV_WAYPOINT,
    MissionEnd,
    MissionPlan,
    MissionProtocol,
    check_jump_against_fence,
    check_legs_against_fence,
    decode_mission,
    plan_from_config,
    waypoint_at_or_after,
)
from merlin.link.mission_transfer import (
    MAV_MISSION_ACCEPTED,
    MAV_MISSION_DENIED,
    MAV_MISSION_ERROR,
    MAV_MISSION_INVALID_SEQUENCE,
    MAV_MISSION_TYPE_MISSION,
    MAV_MISSION_UNSUPPORTED,
    MAV_MISSION_UNSUPPORTED_FRAME,
    WireItem,
)
from merlin.link.security import LinkPolicy
from tests.link.helpers import NOW_UNIX_S

VEH = (1, 1)
GCS = (255, 190)
HOME = LocalFrame(47.397742, 8.545594, 488.0)  # PX4 SITL's default home
REL = 6  # MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
NAN = math.nan


def wp(lat: float, lon: float, height_m: float, frame: int = REL) -> WireItem:
    return WireItem(MAV_CMD_NAV_WAYPOINT, 0.0, 1.0, lat, lon, height_m, frame, 0.0, NAN)


def speed(v: float) -> WireItem:
    return WireItem(MAV_CMD_DO_CHANGE_SPEED, 1.0, v, 0.0, 0.0, NAN, 2, -1.0, 0.0)


RTL = WireItem(MAV_CMD_NAV_RETURN_TO_LAUNCH, NAN, NAN, 0.0, 0.0, 0.0, 2, NAN, NAN)
# what MAVSDK's mission example uploads: three waypoints 25 m up at 10 m/s, and RTL after the mission
MAVSDK_EXAMPLE = (
    wp(47.398039859999997, 8.5455725400000002, 25), speed(10),
    wp(47.398036222362471, 8.5450146439425509, 25), speed(10),
    wp(47.397825620791885, 8.5450092830163271, 25), speed(10),
    RTL,
)


class Wire:
    """Two links facing each other, a MissionProtocol at each end; messages travel as encoded frames."""

    def __init__(self) -> None:
        self.veh_link = MavlinkLink(LinkPolicy("veh"), *VEH)
        self.gcs_link = MavlinkLink(LinkPolicy("gcs"), *GCS)
        self.veh = MissionProtocol(*VEH, HOME)
        self.gcs = MissionProtocol(*GCS, HOME)

    def run(self, first: list[o.OutMessage], t0: float = 0.0) -> None:
        outs, to_vehicle, t = first, True, t0
        for _ in range(1000):
            if not outs:
                return
            src, dst = (self.gcs_link, self.veh_link) if to_vehicle else (self.veh_link, self.gcs_link)
            proto = self.veh if to_vehicle else self.gcs
            replies: list[o.OutMessage] = []
            for out in outs:
                for frame in src.encode(out, NOW_UNIX_S + t):
                    for rx in dst.receive(frame, t, NOW_UNIX_S + t):
                        replies += proto.handle(rx, t)
            outs, to_vehicle = replies, not to_vehicle
            t += 0.01


def test_mavsdk_example_mission_uploads_and_means_three_legs_then_rtl() -> None:
    w = Wire()
    w.run(w.gcs.start_upload(list(MAVSDK_EXAMPLE), VEH, 0.0))
    [res] = w.veh.take_results()
    assert res.upload and res.result == MAV_MISSION_ACCEPTED, res
    plan = w.veh.plan
    assert plan.end is MissionEnd.RTL and plan.end_seq == 6
    assert [p.seq for p in plan.waypoints] == [0, 2, 4]
    n0, e0, d0 = plan.waypoints[0].pos_ned_m
    assert 33.0 < n0 < 34.0 and abs(e0) < 2.0 and d0 == -25.0  # 33 m north of home, 25 m up
    # DO_CHANGE_SPEED applies to the legs after it (MAVSDK: "speed to use after this mission item")
    assert math.isnan(plan.waypoints[0].speed_mps) and plan.waypoints[1].speed_mps == 10.0
    assert plan.trusted_update()["mission_end"] == "rtl"
    [gcs_res] = w.gcs.take_results()
    assert gcs_res.result == MAV_MISSION_ACCEPTED


def test_download_returns_what_was_uploaded() -> None:
    w = Wire()
    w.run(w.gcs.start_upload(list(MAVSDK_EXAMPLE), VEH, 0.0))
    w.veh.take_results()
    w.gcs.plan = MissionPlan()
    w.gcs.take_results()
    w.run(w.gcs.start_download(VEH, 1.0), t0=1.0)
    [res] = w.gcs.take_results()
    assert res.result == MAV_MISSION_ACCEPTED and res.plan is not None
    assert len(res.plan.items) == len(MAVSDK_EXAMPLE)
    for got, sent in zip(res.plan.items, MAVSDK_EXAMPLE, strict=True):
        assert (got.command, got.frame) == (sent.command, sent.frame)
        assert got.lat_deg == pytest.approx(sent.lat_deg, abs=1e-7) and got.lon_deg == pytest.approx(sent.lon_deg, abs=1e-7)


def test_an_unsupported_item_is_refused_naming_it() -> None:
    w = Wire()
    items = [*MAVSDK_EXAMPLE[:2], WireItem(183, 9.0, 1500.0, 0.0, 0.0, 0.0, 2), *MAVSDK_EXAMPLE[2:]]  # DO_SET_SERVO
    w.run(w.gcs.start_upload(items, VEH, 0.0))
    [res] = w.veh.take_results()
    assert res.result == MAV_MISSION_UNSUPPORTED
    assert "item 2 (command 183)" in res.detail
    assert w.veh.plan.empty  # nothing half-applied
    [gcs_res] = w.gcs.take_results()
    assert gcs_res.result == MAV_MISSION_UNSUPPORTED  # the ground station hears the refusal in MISSION_ACK


def test_items_after_the_end_and_unsupported_frames_are_refused() -> None:
    after_rtl = decode_mission((wp(47.398, 8.5456, 20), RTL, wp(47.398, 8.5450, 20)), HOME)
    assert isinstance(after_rtl, tuple) and after_rtl[0] == MAV_MISSION_INVALID_SEQUENCE and "item 2" in after_rtl[1]
    local = decode_mission((wp(47.398, 8.5456, 20, frame=1),), HOME)
    assert isinstance(local, tuple) and local[0] == MAV_MISSION_UNSUPPORTED_FRAME and "item 0" in local[1]
    underground = decode_mission((wp(47.398, 8.5456, 400.0, frame=0),), HOME)  # AMSL 400 m: below home (488 m)
    assert isinstance(underground, tuple) and "item 0" in underground[1]


def test_takeoff_land_and_amsl_frames() -> None:
    items = (
        WireItem(MAV_CMD_NAV_TAKEOFF, NAN, NAN, NAN, NAN, 12.0, REL),
        wp(47.398, 8.5456, 488.0 + 15.0, frame=0),  # AMSL
        WireItem(MAV_CMD_NAV_LAND, NAN, NAN, 47.3978, 8.5450, 0.0, REL),
    )
    plan = decode_mission(items, HOME)
    assert isinstance(plan, MissionPlan)
    assert plan.waypoints[0].pos_ned_m == (0.0, 0.0, -12.0)  # straight up from home
    assert plan.waypoints[1].pos_ned_m[2] == pytest.approx(-15.0)
    # LAND with a position: fly there at the height of the leg before, then land
    assert plan.waypoints[2].seq == 2 and plan.waypoints[2].pos_ned_m[2] == pytest.approx(-15.0)
    assert plan.end is MissionEnd.LAND and plan.end_seq == 2


def test_uploads_refused_while_not_accepted_say_why() -> None:
    w = Wire()
    w.veh.accept_uploads = False
    w.run(w.gcs.start_upload(list(MAVSDK_EXAMPLE), VEH, 0.0))
    [res] = w.veh.take_results()
    assert res.result == MAV_MISSION_DENIED and "while armed" in res.detail


def test_clear_forgets_the_mission() -> None:
    w = Wire()
    w.run(w.gcs.start_upload(list(MAVSDK_EXAMPLE), VEH, 0.0))
    assert not w.veh.plan.empty
    out = w.veh.handle_clear_all(GCS, MAV_MISSION_TYPE_MISSION)
    assert out == [o.MissionAckOut(*GCS, MAV_MISSION_ACCEPTED, MAV_MISSION_TYPE_MISSION)]
    assert w.veh.plan.empty


def test_the_configured_mission_reads_back_as_items() -> None:
    ned = [[20.0, 0.0, -10.0], [20.0, 20.0, -12.0], [0.0, 20.0, -12.0]]
    plan = plan_from_config(ned, [0.0, 3.0, 3.0], "rtl", HOME)
    again = decode_mission(plan.items, HOME)
    assert isinstance(again, MissionPlan)
    assert again.end is MissionEnd.RTL
    for a, b in zip(again.waypoints, plan.waypoints, strict=True):
        assert a.pos_ned_m == pytest.approx(b.pos_ned_m, abs=1e-3)
        assert (math.isnan(a.speed_mps) and math.isnan(b.speed_mps)) or a.speed_mps == b.speed_mps
    assert again.trusted_update()["mission_speed_mps"] == [0.0, 3.0, 3.0]


# ------------------------------------------------------------------------------------------ the fence


def _fence(radius_m: float = 100.0, keep_out: tuple[float, float, float] | None = None) -> geofence.Fence:
    geo: dict[str, object] = {"inclusion_circles": [{"center_ne_m": [0.0, 0.0], "radius_m": radius_m}], "margin_m": 5.0}
    if keep_out is not None:
        geo["exclusion_circles"] = [{"center_ne_m": [keep_out[0], keep_out[1]], "radius_m": keep_out[2]}]
    fence = build_core_config(MerlinConfig.model_validate({"geofence": geo})).fence
    assert fence is not None
    return fence


def _plan(*ned: tuple[float, float, float], end: MissionEnd = MissionEnd.HOLD) -> MissionPlan:
    items = tuple(wp(*HOME.to_geodetic(n, e)[:2], -d) for n, e, d in ned)
    if end is MissionEnd.RTL:
        items += (RTL,)
    plan = decode_mission(items, HOME)
    assert isinstance(plan, MissionPlan)
    return plan


def test_a_leg_leaving_the_fence_is_refused_naming_its_item() -> None:
    fence = _fence(100.0)
    assert check_legs_against_fence(_plan((50, 0, -20), (50, 50, -20)), fence, 5.0, 120.0) is None
    refused = check_legs_against_fence(_plan((50, 0, -20), (50, 97, -20)), fence, 5.0, 120.0)
    assert refused is not None and refused[0] == MAV_MISSION_ERROR
    assert "item 1 (NAV_WAYPOINT)" in refused[1] and "leaves the fence" in refused[1]


def test_a_leg_through_a_keep_out_is_refused_even_with_both_ends_clear() -> None:
    fence = _fence(200.0, keep_out=(40.0, 0.0, 10.0))
    refused = check_legs_against_fence(_plan((80, 0, -20)), fence, 5.0, 120.0)
    assert refused is not None and "item 0" in refused[1] and "keep-out" in refused[1]
    # the return leg of RTL is judged too
    refused = check_legs_against_fence(_plan((80, 40, -20), (80, 0, -20), end=MissionEnd.RTL), fence, 5.0, 120.0)
    assert refused is not None and "NAV_RETURN_TO_LAUNCH" in refused[1]


def test_a_waypoint_above_the_ceiling_is_refused() -> None:
    refused = check_legs_against_fence(_plan((10, 0, -118)), _fence(), 5.0, 120.0)
    assert refused is not None and "ceiling" in refused[1]


def test_the_serving_end_refuses_a_mission_its_check_refuses() -> None:
    w = Wire()
    fence = _fence(100.0)
    w.veh.check = lambda plan: check_legs_against_fence(plan, fence, 5.0, 120.0)
    far = HOME.to_geodetic(0.0, 300.0)
    w.run(w.gcs.start_upload([wp(far[0], far[1], 20)], VEH, 0.0))
    [res] = w.veh.take_results()
    assert res.result == MAV_MISSION_ERROR and "item 0" in res.detail and w.veh.plan.empty


_FENCE = _fence(100.0, keep_out=(30.0, 30.0, 15.0))
coord = st.floats(-140.0, 140.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(coord, coord), min_size=1, max_size=4))
def test_every_point_of_an_accepted_mission_is_inside_the_fence(points: list[tuple[float, float]]) -> None:
    """Safety invariant: the trusted autopilot flies straight legs; if the plan is accepted, every point of
    every leg (home first) is inside the fence and out of the keep-out."""
    plan = _plan(*((n, e, -20.0) for n, e in points))
    if check_legs_against_fence(plan, _FENCE, 5.0, 120.0) is not None:
        return
    path = [(0.0, 0.0)] + [w.pos_ned_m[:2] for w in plan.waypoints]
    for (an, ae), (bn, be) in itertools.pairwise(path):
        for k in range(21):
            f = k / 20.0
            n, e = an + f * (bn - an), ae + f * (be - ae)
            assert geofence.contains(_FENCE, (n, e, -20.0)), (n, e)
            assert math.hypot(n - 30.0, e - 30.0) > 15.0


def test_the_item_set_current_maps_to_the_waypoint_at_or_after_it() -> None:
    plan = decode_mission(MAVSDK_EXAMPLE, HOME)  # waypoints at items 0, 2, 4; speeds 1, 3, 5; RTL 6
    assert isinstance(plan, MissionPlan)
    assert [waypoint_at_or_after(plan, k) for k in range(7)] == [0, 1, 1, 2, 2, 3, 3]


def test_a_jump_whose_straight_leg_crosses_a_keep_out_is_refused_naming_the_item() -> None:
    """MISSION_SET_CURRENT makes a leg the upload never checked: from where the vehicle is to the item set."""
    fence = _fence(200.0, keep_out=(40.0, 0.0, 10.0))
    plan = _plan((80, 40, -20), (80, 0, -20), (0, 40, -20), end=MissionEnd.RTL)
    assert check_legs_against_fence(plan, fence, 5.0, 120.0) is None  # the uploaded legs are clear
    assert check_jump_against_fence(plan, 1, (80.0, 40.0), fence, 5.0) is None
    why = check_jump_against_fence(plan, 1, (0.0, 0.0), fence, 5.0)  # home straight to (80, 0): through it
    assert why is not None and "item 1 (NAV_WAYPOINT)" in why and "keep-out" in why
    why = check_jump_against_fence(plan, 3, (80.0, 0.0), fence, 5.0)  # the end: RTL's leg home
    assert why is not None and "NAV_RETURN_TO_LAUNCH" in why
    assert check_jump_against_fence(plan, 1, (150.0, 150.0), _fence(100.0), 5.0) is not None  # outside
    assert check_jump_against_fence(plan, 1, (0.0, 0.0), None, 5.0) is None
    assert check_jump_against_fence(_plan((10, 0, -20)), 1, (0.0, 0.0), fence, 5.0) is None  # HOLD end
