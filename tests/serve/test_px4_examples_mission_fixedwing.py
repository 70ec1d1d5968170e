"""A waypoint mission uploaded to ``merlin serve --vehicle aerosonde`` is flown by the fixed wing's own
mission stage (L1 legs at cruise airspeed): launched, then AUTO.MISSION, it passes the uploaded waypoints."""

from __future__ import annotations

import math
from pathlib import Path

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
