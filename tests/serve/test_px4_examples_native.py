"""The MAVSDK example flows on the native ``mavsdk`` 4.x binding (:mod:`tests.serve.px4_examples_native`)
against a fresh ``merlin serve``: the mission (upload, start on the ground, RTL after it, back on the
ground), take-off and land, and offboard velocity NED."""

from __future__ import annotations

import time

import pytest

from tests.serve.conftest import ServeProc, lines_until

pytest.importorskip("mavsdk.asyncio", reason="the native MAVSDK binding (mavsdk 4.x) runs these flows")
pytestmark = pytest.mark.integration

FINISHED = "EXAMPLE FINISHED"


def run_native(serve: ServeProc, name: str, timeout_s: float) -> str:
    p = serve.spawn("-m", "tests.serve.px4_examples_native", name, f"udpin://0.0.0.0:{serve.ctl_port}")
    out = "\n".join(lines_until(p, FINISHED, timeout_s))
    assert FINISHED in out, f"{name} did not run to its end:\n{out[-3000:]}"
    assert "failed with error code" not in out, out[-3000:]
    return out


def _behaviours(serve: ServeProc) -> list[str]:
    return [e["behavior"] for e in serve.events() if e["type"] == "behavior"]


def _wait_behaviour(serve: ServeProc, behaviour: str, timeout_s: float = 10.0) -> list[str]:
    t_end = time.monotonic() + timeout_s  # the program may exit a tick before the behaviour is recorded
    while behaviour not in _behaviours(serve) and time.monotonic() < t_end:
        time.sleep(0.2)
    return _behaviours(serve)


def test_native_mission(serve: ServeProc) -> None:
    out = run_native(serve, "mission", 170)
    assert "Mission progress: 3/3" in out, out[-2000:]
    assert _behaviours(serve)[:3] == ["TAKEOFF", "MISSION", "RTL"]


def test_native_takeoff_and_land(serve: ServeProc) -> None:
    run_native(serve, "takeoff_and_land", 90)
    b = _wait_behaviour(serve, "LAND")
    assert "TAKEOFF" in b and "LAND" in b, b


def test_native_offboard_velocity_ned(serve: ServeProc) -> None:
    run_native(serve, "offboard_velocity_ned", 120)
    events = serve.events()
    assert any(e["type"] == "granted" for e in events)
    assert not any(e["type"] == "denied" for e in events)
    # flown to its end inside the default envelope: no revocation
    assert not any(e["type"] == "revoked" for e in events), [e for e in events if e["type"] == "revoked"]
