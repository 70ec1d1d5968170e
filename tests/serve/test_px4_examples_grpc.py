"""MAVSDK-Python's example programs run unchanged against a fresh ``merlin serve``, as against PX4 SITL.

Each test starts ``merlin serve`` with no arguments but its ports (PX4 SITL's conventions: its home is the
examples' home), runs one program of :mod:`tests.serve.px4_examples` (the calls, order and waits of the
MAVSDK-Python example of the same name, on the gRPC ``mavsdk_grpc`` package) on the offboard port, and
checks that it ran to its end with no error and that the vehicle did what PX4 would have done. The last test
shows the supervision on an unchanged program: with a fence uploaded, the offboard example flying outward
is revoked (the mode leaves OFFBOARD) and the vehicle stays inside.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import pytest

from tests.ports import reserve_port
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

pytest.importorskip("mavsdk_grpc", reason="the gRPC MAVSDK-Python (pip install mavsdk-grpc) runs the examples")
pytestmark = pytest.mark.integration

FINISHED = "EXAMPLE FINISHED"


def run_example(serve: ServeProc, name: str, timeout_s: float) -> str:
    """Run the program ``name`` to its end; its whole output."""
    p = serve.spawn("-m", "tests.serve.px4_examples", name, f"udpin://0.0.0.0:{serve.ctl_port}",
                    str(reserve_port()))
    out = "\n".join(lines_until(p, FINISHED, timeout_s))
    assert FINISHED in out, f"{name} did not run to its end:\n{out[-3000:]}"
    assert "failed with error code" not in out, out[-3000:]
    return out


def _types(serve: ServeProc, kind: str) -> list[dict[str, Any]]:
    return [e for e in serve.events() if e["type"] == kind]


def _behaviours(serve: ServeProc) -> list[str]:
    return [e["behavior"] for e in _types(serve, "behavior")]


def _wait_behaviour(serve: ServeProc, behaviour: str, timeout_s: float = 10.0) -> list[str]:
    """The behaviours so far, once ``behaviour`` is among them (an example may exit the moment its last
    command is acknowledged, a tick before the behaviour's record is written) or the time is up."""
    t_end = time.monotonic() + timeout_s
    while behaviour not in _behaviours(serve) and time.monotonic() < t_end:
        time.sleep(0.2)
    return _behaviours(serve)


def _check_offboard_flown(serve: ServeProc, revoked_on: tuple[str, ...] = ()) -> None:
    """Granted, and flown to the example's end without a revocation: its commands are legitimate PX4
    offboard commands, and Merlin's trusted loops fly them inside the default envelope. ``revoked_on``: the
    envelope parameters the example's own commands leave (its revocation is the supervision working)."""
    assert _types(serve, "granted"), "never granted OFFBOARD"
    assert not refused_to_the_client(serve.events()), refused_to_the_client(serve.events())
    revoked = _types(serve, "revoked")
    assert [(r["reason"], r["reason_detail"]["parameter"]) for r in revoked] == [
        ("envelope", p) for p in revoked_on], revoked


def test_home_is_px4_sitl_home(serve: ServeProc) -> None:
    m = gcs_connection(serve.gcs_port)
    home = wait_for(m, lambda x: x.get_type() == "HOME_POSITION")
    assert home is not None
    assert (home.latitude / 1e7, home.longitude / 1e7) == pytest.approx(PX4_HOME[:2], abs=1e-6)
    assert home.altitude / 1e3 == pytest.approx(PX4_HOME[2], abs=0.1)


def test_firmware_version(serve: ServeProc) -> None:
    run_example(serve, "firmware_version", 60)


def test_all_params(serve: ServeProc) -> None:
    out = run_example(serve, "all_params", 90)
    assert "name:" in out.lower() or "IntParam" in out or "FloatParam" in out, out[-2000:]


def test_offboard_velocity_ned(serve: ServeProc) -> None:
    run_example(serve, "offboard_velocity_ned", 120)
    _check_offboard_flown(serve)


def test_offboard_position_ned(serve: ServeProc) -> None:
    # its last setpoint is 0 m down (on the ground): below the conservative stage's 3 m altitude limit, so
    # the descent towards it is revoked once under 3 m for 0.5 s (PX4 would fly it down); every leg before
    # it is flown inside the envelope
    run_example(serve, "offboard_position_ned", 120)
    _check_offboard_flown(serve, revoked_on=("altitude_m",))


def test_offboard_velocity_body(serve: ServeProc) -> None:
    run_example(serve, "offboard_velocity_body", 150)
    _check_offboard_flown(serve)


def test_offboard_attitude(serve: ServeProc) -> None:
    """MAVSDK's offboard_attitude example arms and starts OFFBOARD on the ground with an attitude setpoint; on
    PX4 its thrust lifts the vehicle. Merlin grants it as PX4 does, supervised (icd/ICD.md 6.1): the altitude
    floors judge it once the vehicle is above them, everything else from the first tick. The example's "up at
    70 % thrust" is PX4 SITL's quadrotor climbing gently (it hovers near 0.6); Merlin's default quadrotor hovers
    at 0.5, so 0.7 climbs beyond the conservative stage's 3 m/s and the envelope revokes it on vel_d (the
    supervision working on an unchanged program): Merlin's trusted autopilot brakes and flies the example's
    later hold and land. The program runs to its end."""
    m = gcs_connection(serve.gcs_port)
    p = serve.spawn("-m", "tests.serve.px4_examples", "offboard_attitude", f"udpin://0.0.0.0:{serve.ctl_port}",
                    str(reserve_port()))
    highest = 0.0
    t_end = time.monotonic() + 90.0
    while time.monotonic() < t_end and p.poll() is None:
        pos = wait_for(m, lambda x: x.get_type() == "GLOBAL_POSITION_INT", timeout_s=STEP_TIMEOUT_S)
        if pos is not None:
            highest = max(highest, pos.relative_alt / 1e3)
    out = "\n".join(lines_until(p, FINISHED, 30))
    assert FINISHED in out, out[-3000:]
    assert "failed with error code" not in out, out[-3000:]
    [granted] = _types(serve, "granted")
    [attitude] = [e for e in _types(serve, "offboard_takeoff") if e["phase"] == "attitude"]
    assert granted["t"] >= attitude["t"]
    assert highest > 3.0, highest  # lifted off on the controller's thrust, through the envelope's 3 m floor
    _check_offboard_flown(serve, revoked_on=("vel_d_mps",))
    assert "LAND" in _wait_behaviour(serve, "LAND")


def test_offboard_position_velocity_ned(serve: ServeProc) -> None:
    run_example(serve, "offboard_position_velocity_ned", 120)
    _check_offboard_flown(serve)


def test_takeoff_and_land(serve: ServeProc) -> None:
    run_example(serve, "takeoff_and_land", 90)
    b = _wait_behaviour(serve, "LAND")
    assert "TAKEOFF" in b and "LAND" in b, b


def test_telemetry_takeoff_and_land(serve: ServeProc) -> None:
    out = run_example(serve, "telemetry_takeoff_and_land", 120)  # it returns once landed
    assert "Altitude: 10" in out or "Altitude: 9" in out, out[-2000:]


def test_mission(serve: ServeProc) -> None:
    """Upload, arm, start on the ground: Merlin takes off, flies the three waypoints, returns (MAVSDK's
    set_return_to_launch_after_mission) and lands; the program returns once the vehicle is down."""
    out = run_example(serve, "mission", 170)
    assert "Mission progress: 3/3" in out, out[-2000:]
    [applied] = _types(serve, "mission_applied")
    assert applied["waypoints"] == 3 and applied["end"] == "rtl"
    b = _behaviours(serve)
    assert b[:3] == ["TAKEOFF", "MISSION", "RTL"], b


def _distance_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    k = 111_320.0
    return math.hypot((lat2 - lat1) * k, (lon2 - lon1) * k * math.cos(math.radians(lat1)))


def test_goto(tmp_path: Path) -> None:
    """The goto example's target is 780 m from home, beyond Merlin's built-in 300 m range: against a range that
    holds it (PX4 SITL has no fence at all), the unchanged example flies there. Its goto_location comes 1 s
    after takeoff(), 0.1 m up: as on PX4 (the DO_REPOSITION switches to AUTO.LOITER, whose hold point is the
    target), the vehicle climbs to the goto altitude (20 m above home) and flies towards the target."""
    cfg = tmp_path / "range_1500m.yaml"
    lat, lon, alt = PX4_HOME  # (a configuration file states its home; PX4 SITL's, as serve's default)
    cfg.write_text(f"home: {{lat_deg: {lat}, lon_deg: {lon}, alt_amsl_m: {alt}}}\n"
                   "geofence:\n  inclusion_circles: [{name: wide range, center_ne_m: [0, 0], radius_m: 1500}]\n")
    serve = start_serve(tmp_path, "--config", str(cfg))
    try:
        m = gcs_connection(serve.gcs_port)
        run_example(serve, "goto", 90)
        target = (47.399386, 8.535245)
        # followed as it flies: every position report read as it arrives (a reading taken after a sleep would
        # be the oldest report waiting in the socket's buffer, not the vehicle's position)
        track: list[tuple[float, float]] = []
        t_end = time.monotonic() + 20.0
        while time.monotonic() < t_end:
            pos = wait_for(m, lambda x: x.get_type() == "GLOBAL_POSITION_INT", timeout_s=STEP_TIMEOUT_S)
            assert pos is not None
            track.append((_distance_m(pos.lat / 1e7, pos.lon / 1e7, *target), pos.relative_alt / 1e3))
        assert track[-1][0] < track[0][0] - 60.0, (track[0], track[-1])
        assert max(h for _, h in track) == pytest.approx(20.0, abs=1.5), max(h for _, h in track)
        assert [b for b in _behaviours(serve) if b != "TAKEOFF"][:1] == ["HOLD"], _behaviours(serve)
        [goto] = [e for e in _types(serve, "command_ack") if e["command"] == "GOTO"]
        assert goto["accepted"], goto
    finally:
        stop(serve)


def test_goto_beyond_the_range_is_denied(serve: ServeProc) -> None:
    """With the built-in 300 m range the same program's goto_location is denied (Merlin's trusted autopilot
    never flies out of its fence; section 13 of the ICD): the example stops there with PX4's error."""
    p = serve.spawn("-m", "tests.serve.px4_examples", "goto", f"udpin://0.0.0.0:{serve.ctl_port}",
                    str(reserve_port()))
    out = "\n".join(lines_until(p, "COMMAND_DENIED", 90))
    assert "goto_location" in out and "COMMAND_DENIED" in out, out[-2000:]


def test_do_orbit(serve: ServeProc) -> None:
    run_example(serve, "do_orbit", 150)
    assert "RTL" in _wait_behaviour(serve, "RTL")


def _upload_circle_fence(m: Any, lat: float, lon: float, radius_m: float) -> None:
    m.mav.mission_count_send(1, 1, 1, 1)  # one item, MAV_MISSION_TYPE_FENCE
    req = wait_for(m, lambda x: x.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST") and x.mission_type == 1)
    assert req is not None and req.seq == 0
    m.mav.mission_item_int_send(1, 1, 0, 0, 5003, 0, 1, radius_m, 0.0, 0.0, 0.0, round(lat * 1e7), round(lon * 1e7),
                                0.0, 1)  # MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION
    ack = wait_for(m, lambda x: x.get_type() == "MISSION_ACK" and x.mission_type == 1)
    assert ack is not None and ack.type == 0, ack


def test_offboard_example_flying_out_of_an_uploaded_fence_is_revoked_and_stays_inside(serve: ServeProc) -> None:
    """offboard_position_velocity_ned flies 50 m north; with a 25 m fence around home uploaded first, Merlin
    takes authority back (the program sees the mode leave OFFBOARD) and the vehicle never leaves the fence."""
    m = gcs_connection(serve.gcs_port)
    home = wait_for(m, lambda x: x.get_type() == "HOME_POSITION")
    assert home is not None
    lat0, lon0 = home.latitude / 1e7, home.longitude / 1e7
    _upload_circle_fence(m, lat0, lon0, 25.0)
    p = serve.spawn("-m", "tests.serve.px4_examples", "offboard_position_velocity_ned",
                    f"udpin://0.0.0.0:{serve.ctl_port}", str(reserve_port()))
    farthest = 0.0
    t_end = time.monotonic() + 90.0
    while time.monotonic() < t_end and p.poll() is None:
        pos = wait_for(m, lambda x: x.get_type() == "GLOBAL_POSITION_INT", timeout_s=STEP_TIMEOUT_S)
        if pos is not None:
            farthest = max(farthest, _distance_m(lat0, lon0, pos.lat / 1e7, pos.lon / 1e7))
    out = "\n".join(lines_until(p, FINISHED, 30))
    revoked = _types(serve, "revoked")
    assert revoked and revoked[0]["reason"] == "geofence", (revoked, out[-2000:])
    assert _types(serve, "granted"), out[-2000:]
    assert farthest < 25.0, farthest
