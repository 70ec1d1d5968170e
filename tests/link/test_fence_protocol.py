"""The fence mission protocol: upload and download between two instances over real MAVLink frames."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.config.models import GeofenceConfig
from merlin.geodesy import LocalFrame
from merlin.link import inbound as i
from merlin.link import outbound as o
from merlin.link.fence_protocol import (
    MAV_MISSION_ACCEPTED,
    MAV_MISSION_DENIED,
    MAV_MISSION_INVALID_PARAM1,
    MAV_MISSION_NO_SPACE,
    MAV_MISSION_OPERATION_CANCELLED,
    FenceCircleLL,
    FenceDescription,
    FenceItem,
    FencePolygonLL,
    FenceProtocol,
)
from merlin.link.link import MavlinkLink
from merlin.link.security import LinkPolicy
from tests.link.helpers import NOW_UNIX_S

VEH = (1, 1)
GCS = (255, 190)
FENCE = FenceDescription(
    polygons=(
        FencePolygonLL(((29.650, -82.330), (29.655, -82.330), (29.655, -82.320), (29.650, -82.320)), True, 0),
        FencePolygonLL(((29.6520, -82.3260), (29.6525, -82.3260), (29.6525, -82.3255)), False),
    ),
    circles=(FenceCircleLL((29.6516, -82.3248), 300.0, True, 1), FenceCircleLL((29.6530, -82.3240), 25.0, False)),
    return_point=(29.6516, -82.3248, 30.0),
)


class Wire:
    """Two links facing each other, each with a FenceProtocol; messages travel as encoded frames."""

    def __init__(self) -> None:
        self.veh_link = MavlinkLink(LinkPolicy("veh"), *VEH)
        self.gcs_link = MavlinkLink(LinkPolicy("gcs"), *GCS)
        self.veh = FenceProtocol(*VEH)
        self.gcs = FenceProtocol(*GCS)
        self.sent = 0

    def deliver(self, outs: list[o.OutMessage], to_vehicle: bool, t_s: float, drop: set[int] | None = None) -> list[o.OutMessage]:
        src, dst = (self.gcs_link, self.veh_link) if to_vehicle else (self.veh_link, self.gcs_link)
        proto = self.veh if to_vehicle else self.gcs
        replies: list[o.OutMessage] = []
        for out in outs:
            self.sent += 1
            if drop and self.sent in drop:
                continue
            for frame in src.encode(out, NOW_UNIX_S + t_s):
                for rx in dst.receive(frame, t_s, NOW_UNIX_S + t_s):
                    replies += proto.handle(rx, t_s)
        return replies

    def run(self, first: list[o.OutMessage], from_gcs: bool = True, drop: set[int] | None = None,
            t0: float = 0.0) -> None:
        outs, to_vehicle, t = first, from_gcs, t0
        for _ in range(2000):
            if outs:
                outs = self.deliver(outs, to_vehicle, t, drop)
                to_vehicle = not to_vehicle
                continue
            t += 0.5
            if not (self.veh.busy or self.gcs.busy):
                return
            outs = self.gcs.tick(t)
            to_vehicle = True
            if not outs:
                outs = self.veh.tick(t)
                to_vehicle = False


def test_upload_then_download_round_trip() -> None:
    w = Wire()
    w.run(w.gcs.start_upload(FENCE, VEH, 0.0))
    assert w.veh.fence == FENCE
    up = w.veh.take_results()
    assert [(r.upload, r.result) for r in up] == [(True, MAV_MISSION_ACCEPTED)]
    assert up[0].fence == FENCE
    assert w.gcs.take_results()[0].result == MAV_MISSION_ACCEPTED

    w2 = Wire()
    w2.veh.fence = FENCE
    w2.run(w2.gcs.start_download(VEH, 0.0))
    got = w2.gcs.take_results()
    assert [(r.upload, r.result) for r in got] == [(False, MAV_MISSION_ACCEPTED)]
    assert got[0].fence == FENCE
    assert not w2.veh.busy


def test_lost_messages_are_retried() -> None:
    w = Wire()
    w.run(w.gcs.start_upload(FENCE, VEH, 0.0), drop={2, 5, 9})
    assert w.veh.fence == FENCE
    assert w.veh.take_results()[-1].result == MAV_MISSION_ACCEPTED


def test_silent_peer_times_out_with_cancel() -> None:
    veh = FenceProtocol(*VEH, timeout_s=1.0, max_retries=3)
    rx = i.Received(0.0, "gcs", *GCS, False, i.MissionCountIn(1, 1, 4, 1))
    out = veh.handle(rx, 0.0)
    assert isinstance(out[0], o.MissionRequestIntOut) and out[0].seq == 0
    resent = [veh.tick(t) for t in (0.5, 1.0, 2.0, 3.0)]
    assert [len(r) for r in resent] == [0, 1, 1, 1]
    final = veh.tick(4.0)
    assert isinstance(final[0], o.MissionAckOut) and final[0].result == MAV_MISSION_OPERATION_CANCELLED
    assert not veh.busy and veh.counters["timeouts"] == 1
    assert veh.fence == FenceDescription()  # nothing half-applied


def test_out_of_order_item_re_requests_the_expected_one() -> None:
    veh = FenceProtocol(*VEH)
    veh.handle(i.Received(0.0, "gcs", *GCS, False, i.MissionCountIn(1, 1, 2, 1)), 0.0)
    item = i.MissionItemIntIn(1, 1, 1, 0, 5003, 0, 1, 50.0, 0, 0, 0, 29.6, -82.3, 0, 1)
    out = veh.handle(i.Received(0.1, "gcs", *GCS, False, item), 0.1)
    assert isinstance(out[0], o.MissionRequestIntOut) and out[0].seq == 0


def test_items_from_another_peer_during_a_transfer_are_ignored() -> None:
    veh = FenceProtocol(*VEH)
    veh.handle(i.Received(0.0, "gcs", *GCS, False, i.MissionCountIn(1, 1, 1, 1)), 0.0)
    item = i.MissionItemIntIn(1, 1, 0, 0, 5003, 0, 1, 50.0, 0, 0, 0, 29.6, -82.3, 0, 1)
    assert veh.handle(i.Received(0.1, "gcs", 7, 7, False, item), 0.1) == []
    assert veh.counters["unexpected"] == 1
    other = veh.handle(i.Received(0.1, "gcs", 7, 7, False, i.MissionCountIn(1, 1, 1, 1)), 0.1)
    assert other[0].result == MAV_MISSION_DENIED


def test_absurd_count_and_invalid_items() -> None:
    veh = FenceProtocol(*VEH, max_items=10)
    out = veh.handle(i.Received(0.0, "gcs", *GCS, False, i.MissionCountIn(1, 1, 11, 1)), 0.0)
    assert out[0].result == MAV_MISSION_NO_SPACE and not veh.busy
    w = Wire()
    bad = FenceDescription(circles=(FenceCircleLL((29.6, -82.3), 300.0, True),))
    items = list(bad.to_items())
    items[0] = FenceItem(5003, -5.0, 0.0, 29.6, -82.3)  # negative radius
    w.gcs._t = None
    outs = w.gcs.start_upload(bad, VEH, 0.0)
    w.gcs._t.items = items  # type: ignore[union-attr]  # a misbehaving client
    w.run(outs)
    res = w.veh.take_results()[-1]
    assert res.result == MAV_MISSION_INVALID_PARAM1 and "radius" in res.detail
    assert w.veh.fence == FenceDescription()


def test_uploads_refused_when_not_accepted() -> None:
    veh = FenceProtocol(*VEH)
    veh.accept_uploads = False
    out = veh.handle(i.Received(0.0, "gcs", *GCS, False, i.MissionCountIn(1, 1, 3, 1)), 0.0)
    assert out[0].result == MAV_MISSION_DENIED
    out = veh.handle(i.Received(0.0, "gcs", *GCS, False, i.MissionClearAllIn(1, 1, 1)), 0.0)
    assert out[0].result == MAV_MISSION_DENIED


def test_other_mission_types_get_minimal_answers() -> None:
    veh = FenceProtocol(*VEH)
    out = veh.handle(i.Received(0.0, "gcs", *GCS, False, i.MissionRequestListIn(1, 1, 0)), 0.0)
    assert isinstance(out[0], o.MissionCountOut) and out[0].count == 0 and out[0].mission_type == 0
    out = veh.handle(i.Received(0.0, "gcs", *GCS, False, i.MissionCountIn(1, 1, 5, 2)), 0.0)
    assert out[0].result == 3  # MAV_MISSION_UNSUPPORTED


def test_clear_all_fence() -> None:
    veh = FenceProtocol(*VEH, fence=FENCE)
    out = veh.handle(i.Received(0.0, "gcs", *GCS, False, i.MissionClearAllIn(1, 1, 1)), 0.0)
    assert out[0].result == MAV_MISSION_ACCEPTED and veh.fence == FenceDescription()


def test_apply_to_configuration_and_back() -> None:
    cfg = FENCE.apply_to(GeofenceConfig())
    assert len(cfg.inclusion_polygons) == 1 and len(cfg.exclusion_polygons) == 1
    assert len(cfg.inclusion_circles) == 1 and cfg.exclusion_circles[0].radius_m == 25.0
    assert cfg.margin_m == GeofenceConfig().margin_m
    back = FenceDescription.from_config(cfg, LocalFrame(29.6516, -82.3248, 30.0))
    assert {p.vertices_deg for p in back.polygons} == {p.vertices_deg for p in FENCE.polygons}
    # the default configuration's circle is given in metres about home
    default = FenceDescription.from_config(GeofenceConfig(), LocalFrame(29.6516, -82.3248, 30.0))
    assert default.circles[0].center_deg == pytest.approx((29.6516, -82.3248))


latlon = st.tuples(st.floats(-89.0, 89.0), st.floats(-179.0, 179.0))


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.lists(latlon, min_size=3, max_size=8), st.booleans()), max_size=4),
    st.lists(st.tuples(latlon, st.floats(0.5, 1e5), st.booleans()), max_size=4),
)
def test_items_round_trip(polys: list[Any], circles: list[Any]) -> None:
    fence = FenceDescription(
        tuple(FencePolygonLL(tuple(v), inc, 0) for v, inc in polys),
        tuple(FenceCircleLL(c, r, inc, 0) for c, r, inc in circles),
    )
    assert FenceDescription.from_items(fence.to_items()) == fence
