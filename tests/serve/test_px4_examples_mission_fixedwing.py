"""A waypoint mission uploaded to ``merlin serve --vehicle aerosonde`` is flown by the fixed wing's own
mission stage (L1 legs at cruise airspeed): launched, then AUTO.MISSION, it passes the uploaded waypoints."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from merlin.geodesy import LocalFrame
from tests.serve.conftest import command, gcs_connection, start_serve, stop, wait_for
from tests.serve.test_px4_examples_mission import PX4_AUTO, PX4_MISSION, _home, _item, _px4_mode, _upload

pytestmark = pytest.mark.integration

WAYPOINTS_NE = ((600.0, 0.0), (600.0, 600.0), (0.0, 600.0))  # inside the fixed wing's 1.5 km range


def test_fixed_wing_flies_an_uploaded_mission(tmp_path: Path) -> None:
    sp = start_serve(tmp_path, "--vehicle", "aerosonde", "--rate-hz", "100", "--speedup", "4", duration_s=600.0)
    try:
        m = gcs_connection(sp.gcs_port)
        frame: LocalFrame = _home(m)
        items = [_item(frame, k, 16, n, e, 80.0) for k, (n, e) in enumerate(WAYPOINTS_NE)]
        assert _upload(m, items).type == 0
        assert command(m, 400, 1.0).result == 0  # arm
        assert command(m, 22, 0, 0, 0, math.nan, 0, 0, math.nan).result == 0  # launch
        climbing = wait_for(m, lambda x: x.get_type() == "GLOBAL_POSITION_INT" and x.relative_alt > 40_000)
        assert climbing is not None
        assert command(m, 176, 1.0, PX4_AUTO, PX4_MISSION).result == 0
        hb = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.type == 1 and _px4_mode(x) == (PX4_AUTO, PX4_MISSION))
        assert hb is not None
        closest = [math.inf] * len(WAYPOINTS_NE)
        for _ in range(1500):  # GLOBAL_POSITION_INT at 5 Hz on the GCS link, 4x real time: ~75 s of flight
            pos = wait_for(m, lambda x: x.get_type() == "GLOBAL_POSITION_INT")
            if pos is None:
                break
            n, e, _ = frame.to_ned(pos.lat / 1e7, pos.lon / 1e7)
            for k, (wn, we) in enumerate(WAYPOINTS_NE):
                closest[k] = min(closest[k], math.hypot(n - wn, e - we))
            if closest[-1] < 60.0:
                break
        assert all(c < 60.0 for c in closest), closest  # within an L1 turn of each uploaded waypoint
    finally:
        stop(sp)


def _distance_to(m: Any, frame: LocalFrame, ne: tuple[float, float]) -> float:
    pos = wait_for(m, lambda x: x.get_type() == "GLOBAL_POSITION_INT")
    assert pos is not None
    n, e, _ = frame.to_ned(pos.lat / 1e7, pos.lon / 1e7)
    return math.hypot(n - ne[0], e - ne[1])


def test_fixed_wing_mission_pause_resume_rtl_end_then_goto_and_orbit(tmp_path: Path) -> None:
    """As PX4's fixed wing: the mission's items reported reached, a pause (AUTO.LOITER) resumed at the item it
    was flying, the RTL end item flown and reported; then a reposition (DO_REPOSITION) loiters about its point
    and an orbit (DO_ORBIT) circles its centre, never tighter than the aircraft turns."""
    sp = start_serve(tmp_path, "--vehicle", "aerosonde", "--rate-hz", "100", "--speedup", "4", duration_s=900.0)
    try:
        m = gcs_connection(sp.gcs_port)
        frame: LocalFrame = _home(m)
        items = [_item(frame, k, 16, n, e, 80.0) for k, (n, e) in enumerate(WAYPOINTS_NE)]
        items.append(_item(frame, 3, 20, mav_frame=2))  # NAV_RETURN_TO_LAUNCH
        assert _upload(m, items).type == 0
        assert command(m, 400, 1.0).result == 0
        assert command(m, 22, 0, 0, 0, math.nan, 0, 0, math.nan).result == 0
        assert wait_for(m, lambda x: x.get_type() == "GLOBAL_POSITION_INT" and x.relative_alt > 40_000) is not None
        assert command(m, 176, 1.0, PX4_AUTO, PX4_MISSION).result == 0
        assert wait_for(m, lambda x: x.get_type() == "MISSION_ITEM_REACHED" and x.seq == 0, timeout_s=120) is not None
        assert command(m, 176, 1.0, PX4_AUTO, 3).result == 0  # pause: AUTO.LOITER
        paused = wait_for(m, lambda x: x.get_type() == "MISSION_CURRENT" and x.mission_state == 4)
        assert paused is not None and paused.seq == 1, paused
        assert command(m, 176, 1.0, PX4_AUTO, PX4_MISSION).result == 0  # resume at item 1
        cur = wait_for(m, lambda x: x.get_type() == "MISSION_CURRENT" and x.mission_state == 3)
        assert cur is not None and cur.seq == 1, cur
        for seq in (1, 2, 3):  # the RTL end item: reported as the return begins
            assert wait_for(m, lambda x, s=seq: x.get_type() == "MISSION_ITEM_REACHED" and x.seq == s,
                            timeout_s=120) is not None, seq
        rtl = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.type == 1 and _px4_mode(x) == (PX4_AUTO, 5))
        assert rtl is not None

        goto_ne = (-400.0, 300.0)
        lat, lon, _ = frame.to_geodetic(*goto_ne)
        # (the altitude is above mean sea level in every frame, as PX4 reads DO_REPOSITION: 90 m above home)
        m.mav.command_int_send(1, 1, 6, 192, 0, 0, -1, 1, 0, math.nan, round(lat * 1e7), round(lon * 1e7),
                               frame.alt0_amsl_m + 90.0)
        ack = wait_for(m, lambda x: x.get_type() == "COMMAND_ACK" and x.command == 192)
        assert ack is not None and ack.result == 0, ack
        radius = 120.0  # the stage's loiter radius
        dists = [_distance_to(m, frame, goto_ne) for _ in range(400)]  # 5 Hz, 4x: ~80 s of flight
        assert max(dists[-100:]) < radius + 40.0 and min(dists[-100:]) > radius - 40.0, dists[-100:]

        orbit_ne = (300.0, -300.0)
        lat, lon, _ = frame.to_geodetic(*orbit_ne)
        m.mav.command_long_send(1, 1, 34, 0, 50.0, 0.0, 0, math.nan, lat, lon, frame.alt0_amsl_m + 90.0)
        ack = wait_for(m, lambda x: x.get_type() == "COMMAND_ACK" and x.command == 34)
        assert ack is not None and ack.result == 0, ack
        dists = [_distance_to(m, frame, orbit_ne) for _ in range(400)]
        assert max(dists[-100:]) < radius + 40.0 and min(dists[-100:]) > radius - 40.0, dists[-100:]
        events = sp.events()
        assert [e["end"] for e in events if e["type"] == "fixed_wing_mission_end"] == ["rtl"]
    finally:
        stop(sp)
