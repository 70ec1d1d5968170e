"""``merlin serve`` as a PX4 drop-in for offboard control written the way PX4's documentation shows it: plain
pymavlink (:mod:`tests.serve.px4_offboard_client`), a ground-station HEARTBEAT type as MAVSDK declares by
default, OFFBOARD asked for right after the first setpoint, and supervision still in force."""

from __future__ import annotations

import itertools
import math
import os
import re
import signal
from pathlib import Path

import pytest

from tests.serve.conftest import (
    ServeProc,
    arm_and_takeoff,
    gcs_connection,
    lines_until,
    start_serve,
    stop,
    wait_for,
)

pytestmark = pytest.mark.integration

MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS = 0, 5
TICK_S = 1.0 / 250.0


def _client(sp: ServeProc, *args: str) -> object:
    return sp.spawn("-m", "tests.serve.px4_offboard_client", "--url", f"udpin:127.0.0.1:{sp.ctl_port}", *args)


def _t(line: str) -> float:
    found = re.search(r"t=([0-9.]+)$", line)
    assert found, line
    return float(found.group(1))


def _acks(lines: list[str]) -> list[tuple[int, float]]:
    out = []
    for x in lines:
        found = re.search(r"ack command=176 result=(\d+) ", x)
        if found:
            out.append((int(found.group(1)), _t(x)))
    return out


def test_offboard_start_right_after_the_first_setpoint_is_held_then_granted(serve: ServeProc) -> None:
    # MAVSDK's offboard examples: one setpoint, then offboard.start() at once; PX4 accepts. Merlin holds the
    # request (IN_PROGRESS) until its heartbeat rule is met, then grants: never a denial for its own timing
    m = gcs_connection(serve.gcs_port)
    arm_and_takeoff(m)
    ctl = _client(serve, "--flow", "velocity", "--vn", "0.5", "--fly-s", "20")
    out = lines_until(ctl, "mode OFFBOARD", timeout_s=60)
    acks = _acks(out)
    assert acks and acks[0][0] == MAV_RESULT_IN_PROGRESS, out
    assert acks[-1][0] == MAV_RESULT_ACCEPTED, out
    # MAVSDK waits retries x timeout = 1.5 s after each IN_PROGRESS: every answer came within that
    times = [0.0] + [t for _, t in acks]
    assert max(b - a for a, b in itertools.pairwise(times)) < 1.5, acks
    assert all(r == MAV_RESULT_IN_PROGRESS for r, _ in acks[:-1]), acks
    assert any("mode OFFBOARD" in x for x in out)
    ev = serve.events()
    assert not any(e["type"] == "denied" for e in ev), [e for e in ev if e["type"] == "denied"]
    held = [e for e in ev if e["type"] == "offboard_request_held"]
    assert held and held[0]["link"] == "controller"


def test_a_controller_that_never_streamed_is_denied_at_once_with_its_reason(serve: ServeProc) -> None:
    m = gcs_connection(serve.gcs_port)
    arm_and_takeoff(m)
    from pymavlink import mavutil

    c = mavutil.mavlink_connection(f"udpin:127.0.0.1:{serve.ctl_port}", source_system=245, source_component=191,
                                   dialect="common")
    assert c.wait_heartbeat(timeout=60) is not None
    c.mav.heartbeat_send(6, 8, 0, 0, 0)
    c.mav.command_long_send(1, 1, 176, 0, 1, 6, 0, 0, 0, 0, 0)
    ack = wait_for(c, lambda x: x.get_type() == "COMMAND_ACK" and x.command == 176, timeout_s=10, heartbeat=False)
    assert ack is not None and ack.result not in (MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS), ack
    c.close()
    denied = [e for e in serve.events() if e["type"] == "denied"]
    assert denied and denied[0]["reason"] in ("setpoint_stale", "precondition"), denied
    assert not any(e["type"] == "offboard_request_held" for e in serve.events())


def test_killing_the_client_revokes_within_the_loss_time_plus_one_core_period(serve: ServeProc) -> None:
    m = gcs_connection(serve.gcs_port)
    arm_and_takeoff(m)
    ctl = _client(serve, "--flow", "velocity", "--fly-s", "600")
    out = lines_until(ctl, "mode OFFBOARD", timeout_s=60)
    assert any("mode OFFBOARD" in x for x in out), out
    assert wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1
                    and (x.custom_mode >> 16) & 0xFF == 6) is not None
    os.kill(ctl.pid, signal.SIGKILL)  # type: ignore[attr-defined]
    hb = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1
                  and (x.custom_mode >> 16) & 0xFF != 6)
    assert hb is not None, "the mode never left OFFBOARD"
    [rv] = [e for e in serve.events() if e["type"] == "revoked"][:1]
    assert rv["reason"] in ("controller_heartbeat", "setpoint_stale")
    # in the core's clock: the silence at the revocation is at most the watchdog (itself at most
    # links.offboard_loss_timeout_s = 1 s, PX4's COM_OF_LOSS_T) plus one of the core's periods (serve's
    # default: 10 ms rounded down to whole ticks, two 4 ms ticks at its 250 Hz; serve_start records it)
    core_s = next(e for e in serve.events() if e["type"] == "serve_start")["core_dt_s"]
    assert core_s == 2 * TICK_S
    d = rv["reason_detail"]
    assert d["limit"] <= 1.0 and d["limit"] < d["value"] <= d["limit"] + core_s + 1e-9, d


FENCE_60M = """
geofence:
  inclusion_circles:
    - {name: test range, center_ne_m: [0.0, 0.0], radius_m: 60.0}
"""


def test_an_outward_offboard_flight_is_revoked_by_the_fence_and_stays_inside(tmp_path: Path) -> None:
    cfg = tmp_path / "fence60.yaml"
    cfg.write_text(FENCE_60M)
    sp = start_serve(tmp_path, "--config", str(cfg))
    try:
        m = gcs_connection(sp.gcs_port)
        arm_and_takeoff(m)
        ctl = _client(sp, "--flow", "velocity", "--vn", "3", "--fly-s", "600")
        out = lines_until(ctl, "mode left OFFBOARD", timeout_s=90)
        assert any("mode OFFBOARD" in x for x in out) and any("mode left OFFBOARD" in x for x in out), out
        worst = 0.0
        for _ in range(150):  # the next ~15 s of positions (10 Hz): never outside the 60 m circle
            pos = wait_for(m, lambda x: x.get_type() == "LOCAL_POSITION_NED", timeout_s=5)
            assert pos is not None
            worst = max(worst, math.hypot(pos.x, pos.y))
        assert worst < 60.0, worst
    finally:
        stop(sp)
    revoked = [e for e in sp.events() if e["type"] == "revoked"]
    assert revoked and revoked[0]["reason"] == "geofence", revoked


def _takeoff_flow(sp: ServeProc, height: str, *extra: str) -> tuple[list[str], object]:
    m = gcs_connection(sp.gcs_port)
    ctl = _client(sp, "--flow", "takeoff", "--height", height, "--prestream-s", "3", "--fly-s", "60",
                  "--report-position", *extra)
    return lines_until(ctl, "mode OFFBOARD", timeout_s=30), m


@pytest.mark.parametrize("variant", ["command", "message", "arm-first"])
def test_px4_tutorial_take_off_in_offboard_is_flown_by_merlin_then_handed_over(serve: ServeProc,
                                                                             variant: str) -> None:
    # PX4's offboard tutorial (MAVROS offb_node, here pymavlink): on the ground and disarmed, stream a position
    # setpoint up, switch to OFFBOARD (DO_SET_MODE, or the SET_MODE message MAVROS sends), arm; or arm first
    # and then switch, as MAVSDK's offboard examples do
    extra = ("--arm-first",) if variant == "arm-first" else ("--set-mode", variant)
    out, m = _takeoff_flow(serve, "5", *extra)
    brief = [x for x in out if "position" not in x]
    assert any("ack command=176 result=0" in x for x in out), brief  # accepted on the ground, as PX4 does
    first = next(x for x in out if "mode OFFBOARD" in x)
    armed_when_shown = "armed=True" in out[out.index(first) - 1]
    assert armed_when_shown == (variant == "arm-first"), out  # shown OFFBOARD on the ground, as PX4 shows it
    # the ground station sees the truth meanwhile: Merlin's own take-off (AUTO.TAKEOFF)
    tk = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1
                  and x.custom_mode == (4 << 16 | 2 << 24))
    assert tk is not None
    # then the grant, in the air, above the envelope's lowest altitude (3 m) plus the margin
    off = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1
                   and (x.custom_mode >> 16) & 0xFF == 6)
    assert off is not None, "never handed over"
    ev = serve.events()
    phases = [e["phase"] for e in ev if e["type"] == "offboard_takeoff"]
    assert phases[:3] == ["accepted", "climbing", "requested"], phases
    req = next(e for e in ev if e.get("phase") == "requested")
    assert req["alt_m"] >= 4.0 - 0.1
    granted = [e for e in ev if e["type"] == "authority" and e.get("to") == "EXPERIMENTAL"]
    assert granted, [e for e in ev if e["type"] in ("denied", "offboard_takeoff")]
    # the controller's setpoint (5 m up) is flown: the vehicle settles near 5 m
    got = wait_for(m, lambda x: x.get_type() == "LOCAL_POSITION_NED" and abs(-x.z - 5.0) < 0.5, timeout_s=30)
    assert got is not None


def test_a_stream_that_stutters_during_merlins_take_off_is_handed_over_as_px4_would(serve: ServeProc) -> None:
    """The controller's link goes silent for 0.7 s as Merlin's climb nears the hand-over height (a loaded
    machine, MAVSDK's server starved): longer than the controller watchdog's 0.5 s, so Merlin's liveness rule
    (1 s unbroken) fails at the request or between the grant and its ACK; shorter than PX4's COM_OF_LOSS_T
    (1 s), so PX4 would not have refused. The flow waits for the rule and asks again: the controller's link
    keeps showing OFFBOARD, and it is handed over. (Before, a denial at the exchange's switch left the
    controller's link showing OFFBOARD while Merlin held, for good.)"""
    # from 3.0 m: the silence overlaps the request at 4.0 m (or the exchange after it) for any lag of the
    # client's view of the height up to about its own length (the deterministic cases, tick by tick:
    # tests/serve/test_exchange_stutter.py)
    out, m = _takeoff_flow(serve, "5", "--arm-first", "--stutter-at-alt", "3.0", "--stutter-s", "0.7")
    ctl = serve.extra[-1]
    out += lines_until(ctl, "stutter", timeout_s=60)
    assert any("stutter" in x for x in out), [x for x in out if "position" not in x]
    off = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1
                   and (x.custom_mode >> 16) & 0xFF == 6, timeout_s=30)
    ev = serve.events()
    flow = [e for e in ev if e["type"] in ("denied", "offboard_takeoff", "authority")]
    assert off is not None, flow
    phases = [e["phase"] for e in ev if e["type"] == "offboard_takeoff"]
    assert phases[:2] == ["accepted", "climbing"] and "waiting" in phases and phases[-1] == "requested", phases
    for k, e in enumerate(flow):  # a denial only on the liveness rule, and the flow waits again after it
        if e["type"] == "denied":
            assert e["reason"] == "heartbeat_not_established", flow
            assert flow[k + 1].get("phase") == "waiting", flow
    assert [e["to"] for e in ev if e["type"] == "authority"] == ["EXPERIMENTAL"], flow
    assert not any("mode left OFFBOARD" in x for x in out + lines_until(ctl, "mode left OFFBOARD", timeout_s=2))


def test_px4_tutorial_with_a_setpoint_below_the_envelope_takes_off_and_is_refused_with_its_reason(
        serve: ServeProc) -> None:
    # the tutorial's 2 m is below the conservative envelope's altitude_m.min (3 m): Merlin flies its take-off,
    # and the request is refused (the setpoint commands a height outside the envelope); the controller sees
    # the mode leave OFFBOARD and the reason in STATUSTEXT, and the vehicle holds under Merlin
    out, m = _takeoff_flow(serve, "2")
    assert any("mode OFFBOARD" in x for x in out), out
    ctl = serve.extra[-1]
    more = lines_until(ctl, "mode left OFFBOARD", timeout_s=60)
    assert any("mode left OFFBOARD" in x for x in more), more
    more += lines_until(ctl, "altitude_m", timeout_s=10)  # the reason follows the mode change
    text = " ".join(x for x in out + more if "statustext" in x)
    assert "altitude_m" in text, text
    hold = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1
                    and x.custom_mode in (4 << 16 | 3 << 24, 4 << 16 | 2 << 24))
    assert hold is not None and hold.base_mode & 128  # armed, Merlin's take-off or hold
    ev = serve.events()
    denied = [e for e in ev if e["type"] == "denied"]
    assert denied and denied[0]["reason"] == "envelope", denied
    assert not any(e["type"] == "authority" and e.get("to") == "EXPERIMENTAL" for e in ev)
