"""``merlin serve --vehicle aerosonde``: the JSBSim fixed wing behind the same MAVLink server as the multirotor,
driven by pymavlink as a ground station (a real subprocess on loopback, faster than real time).

The fixed wing starts on its catapult; arm, then MAV_CMD_NAV_TAKEOFF launches it (``sims/fixedwing_loop.py``),
it climbs out at cruise speed to the takeoff height and loiters; RTL brings it home.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.serve.conftest import command, gcs_connection, start_serve, stop, wait_for

pytestmark = pytest.mark.integration

MAV_TYPE_FIXED_WING = 1
PX4_AUTO = 4
PX4_AUTO_TAKEOFF, PX4_AUTO_LOITER, PX4_AUTO_RTL = 2, 3, 5
CRUISE_MPS = 22.0


def _mode(main: int, sub: int) -> int:
    return main << 16 | sub << 24


def _fw_heartbeat(x: object, mode: int | None = None) -> bool:
    return bool(x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1  # type: ignore[attr-defined]
                and (mode is None or x.custom_mode == mode))  # type: ignore[attr-defined]


def test_serve_flies_the_fixed_wing_launch_cruise_and_rtl(tmp_path: Path) -> None:
    sp = start_serve(tmp_path, "--vehicle", "aerosonde", "--rate-hz", "100", "--speedup", "4", duration_s=400.0)
    try:
        m = gcs_connection(sp.gcs_port)
        hb = wait_for(m, _fw_heartbeat)
        assert hb is not None and hb.type == MAV_TYPE_FIXED_WING
        on_rail = wait_for(m, lambda x: x.get_type() == "VFR_HUD")
        assert on_rail is not None and on_rail.airspeed == pytest.approx(0.0, abs=0.5)  # resting on the catapult
        ack = command(m, 400, 1.0)  # ARM
        assert ack is not None and ack.result == 0, ack
        ack = command(m, 22, 0, 0, 0, float("nan"), 0, 0, float("nan"))  # TAKEOFF: fires the catapult
        assert ack is not None and ack.result == 0, ack
        assert wait_for(m, lambda x: _fw_heartbeat(x, _mode(PX4_AUTO, PX4_AUTO_TAKEOFF))) is not None
        # climbing out at cruise speed
        climbing = wait_for(m, lambda x: x.get_type() == "GLOBAL_POSITION_INT" and x.relative_alt > 30_000)
        assert climbing is not None, "never climbed above 30 m after the launch"
        hud = wait_for(m, lambda x: x.get_type() == "VFR_HUD")
        assert hud is not None and hud.airspeed == pytest.approx(CRUISE_MPS, abs=2.5)
        assert hud.throttle > 20  # percent: the motor runs
        # the takeoff ends in a loiter (HOLD) at the takeoff height
        assert wait_for(m, lambda x: _fw_heartbeat(x, _mode(PX4_AUTO, PX4_AUTO_LOITER))) is not None
        ack = command(m, 20)  # MAV_CMD_NAV_RETURN_TO_LAUNCH
        assert ack is not None and ack.result == 0, ack
        rtl = wait_for(m, lambda x: _fw_heartbeat(x, _mode(PX4_AUTO, PX4_AUTO_RTL)))
        assert rtl is not None and rtl.type == MAV_TYPE_FIXED_WING
        hud = wait_for(m, lambda x: x.get_type() == "VFR_HUD")
        assert hud is not None and hud.airspeed == pytest.approx(CRUISE_MPS, abs=2.5)
        m.close()
    finally:
        stop(sp)
    events = sp.events()
    # the fusion EKF navigates (started again in the air at the catapult's release), and serve says so
    assert next(e for e in events if e["type"] == "serve_start")["estimator"] == "ekf"
    assert next(e for e in events if e["type"] == "serve_stop")["estimator"] == "ekf"
    behaviours = [e["behavior"] for e in events if e["type"] == "behavior"]
    assert behaviours[-3:] == ["TAKEOFF", "HOLD", "RTL"], behaviours
    assert not [e for e in events if e["type"] == "monitor_tripped" and e.get("monitor") == "geofence"]

