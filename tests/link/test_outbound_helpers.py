"""Building outgoing telemetry and exchange messages from the core's plain data (what `merlin serve` uses)."""

from __future__ import annotations

import math

import pytest

from merlin.config.models import ENVELOPE_PARAMETERS, EnvelopeConfig
from merlin.core.types import Authority, Behavior, Event, EventKind, Reason, ReasonCode, VehicleState
from merlin.geodesy import LocalFrame
from merlin.link import outbound as o
from tests.link.helpers import NOW_UNIX_S, Peer, make_link

FRAME = LocalFrame(29.6516, -82.3248, 30.0)
STATE = VehicleState(
    pos_ned_m=(100.0, -50.0, -20.0), vel_ned_mps=(3.0, 4.0, -1.0), att_rpy_rad=(0.1, -0.05, -math.pi / 2),
    rates_frd_radps=(0.2, 0.0, 0.0), armed=True, landed=False, battery_frac=0.8,
)


def _wire(out: o.OutMessage) -> object:
    return Peer().decode_all(b"".join(make_link().encode(out, NOW_UNIX_S)))[0]


def test_position_helpers_agree_with_the_local_frame() -> None:
    g = o.global_position_from_state(STATE, FRAME, 10)
    lat, lon, alt = FRAME.to_geodetic(100.0, -50.0, -20.0)
    assert alt == pytest.approx(50.0)
    assert (g.lat_deg, g.lon_deg, g.alt_amsl_m, g.relative_alt_m) == pytest.approx((lat, lon, 50.0, 20.0))
    assert g.heading_rad == pytest.approx(1.5 * math.pi)
    m = _wire(g)
    assert m.hdg == 27000 and m.relative_alt == 20000  # type: ignore[attr-defined]
    h = o.vfr_hud_from_state(STATE, FRAME, 0.55)
    assert (h.groundspeed_mps, h.alt_amsl_m, h.climb_mps) == pytest.approx((5.0, 50.0, 1.0))
    assert o.local_position_from_state(STATE, 1).pos_ned_m == STATE.pos_ned_m
    assert o.attitude_from_state(STATE, 1).rates_frd_radps == STATE.rates_frd_radps
    assert not o.extended_sys_state_from_state(STATE).landed
    assert o.sys_status_from_state(STATE).battery_frac == 0.8
    home = o.home_position_from_frame(FRAME)
    assert (home.lat_deg, home.lon_deg, home.alt_amsl_m) == (29.6516, -82.3248, 30.0)


def test_exchange_messages_from_events() -> None:
    g = o.grant_from_event(Event(1.0, EventKind.GRANTED, seq=4), 1000, (42, 191), 17, Authority.EXPERIMENTAL, 1.0, 1.0)
    assert (g.grant_seq, g.request_id, g.target_system) == (4, 17, 42)
    d = o.deny_from_event(Event(1.0, EventKind.DENIED, reason=Reason(ReasonCode.COOLDOWN)), 1000, (42, 191), 18, 3.2)
    assert d.reason.code is ReasonCode.COOLDOWN and d.retry_after_s == 3.2
    r = Reason(ReasonCode.GEOFENCE, monitor="geofence", parameter="margin_m", value=-2.0, limit=0.0)
    rv = o.revoke_from_event(Event(2.0, EventKind.REVOKED, reason=r, from_=Authority.EXPERIMENTAL,
                                   to=Authority.TRUSTED, behavior=Behavior.RTL), 2000, (0, 0), 4, 5.0, 1)
    m = _wire(rv)
    assert (m.reason, m.behavior, m.to_authority, m.monitor, m.parameter) == (  # type: ignore[attr-defined]
        int(ReasonCode.GEOFENCE), int(Behavior.RTL), int(Authority.TRUSTED), "geofence", "margin_m")


def test_envelope_status_units_and_states() -> None:
    limits = EnvelopeConfig().effective()  # conservative: roll within +-30 deg, duration 0
    rolled = VehicleState(att_rpy_rad=(math.radians(35.0), 0.0, 0.0), pos_ned_m=(0.0, 0.0, -10.0))
    st = {s.parameter: s for s in o.envelope_status_from(5, rolled, limits, "conservative", {"roll_deg": 0.0})}
    roll = st[5]
    assert roll.value == pytest.approx(35.0) and (roll.min, roll.max) == (-30.0, 30.0)
    assert roll.state == o.ENVELOPE_TRIPPED  # duration 0: tripped on the tick of the violation
    assert st[0].state == o.ENVELOPE_DISABLED  # airspeed disabled in the conservative stage
    assert st[1].state == o.ENVELOPE_INSIDE and st[1].value == pytest.approx(10.0)
    fast = VehicleState(vel_ned_mps=(9.0, 0.0, 0.0), pos_ned_m=(0.0, 0.0, -10.0))
    vn = {s.parameter: s for s in o.envelope_status_from(5, fast, limits, "c", {"vel_n_mps": 0.2})}[2]
    assert vn.state == o.ENVELOPE_EXCEEDING and vn.exceedance_elapsed_s == 0.2 and vn.exceedance_duration_s == 0.5
    assert len(st) == len(ENVELOPE_PARAMETERS) and {s.parameter_count for s in st.values()} == {len(ENVELOPE_PARAMETERS)}


def test_autopilot_version_carries_icd_version_and_dialect_hash() -> None:
    from merlin.link.dialect import ICD_VERSION, xml_sha256

    m = _wire(o.autopilot_version((0, 1, 0), uid=5))
    major, minor, patch = ICD_VERSION
    assert m.middleware_sw_version == (major << 24) | (minor << 16) | (patch << 8) | 0xFF  # type: ignore[attr-defined]
    assert bytes(m.middleware_custom_version).decode() == xml_sha256()[:8]  # type: ignore[attr-defined]
    assert m.capabilities & 16384 and m.capabilities & 8192  # type: ignore[attr-defined]  # fence, MAVLink 2


def test_authority_status_from_decision() -> None:
    from merlin.core.types import Command, CommandKind, Decision

    d = Decision(t_s=3.0, authority=Authority.EXPERIMENTAL, behavior=Behavior.HOLD,
                 command=Command(CommandKind.VELOCITY, Authority.EXPERIMENTAL), monitors=(), events=(), armed=True,
                 pending_grant_seq=0, revocations=3)
    st = o.authority_status_from_decision(d, 3000, active_grant_seq=9, max_revocations=3, cooldown_remaining_s=1.5,
                                          last_reason=ReasonCode.GRANTED, landed=False, controller_heartbeat_ok=True,
                                          setpoint_fresh=True, signing_required=True)
    assert st.active_grant_seq == 9 and st.revocations == 3
    assert st.flags == o.STATUS_ARMED | o.STATUS_HEARTBEAT_OK | o.STATUS_SETPOINT_FRESH | o.STATUS_COOLDOWN | (
        o.STATUS_REVOCATION_LIMIT | o.STATUS_SIGNING_REQUIRED)
    m = _wire(st)
    assert (m.authority, m.flags, m.cooldown_remaining_ms) == (2, st.flags, 1500)  # type: ignore[attr-defined]
