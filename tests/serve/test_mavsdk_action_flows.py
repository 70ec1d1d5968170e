"""MAVSDK's Action plugin against ``merlin serve`` on both MAVSDK-Python bindings (gRPC ``mavsdk_grpc`` and the
native ``mavsdk`` 4.x): set_takeoff_altitude then takeoff, set_current_speed then goto_location, do_orbit,
reboot refused, kill (:mod:`tests.serve.mavsdk_action_flows`). The flow connects on the ground station's
link: PX4's parameters are written there, on the ground and disarmed (icd/ICD.md section 8.2)."""

from __future__ import annotations

import re

import pytest

from tests.ports import reserve_port
from tests.serve.conftest import ServeProc, lines_until

pytestmark = pytest.mark.integration


def _run(serve: ServeProc, binding: str) -> dict[str, str]:
    p = serve.spawn("-m", "tests.serve.mavsdk_action_flows", binding, f"udpin://0.0.0.0:{serve.gcs_port}",
                    str(reserve_port()))
    out = lines_until(p, "FLOW FINISHED", timeout_s=240)
    assert any("FLOW FINISHED" in x for x in out), "\n".join(out[-40:])
    return dict(m.groups() for x in out if (m := re.match(r"FLOW (\S+) (.*)$", x)))  # type: ignore[misc]


@pytest.mark.parametrize("binding", ["grpc", "native"])
def test_mavsdk_action_flow(serve: ServeProc, binding: str) -> None:
    if binding == "grpc":
        pytest.importorskip("mavsdk_grpc")
    got = _run(serve, binding)
    assert float(got["takeoff_altitude_param"]) == pytest.approx(5.0)
    assert float(got["altitude_after_takeoff_m"]) == pytest.approx(5.0, abs=0.6)  # MIS_TAKEOFF_ALT flown
    assert float(got["goto_fastest_mps"]) <= 2.0 * 1.15  # DO_CHANGE_SPEED 2 m/s held
    assert float(got["orbit_radius_min_m"]) >= 12.0 and float(got["orbit_radius_max_m"]) <= 18.0
    assert got["reboot"] != "accepted" and got["killed"] == "True"
    ev = serve.events()
    changed = [e for e in ev if e["type"] == "config_changed"]
    assert changed and changed[0]["param"] == "MIS_TAKEOFF_ALT" and changed[0]["new"] == 5.0
    kinds = [e.get("command") for e in ev if e["type"] == "command_ack"]
    assert {"TAKEOFF", "SPEED", "GOTO", "ORBIT", "DISARM"} <= set(kinds), kinds
