"""The MAVSDK example flows on the native ``mavsdk`` 4.x binding (:mod:`tests.serve.px4_examples_native`)
against a fresh ``merlin serve``: the twelve MAVSDK-Python examples, checked as their gRPC twins in
:mod:`tests.serve.test_px4_examples_grpc` (the two information flows share one serve: they change nothing)."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import pytest

from tests.serve.conftest import (
    STEP_TIMEOUT_S,
    ServeProc,
    gcs_connection,
    lines_until,
    refused_to_the_client,
    start_serve,
    stop,
    wait_for,
)
from tests.serve.px4_examples import PX4_HOME

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
    assert not refused_to_the_client(events), refused_to_the_client(events)
    # flown to its end inside the default envelope: no revocation
    assert not any(e["type"] == "revoked" for e in events), [e for e in events if e["type"] == "revoked"]


def _types(serve: ServeProc, kind: str) -> list[dict[str, Any]]:
    return [e for e in serve.events() if e["type"] == kind]


def _flown(serve: ServeProc, revoked_on: tuple[str, ...] = ()) -> None:
    """Granted, never refused to the example (tests.serve.conftest.refused_to_the_client), revoked only on
    ``revoked_on`` (the envelope parameters the example leaves)."""
    assert _types(serve, "granted"), "never granted OFFBOARD"
    assert not refused_to_the_client(serve.events()), refused_to_the_client(serve.events())
    revoked = _types(serve, "revoked")
    assert [(r["reason"], r["reason_detail"]["parameter"]) for r in revoked] == [
        ("envelope", p) for p in revoked_on], revoked


def test_native_firmware_version_and_all_params(serve: ServeProc) -> None:
    out = run_native(serve, "firmware_version", 60)
    assert "flight_sw_major" in out or "Version" in out, out[-2000:]
    out = run_native(serve, "all_params", 90)
    assert "IntParam" in out or "FloatParam" in out or "name" in out.lower(), out[-2000:]


def test_native_telemetry_takeoff_and_land(serve: ServeProc) -> None:
    out = run_native(serve, "telemetry_takeoff_and_land", 120)
    assert "Altitude: 10" in out or "Altitude: 9" in out, out[-2000:]


def test_native_offboard_position_ned(serve: ServeProc) -> None:
    run_native(serve, "offboard_position_ned", 120)  # its last setpoint is on the ground (the gRPC test's note)
    _flown(serve, revoked_on=("altitude_m",))


def test_native_offboard_velocity_body(serve: ServeProc) -> None:
    run_native(serve, "offboard_velocity_body", 150)
    _flown(serve)


def test_native_offboard_attitude(serve: ServeProc) -> None:
    run_native(serve, "offboard_attitude", 90)  # granted on the ground, 0.7 thrust revoked on vel_d (gRPC test)
    _flown(serve, revoked_on=("vel_d_mps",))
    assert "LAND" in _wait_behaviour(serve, "LAND")


def test_native_offboard_position_velocity_ned(serve: ServeProc) -> None:
    run_native(serve, "offboard_position_velocity_ned", 120)
    _flown(serve)


def test_native_do_orbit(serve: ServeProc) -> None:
    run_native(serve, "do_orbit", 150)
    assert "RTL" in _wait_behaviour(serve, "RTL")


def test_native_goto(tmp_path: Path) -> None:
    cfg = tmp_path / "range_1500m.yaml"
    lat, lon, alt = PX4_HOME
    cfg.write_text(f"home: {{lat_deg: {lat}, lon_deg: {lon}, alt_amsl_m: {alt}}}\n"
                   "geofence:\n  inclusion_circles: [{name: wide range, center_ne_m: [0, 0], radius_m: 1500}]\n")
    serve = start_serve(tmp_path, "--config", str(cfg))
    try:
        m = gcs_connection(serve.gcs_port)
        run_native(serve, "goto", 90)
        k = 111_320.0
        target = (47.399386, 8.535245)
        track = []
        t_end = time.monotonic() + 15.0
        while time.monotonic() < t_end:  # every report read as it arrives (the gRPC test's note)
            pos = wait_for(m, lambda x: x.get_type() == "GLOBAL_POSITION_INT", timeout_s=STEP_TIMEOUT_S)
            assert pos is not None
            track.append(math.hypot((pos.lat / 1e7 - target[0]) * k,
                                    (pos.lon / 1e7 - target[1]) * k * math.cos(math.radians(target[0]))))
        assert track[-1] < track[0] - 40.0, (track[0], track[-1])
    finally:
        stop(serve)
