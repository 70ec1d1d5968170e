"""An out-of-process experimental controller written with pymavlink against Merlin's dialect (icd/merlin.xml).

It follows the ICD's checklist (icd/ICD.md section 12) step by step: HEARTBEAT at 10 Hz from the start;
velocity setpoints (SET_POSITION_TARGET_LOCAL_NED) at 20 Hz that track the vehicle before asking;
MERLIN_AUTHORITY_REQUEST once the vehicle is armed and airborne; MERLIN_AUTHORITY_ACK of the GRANT's
``grant_seq`` at once; on DENY or REVOKE it prints the reason and waits ``retry_after_ms`` /
``cooldown_ms`` before asking again (with ``--rerequest``). With a signing key it signs everything.

    python -m experimental_controllers.pymavlink_dialect --url udpin:0.0.0.0:14540 --speed 2 --fly-s 20

Progress lines go to stdout prefixed ``pymavlink_dialect:`` (``granted 3``, ``in command``,
``revoked GEOFENCE ...``), so a test can follow them. It uses only pymavlink and the dialect bindings; the
bindings are generated from the XML with pymavlink's mavgen (here through ``merlin.link``'s generator,
which a third party replaces with ``mavgen.py --lang=Python3 --wire-protocol=2.0 icd/merlin.xml``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

MERLIN_REQUEST, MERLIN_RELEASE = 0, 3
MERLIN_EXPERIMENTAL = 2
VELOCITY_ONLY_MASK = 0b0000_1101_1100_0111  # use vx, vy, vz and yaw; ignore position, accel, yaw rate


def say(text: str) -> None:
    print(f"pymavlink_dialect: {text}", flush=True)


def connect(url: str, sysid: int, compid: int, key_file: str | None) -> object:
    from pymavlink import mavutil

    from merlin.link import register_with_mavutil

    dialect = register_with_mavutil()  # the bindings generated from icd/merlin.xml
    m = mavutil.mavlink_connection(url, source_system=sysid, source_component=compid, dialect=dialect)
    if key_file:
        from merlin.link import load_key_file

        m.setup_signing(load_key_file(Path(key_file)), sign_outgoing=True)
    return m


def fly(m: object, speed_mps: float, fly_s: float, rerequest: bool, timeout_s: float) -> int:
    mav = m.mav  # type: ignore[attr-defined]
    hb = m.wait_heartbeat(timeout=timeout_s)  # type: ignore[attr-defined]
    if hb is None:
        say("no heartbeat from Merlin")
        return 1
    target = (hb.get_srcSystem(), hb.get_srcComponent())
    say(f"connected to {target[0]}/{target[1]}")
    yaw = 0.0
    armed = landed = False
    landed = True
    in_command = False
    pending_seq = 0
    request_id = 0
    next_request_t = 0.0
    t_hb = t_sp = 0.0
    flying_since: float | None = None
    t_end = time.monotonic() + timeout_s + fly_s
    while time.monotonic() < t_end:
        now = time.monotonic()
        if now >= t_hb:
            mav.heartbeat_send(18, 8, 0, 0, 0)  # MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID
            t_hb = now + 0.1
        if now >= t_sp:
            v = speed_mps if in_command else 0.0  # track the vehicle (hover) until in command
            mav.set_position_target_local_ned_send(0, target[0], target[1], 1, VELOCITY_ONLY_MASK,
                                                   0, 0, 0, v, 0.0, 0.0, 0, 0, 0, yaw, 0)
            t_sp = now + 0.05
        if armed and not landed and not in_command and pending_seq == 0 and now >= next_request_t:
            request_id += 1
            mav.merlin_authority_request_send(target[0], target[1], MERLIN_REQUEST, request_id)
            say(f"request {request_id}")
            next_request_t = now + 2.0
        if flying_since is not None and now - flying_since > fly_s:
            mav.merlin_authority_request_send(target[0], target[1], MERLIN_RELEASE, request_id + 1)
            say("released")
            return 0
        msg = m.recv_match(blocking=True, timeout=0.01)  # type: ignore[attr-defined]
        if msg is None:
            continue
        kind = msg.get_type()
        if kind == "HEARTBEAT" and msg.get_srcComponent() == target[1]:
            armed = bool(msg.base_mode & 128)
        elif kind == "EXTENDED_SYS_STATE":
            landed = msg.landed_state == 1
        elif kind == "ATTITUDE":
            yaw = msg.yaw
        elif kind == "MERLIN_AUTHORITY_GRANT":
            pending_seq = msg.grant_seq
            mav.merlin_authority_ack_send(target[0], target[1], msg.grant_seq)
            say(f"granted {msg.grant_seq}")
        elif kind == "MERLIN_AUTHORITY_STATUS":
            was = in_command
            in_command = msg.authority == MERLIN_EXPERIMENTAL
            if in_command and not was:
                pending_seq = 0
                flying_since = time.monotonic()
                say("in command")
        elif kind == "MERLIN_AUTHORITY_DENY":
            pending_seq = 0
            say(f"denied reason={msg.reason} retry_after_ms={msg.retry_after_ms}")
            next_request_t = time.monotonic() + max(1.0, msg.retry_after_ms / 1000.0)
        elif kind == "MERLIN_AUTHORITY_REVOKE" and in_command:
            in_command = False
            pending_seq = 0
            flying_since = None
            say(f"revoked reason={msg.reason} parameter={msg.parameter} value={msg.value:.2f} "
                f"limit={msg.limit:.2f} cooldown_ms={msg.cooldown_ms}")
            if not rerequest:
                return 0
            next_request_t = time.monotonic() + msg.cooldown_ms / 1000.0 + 0.5
    say("timeout")
    return 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", default="udpin:0.0.0.0:14540", help="pymavlink connection string")
    ap.add_argument("--sysid", type=int, default=42)
    ap.add_argument("--compid", type=int, default=191, help="191: MAV_COMP_ID_ONBOARD_COMPUTER (ICD section 1)")
    ap.add_argument("--speed", type=float, default=2.0, help="northward speed once in command, m/s")
    ap.add_argument("--fly-s", type=float, default=10.0, help="release after this long in command, s")
    ap.add_argument("--rerequest", action="store_true", help="ask again after a revocation's cooldown")
    ap.add_argument("--signing-key", default=None, help="key file: sign every message")
    ap.add_argument("--timeout", type=float, default=120.0)
    a = ap.parse_args(argv)
    m = connect(a.url, a.sysid, a.compid, a.signing_key)
    return fly(m, a.speed, a.fly_s, a.rerequest, a.timeout)


if __name__ == "__main__":
    sys.exit(main())
