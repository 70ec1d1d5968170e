"""The ICD stays true: its version, mode numbers, timing defaults, messages and reasons match the code."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import get_args

from merlin.config.models import HandoverConfig, Watchdogs
from merlin.core.types import Authority, Behavior, ReasonCode
from merlin.link import outbound as o
from merlin.link.dialect import ICD_VERSION, dialect_xml_path, icd_version_string
from merlin.link.px4_modes import mode_for
from tests.link.helpers import NOW_UNIX_S, make_link

ICD = (Path(__file__).resolve().parents[2] / "icd" / "ICD.md").read_text()


def test_version_stated() -> None:
    assert f"**ICD version {icd_version_string()}**" in ICD
    assert ICD_VERSION[0] >= 1


def test_mode_table_numbers_match_the_encoder() -> None:
    rows = {
        "EXPERIMENTAL": mode_for(Authority.EXPERIMENTAL, Behavior.HOLD),
        "OPERATOR": mode_for(Authority.OPERATOR, Behavior.HOLD),
        **{f"TRUSTED or SHADOW | {b.name}": mode_for(Authority.TRUSTED, b) for b in Behavior if b is not Behavior.TERMINATE},
        "TRUSTED | TERMINATE": mode_for(Authority.TRUSTED, Behavior.TERMINATE),
    }
    for label, mode in rows.items():
        line = next(ln for ln in ICD.splitlines() if ln.startswith(f"| {label} |"))
        assert line.rstrip(" |").endswith(str(mode.custom_mode)), (label, line, mode.custom_mode)


def test_timing_defaults_match_the_configuration() -> None:
    w, h = Watchdogs(), HandoverConfig()
    expect = {
        "watchdogs.controller_heartbeat.timeout_s` = ": w.controller_heartbeat.timeout_s,
        "watchdogs.setpoint_stale.timeout_s` = ": w.setpoint_stale.timeout_s,
    }
    for key, value in expect.items():
        assert re.search(re.escape(key) + re.escape(f"{value} s"), ICD), key
    for text, value in (
        ("| Heartbeat unbroken before a request can be granted | ", h.heartbeat_alive_min_s),
        ("| Acknowledgement after a grant | within ", h.ack_timeout_s),
        ("| Blend (bumpless transfer) | ", h.blend_window_s),
        ("| Cooldown after a revocation | ", h.cooldown_s),
    ):
        assert f"{text}{value:.1f} s" in ICD, text
    assert f"timeout {w.rc_link.timeout_s:.1f} s" in ICD and f"timeout {w.gcs_link.timeout_s:.1f} s" in ICD
    assert f"`handover.max_revocations_per_flight`\n({h.max_revocations_per_flight})" in ICD


def test_every_dialect_message_and_reason_is_documented() -> None:
    root = ET.parse(dialect_xml_path()).getroot()
    for m in root.iter("message"):
        assert f"| {m.get('id')} | {m.get('name')} |" in ICD, m.get("name")
    for r in ReasonCode:
        assert f"| {int(r)} | {r.name} |" in ICD, r.name


def test_every_outgoing_type_encodes() -> None:
    # A smoke test over the union, so a new outgoing type cannot be added without an encoder.
    covered = {type(x) for x in _samples()}
    assert covered == set(get_args(o.OutMessage))
    link = make_link()
    for x in _samples():
        assert link.encode(x, NOW_UNIX_S)


def _samples() -> list[o.OutMessage]:
    from merlin.core.types import Reason
    from merlin.link.px4_modes import OFFBOARD

    r = Reason(ReasonCode.ENVELOPE)
    return [
        o.HeartbeatOut(OFFBOARD, True), o.SysStatusOut(1.0), o.AttitudeOut(0, (0, 0, 0), (0, 0, 0)),
        o.LocalPositionNedOut(0, (0, 0, 0), (0, 0, 0)), o.GlobalPositionIntOut(0, 0, 0, 0, 0, (0, 0, 0), None),
        o.GpsRawIntOut(0, 3, 0, 0, 0), o.VfrHudOut(0, 0, 0, 0, 0, 0), o.ExtendedSysStateOut(True),
        o.HomePositionOut(0, 0, 0), o.StatusTextOut(6, "x"), o.CommandAckOut(1, 0, 1, 1),
        o.AutopilotVersionOut((0, 1, 0), ICD_VERSION, "00000000"), o.ParamValueOut("A", 1.0, 9, 1, 0),
        o.MissionCountOut(1, 1, 0, 1), o.MissionRequestIntOut(1, 1, 0, 1), o.MissionRequestListOut(1, 1, 1),
        o.MissionItemIntOut(1, 1, 0, 0, 5003, 1, 0, 0, 0, 0, 0, 0, 1), o.MissionAckOut(1, 1, 0, 1),
        o.MissionCurrentOut(2, 5, o.MISSION_STATE_ACTIVE, 1), o.MissionItemReachedOut(1),
        o.AuthorityGrantOut(0, 1, 0, 1, 1, Authority.EXPERIMENTAL, 1, 1), o.AuthorityDenyOut(0, 0, 0, 1, 1, r),
        o.AuthorityRevokeOut(0, 1, 0, 0, r, Authority.EXPERIMENTAL, Authority.TRUSTED, Behavior.RTL, 5, 1),
        o.AuthorityStatusOut(0, Authority.TRUSTED, Behavior.IDLE, 0, 0, 0, 3, 0, ReasonCode.NONE, 0),
        o.EnvelopeStatusOut(0, 0, 14, 0, 0, 0, 0, 0, 0, "s"),
    ]
