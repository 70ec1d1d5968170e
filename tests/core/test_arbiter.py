"""Scenario-style tests of the arbiter's whole table: grants, denials, revocations, the operator, commands.

Each test states a behaviour in the user's words; together they cover every branch of
``merlin/core/arbiter.py`` (checked by ``test_arbiter_branch_coverage`` in CI's coverage run).
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from merlin.config.models import ActionName, ArbiterConfig, ClearName, HandoverConfig, MerlinConfig, Rule
from merlin.core import arbiter
from merlin.core.arbiter import ArbiterState, TickView
from merlin.core.types import (
    Action,
    Authority,
    AuthorityRequest,
    Behavior,
    EventKind,
    GcsCommand,
    GcsCommandKind,
    NavMode,
    OperatorInput,
    ReasonCode,
    RequestKind,
    Setpoint,
    SetpointKind,
)
from tests.core.harness import HOVER_10M, Harness, events_of


def _cfg(**sections: object) -> MerlinConfig:
    return MerlinConfig().model_copy(update=sections)


def _reasons(d, kind):
    return [e.reason.code for e in events_of(d, kind)]


# --------------------------------------------------------------------------------------- the exchange


def test_nominal_exchange_request_grant_ack_switch_next_tick_then_release() -> None:
    h = Harness()
    h.airborne()
    d = h.request()
    g = events_of(d, EventKind.GRANTED)
    assert len(g) == 1 and g[0].seq == 1 and d.pending_grant_seq == 1
    assert d.authority is Authority.TRUSTED
    d = h.ack(1)
    assert events_of(d, EventKind.ACKNOWLEDGED) and d.authority is Authority.TRUSTED  # not yet
    d = h.tick()
    assert d.authority is Authority.EXPERIMENTAL  # on the next tick
    ev = events_of(d, EventKind.AUTHORITY)[0]
    assert (ev.from_, ev.to, ev.reason.code, ev.seq) == (Authority.TRUSTED, Authority.EXPERIMENTAL, ReasonCode.GRANTED, 1)
    d = h.tick(requests=(AuthorityRequest(RequestKind.RELEASE),))
    assert d.authority is Authority.TRUSTED and d.behavior is Behavior.HOLD
    assert ReasonCode.RELEASED in _reasons(d, EventKind.RELEASED)
    assert d.revocations == 0


def test_no_ack_in_time_is_denied_with_ack_timeout() -> None:
    h = Harness()
    h.airborne()
    h.request()
    d = h.run(1.0)  # exactly the timeout: still pending
    assert d.pending_grant_seq == 1
    d = h.tick()
    assert ReasonCode.ACK_TIMEOUT in _reasons(d, EventKind.DENIED) and d.pending_grant_seq == 0
    d = h.ack(1)  # a late ACK does not grant
    assert ReasonCode.SEQUENCE_MISMATCH in _reasons(d, EventKind.DENIED)
    assert h.tick().authority is Authority.TRUSTED


def test_wrong_sequence_ack_is_denied_and_the_grant_stays_pending() -> None:
    h = Harness()
    h.airborne()
    h.request()
    d = h.ack(7)
    assert ReasonCode.SEQUENCE_MISMATCH in _reasons(d, EventKind.DENIED) and d.pending_grant_seq == 1
    h.ack(1)
    assert h.tick().authority is Authority.EXPERIMENTAL


def test_second_request_while_pending_or_held_is_busy() -> None:
    h = Harness()
    h.airborne()
    h.request()
    assert ReasonCode.BUSY in _reasons(h.request(), EventKind.DENIED)
    h.ack(1)
    h.tick()
    assert ReasonCode.BUSY in _reasons(h.request(), EventKind.DENIED)


def test_request_before_arming_is_denied() -> None:
    h = Harness()
    d = h.request()
    assert ReasonCode.NOT_ARMED in _reasons(d, EventKind.DENIED)


def test_request_needs_heartbeat_alive_for_the_configured_time() -> None:
    h = Harness()
    h.heartbeat = False
    h.airborne()
    h.heartbeat = True
    h.run(0.5)
    d = h.request()
    assert ReasonCode.HEARTBEAT_NOT_ESTABLISHED in _reasons(d, EventKind.DENIED)
    h.run(0.6)
    assert events_of(h.request(), EventKind.GRANTED)


def test_request_without_any_setpoint_is_denied() -> None:
    h = Harness(setpoint=None)
    h.airborne()
    d = h.request()
    assert _reasons(d, EventKind.DENIED)  # setpoint_stale (never received)


def test_request_denied_when_an_envelope_parameter_is_out_of_bounds() -> None:
    h = Harness()
    h.airborne()
    h.state = replace(HOVER_10M, att_rpy_rad=(math.radians(40), 0.0, 0.0))
    d = h.request()
    den = events_of(d, EventKind.DENIED)
    assert den and den[0].reason.code is ReasonCode.ENVELOPE and den[0].reason.parameter == "roll_deg"


@pytest.mark.parametrize(
    "setpoint, param",
    [
        (Setpoint(SetpointKind.POSITION, pos_ned_m=(50.0, 0.0, -10.0)), "position_error_m"),
        (Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(5.0, 0.0, 0.0)), "velocity_error_mps"),
        (Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(0.0, -0.45, 0.0), thrust=0.5), "attitude_error_deg"),
    ],
)
def test_first_setpoint_must_be_consistent_with_the_state(setpoint: Setpoint, param: str) -> None:
    h = Harness(setpoint=setpoint)
    h.airborne()
    den = events_of(h.request(), EventKind.DENIED)
    assert den and den[0].reason.code in (ReasonCode.SETPOINT_INCONSISTENT, ReasonCode.ENVELOPE)
    if den[0].reason.code is ReasonCode.SETPOINT_INCONSISTENT:
        assert den[0].reason.parameter == param


def test_setpoint_commanding_outside_the_envelope_is_denied() -> None:
    h = Harness(setpoint=Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(math.radians(45), 0.0, 0.0), thrust=0.5))
    h.airborne()
    den = events_of(h.request(), EventKind.DENIED)
    assert den[0].reason.code is ReasonCode.ENVELOPE and "commands" in den[0].reason.text


def test_nav_not_gps_or_sigma_too_large_is_denied() -> None:
    h = Harness()
    h.airborne()
    h.state = replace(HOVER_10M, pos_sigma_h_m=8.0)
    assert ReasonCode.NAV_DEGRADED in _reasons(h.request(), EventKind.DENIED)
    h2 = Harness(cfg=_cfg(arbiter=ArbiterConfig(rules={"nav_gps_lost": Rule(
        experimental=ActionName.WARN, operator=ActionName.WARN, trusted=ActionName.NONE)})))
    h2.airborne()
    h2.state = replace(HOVER_10M, nav_mode=NavMode.VO)
    den = events_of(h2.request(), EventKind.DENIED)
    assert den[0].reason.code is ReasonCode.NAV_DEGRADED and den[0].reason.parameter == "nav_mode"


def test_switch_is_denied_if_preconditions_fail_between_ack_and_switch() -> None:
    h = Harness()
    h.airborne()
    h.request()
    h.ack(1)
    h.state = replace(HOVER_10M, att_rpy_rad=(math.radians(40), 0.0, 0.0))
    d = h.tick()
    assert d.authority is Authority.TRUSTED and ReasonCode.ENVELOPE in _reasons(d, EventKind.DENIED)


# ------------------------------------------------------------------------------------------ revocations


def test_heartbeat_gap_revokes_on_first_tick_after_timeout_to_hold() -> None:
    h = Harness()
    h.airborne()
    h.grant()
    h.heartbeat = False
    last = h.last_hb_t
    # 0.5 s timeout: ticks until gap == 0.5 are alive, the next one revokes
    while True:
        d = h.tick()
        if d.authority is Authority.TRUSTED:
            break
    assert d.t_s - last > 0.5 and d.t_s - last <= 0.5 + h.dt + 1e-12
    assert ReasonCode.CONTROLLER_HEARTBEAT in _reasons(d, EventKind.REVOKED)
    assert d.behavior is Behavior.HOLD and d.revocations == 1


def test_stale_setpoints_revoke_even_with_heartbeat_alive() -> None:
    h = Harness()
    h.airborne()
    h.grant()
    h.setpoint_fresh = False
    d = h.run(0.51)
    assert d.authority is Authority.TRUSTED
    assert any(ReasonCode.SETPOINT_STALE in _reasons(x, EventKind.REVOKED) for x in h.history[-10:])


def test_nan_setpoint_revokes_with_invalid_input() -> None:
    h = Harness()
    h.airborne()
    h.grant()
    h.setpoint = Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(math.nan, 0.0, 0.0))
    d = h.tick()
    assert d.authority is Authority.TRUSTED
    assert _reasons(d, EventKind.REVOKED) == [ReasonCode.INVALID_INPUT]
    assert all(math.isfinite(x) for x in d.command.vel_ned_mps)


def test_cooldown_and_revocation_limit() -> None:
    cfg = _cfg(handover=HandoverConfig(cooldown_s=2.0, max_revocations_per_flight=2))
    h = Harness(cfg=cfg)
    h.airborne()
    for i in range(2):
        h.grant()
        h.heartbeat = False
        h.run(0.6)
        h.heartbeat = True
        assert ReasonCode.COOLDOWN in _reasons(h.request(), EventKind.DENIED)
        h.run(2.0)
        if i == 0:
            continue
    d = h.request()
    assert ReasonCode.REVOCATION_LIMIT in _reasons(d, EventKind.DENIED)


def test_warn_action_does_not_revoke_but_reports() -> None:
    h = Harness(rc_alive=True)
    h.airborne()
    h.grant()
    h.rc_alive = False
    d = h.run(1.1)
    assert d.authority is Authority.EXPERIMENTAL
    assert any(ReasonCode.RC_LINK in _reasons(x, EventKind.WARNING) for x in h.history[-60:])


def test_gcs_link_loss_revokes_to_rtl_and_escalates_trusted_hold() -> None:
    h = Harness()
    h.airborne()
    h.grant()
    h.gcs_alive = False
    d = h.run(5.1)
    assert d.authority is Authority.TRUSTED and d.behavior is Behavior.RTL


def test_trusted_hold_escalates_to_rtl_on_gcs_loss_but_not_on_the_ground() -> None:
    h = Harness()
    h.airborne()
    h.gcs_alive = False
    assert h.run(5.1).behavior is Behavior.RTL
    g = Harness()
    g.state = replace(HOVER_10M, pos_ned_m=(0.0, 0.0, 0.0), landed=True)
    g.command(GcsCommandKind.ARM)
    g.gcs_alive = False
    assert g.run(5.1).behavior is Behavior.IDLE


def test_shadow_is_judged_on_commands_and_never_actuates() -> None:
    h = Harness()
    h.airborne()
    d = h.grant(shadow=True)
    assert d.command.source is Authority.TRUSTED
    h.setpoint = Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(math.radians(40), 0.0, 0.0), thrust=0.5)
    d = h.tick()
    assert d.authority is Authority.TRUSTED
    sv = events_of(d, EventKind.SHADOW_VIOLATION)
    assert sv and sv[0].reason.parameter == "roll_deg"
    assert d.revocations == 0


def test_shadow_fence_judgement_on_commanded_velocity() -> None:
    h = Harness()
    h.airborne()
    h.grant(shadow=True)
    h.setpoint = Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(0.0, 0.0, 0.0))
    assert h.tick().authority is Authority.SHADOW
    h.state = replace(HOVER_10M, pos_ned_m=(288.0, 0.0, -10.0))
    h.setpoint = Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(7.0, 0.0, 0.0))
    d = h.tick()
    assert any(e.reason.code is ReasonCode.GEOFENCE for e in events_of(d, EventKind.SHADOW_VIOLATION))


def test_shadow_release() -> None:
    h = Harness()
    h.airborne()
    h.grant(shadow=True)
    d = h.tick(requests=(AuthorityRequest(RequestKind.RELEASE),))
    assert d.authority is Authority.TRUSTED and events_of(d, EventKind.RELEASED)


def test_release_while_pending_cancels_the_grant() -> None:
    h = Harness()
    h.airborne()
    h.request()
    d = h.tick(requests=(AuthorityRequest(RequestKind.RELEASE),))
    assert ReasonCode.RELEASED in _reasons(d, EventKind.DENIED) and d.pending_grant_seq == 0


# --------------------------------------------------------------------------------------------- operator


def test_operator_can_always_take_over_and_cancels_a_pending_grant() -> None:
    h = Harness(rc_alive=True)
    h.airborne()
    h.request()
    h.operator = OperatorInput(takeover=True)
    d = h.tick()
    assert d.authority is Authority.OPERATOR
    assert ReasonCode.OPERATOR_TAKEOVER in _reasons(d, EventKind.DENIED)
    assert ReasonCode.BUSY in _reasons(h.request(), EventKind.DENIED)
    h.operator = OperatorInput(takeover=False)
    d = h.tick()
    assert d.authority is Authority.TRUSTED and d.behavior is Behavior.HOLD


def test_operator_takeover_from_experimental() -> None:
    h = Harness(rc_alive=True)
    h.airborne()
    h.grant()
    h.operator = OperatorInput(takeover=True, pitch=0.5)
    d = h.tick()
    assert d.authority is Authority.OPERATOR and d.command.source is Authority.OPERATOR


def test_operator_is_under_envelope_oversight_with_grace_for_a_condition_present_at_takeover() -> None:
    h = Harness(rc_alive=True)
    h.airborne()
    h.operator = OperatorInput(takeover=True)
    h.tick()
    h.state = replace(HOVER_10M, att_rpy_rad=(math.radians(40), 0.0, 0.0))
    d = h.tick()
    assert d.authority is Authority.TRUSTED and ReasonCode.ENVELOPE in _reasons(d, EventKind.REVOKED)
    # a new takeover while the condition persists gets the grace period
    h.operator = OperatorInput(takeover=False)
    h.tick()
    h.operator = OperatorInput(takeover=True)
    d = h.tick()
    assert d.authority is Authority.OPERATOR
    d = h.run(4.9)
    assert d.authority is Authority.OPERATOR
    d = h.run(0.2)
    assert d.authority is Authority.TRUSTED


def test_operator_oversight_can_be_switched_off() -> None:
    cfg = _cfg(operator=MerlinConfig().operator.model_copy(update={"oversight_envelope": False}))
    h = Harness(cfg=cfg, rc_alive=True)
    h.airborne()
    h.operator = OperatorInput(takeover=True)
    h.tick()
    h.state = replace(HOVER_10M, att_rpy_rad=(math.radians(40), 0.0, 0.0))
    assert h.run(1.0).authority is Authority.OPERATOR


def test_operator_rc_loss_revokes_to_rtl() -> None:
    h = Harness(rc_alive=True)
    h.airborne()
    h.operator = OperatorInput(takeover=True)
    h.tick()
    h.rc_alive = False
    d = h.run(1.1)
    assert d.authority is Authority.TRUSTED and d.behavior is Behavior.RTL


def test_takeover_ignored_when_disarmed() -> None:
    h = Harness(rc_alive=True)
    h.operator = OperatorInput(takeover=True)
    assert h.tick().authority is Authority.TRUSTED


# ------------------------------------------------------------------------------------- ground station


def test_arming_is_refused_outside_the_fence_and_forced_arming_works() -> None:
    h = Harness()
    h.state = replace(HOVER_10M, pos_ned_m=(400.0, 0.0, 0.0), landed=True)
    d = h.command(GcsCommandKind.ARM)
    acks = events_of(d, EventKind.COMMAND_ACK)
    assert not d.armed and not acks[0].accepted and acks[0].reason.code is ReasonCode.OUTSIDE_FENCE
    d = h.command(GcsCommandKind.ARM, force=True)
    assert d.armed
    assert events_of(h.command(GcsCommandKind.ARM), EventKind.COMMAND_ACK)[0].accepted  # already armed


def test_disarm_refused_in_the_air_accepted_on_ground() -> None:
    h = Harness()
    h.airborne()
    assert not events_of(h.command(GcsCommandKind.DISARM), EventKind.COMMAND_ACK)[0].accepted
    assert not h.command(GcsCommandKind.DISARM, force=True).armed
    assert events_of(h.command(GcsCommandKind.DISARM), EventKind.COMMAND_ACK)[0].accepted


def test_mode_commands_take_authority_back_and_need_arming() -> None:
    h = Harness()
    assert not events_of(h.command(GcsCommandKind.RTL), EventKind.COMMAND_ACK)[0].accepted
    h.airborne()
    h.grant()
    d = h.command(GcsCommandKind.RTL)
    assert d.authority is Authority.TRUSTED and d.behavior is Behavior.RTL
    assert events_of(d, EventKind.AUTHORITY)[0].reason.code is ReasonCode.GCS_COMMAND
    assert h.command(GcsCommandKind.LAND).behavior is Behavior.LAND
    assert h.command(GcsCommandKind.HOLD).behavior is Behavior.HOLD
    assert h.command(GcsCommandKind.MISSION).behavior is Behavior.MISSION
    assert not events_of(h.command(GcsCommandKind.TAKEOFF), EventKind.COMMAND_ACK)[0].accepted


def test_mode_command_on_ground_refused_except_land() -> None:
    h = Harness()
    h.state = replace(HOVER_10M, pos_ned_m=(0.0, 0.0, 0.0), landed=True)
    h.command(GcsCommandKind.ARM)
    assert not events_of(h.command(GcsCommandKind.HOLD), EventKind.COMMAND_ACK)[0].accepted
    assert events_of(h.command(GcsCommandKind.LAND), EventKind.COMMAND_ACK)[0].accepted


def test_termination_disabled_by_default_and_never_clears_when_enabled() -> None:
    h = Harness()
    h.airborne()
    assert not events_of(h.command(GcsCommandKind.TERMINATE), EventKind.COMMAND_ACK)[0].accepted
    h2 = Harness(cfg=_cfg(arbiter=ArbiterConfig(termination_enabled=True)))
    h2.airborne()
    h2.grant()
    d = h2.command(GcsCommandKind.TERMINATE)
    assert d.behavior is Behavior.TERMINATE and d.command.kind.name == "TERMINATE"
    assert h2.command(GcsCommandKind.HOLD).behavior is Behavior.TERMINATE  # latched: never clears in flight
    den = events_of(h2.request(), EventKind.DENIED)
    assert den and den[0].reason.code is ReasonCode.GCS_COMMAND


def test_landing_disarms_after_two_seconds_on_the_ground() -> None:
    h = Harness()
    h.airborne()
    h.command(GcsCommandKind.LAND)
    h.state = replace(HOVER_10M, pos_ned_m=(0.0, 0.0, 0.0), landed=True)
    d = h.run(1.9)
    assert d.armed
    d = h.run(0.2)
    assert not d.armed and d.behavior is Behavior.IDLE


def test_takeoff_completes_into_hold() -> None:
    h = Harness()
    h.airborne()
    assert h.tick().behavior is Behavior.HOLD


# ------------------------------------------------------------------------------------- clear conditions


def test_when_clear_latch_ends_with_its_condition() -> None:
    rules = {"gcs_link": Rule(experimental=ActionName.RTL, operator=ActionName.WARN, trusted=ActionName.RTL,
                              clear=ClearName.WHEN_CLEAR)}
    h = Harness(cfg=_cfg(arbiter=ArbiterConfig(rules=rules)))
    h.airborne()
    h.gcs_alive = False
    assert h.run(5.1).behavior is Behavior.RTL
    h.gcs_alive = True
    assert h.tick().behavior is Behavior.HOLD


def test_on_request_latch_cleared_by_a_mode_command() -> None:
    h = Harness()
    h.airborne()
    h.gcs_alive = False
    assert h.run(5.1).behavior is Behavior.RTL
    h.gcs_alive = True
    assert h.tick().behavior is Behavior.RTL  # stays until asked
    assert h.command(GcsCommandKind.HOLD).behavior is Behavior.HOLD


# ----------------------------------------------------------------------------------- pure table helpers


def test_column_reads_the_table_per_authority() -> None:
    from merlin.core.config import RuleRow
    from merlin.core.types import MonitorId

    row = RuleRow(MonitorId.ENVELOPE, Action.RTL, Action.WARN, Action.HOLD)  # typed: the compiled core checks it
    assert arbiter.column(row, Authority.EXPERIMENTAL) is Action.RTL
    assert arbiter.column(row, Authority.OPERATOR) is Action.WARN
    assert arbiter.column(row, Authority.TRUSTED) is Action.HOLD
    assert arbiter.column(row, Authority.SHADOW) is Action.HOLD


def test_behavior_is_idle_when_disarmed_and_latched_action_outranks_base() -> None:
    st = ArbiterState()
    assert st.behavior is Behavior.IDLE
    from merlin.core.arbiter import Latch
    from merlin.core.types import Reason

    st = st._replace(armed=True, base=Behavior.HOLD, latches=(Latch("x", Action.WARN, Reason(ReasonCode.NONE), "never"),
                                                              Latch("y", Action.LAND, Reason(ReasonCode.NONE), "never")))
    assert st.behavior is Behavior.LAND


def test_update_is_pure() -> None:
    h = Harness()
    cfg = h.core.cfg
    view = TickView(now=1.0, tripped={}, shadow_tripped={}, newly_tripped=frozenset(), grant_block=None,
                    shadow_block=None, arm_block=None, takeover=False, landed=True)
    a = arbiter.update(ArbiterState(), view, cfg)
    b = arbiter.update(ArbiterState(), view, cfg)
    assert a == b


def test_warn_under_trusted_reports_without_changing_behaviour() -> None:
    rules = {"gcs_link": Rule(experimental=ActionName.RTL, operator=ActionName.WARN, trusted=ActionName.WARN)}
    h = Harness(cfg=_cfg(arbiter=ArbiterConfig(rules=rules)))
    h.airborne()
    h.gcs_alive = False
    d = h.run(5.1)
    assert d.behavior is Behavior.HOLD
    assert any(ReasonCode.GCS_LINK in _reasons(x, EventKind.WARNING) for x in h.history[-60:])


def test_grace_ends_when_the_condition_clears_then_oversight_applies_again() -> None:
    h = Harness(rc_alive=True)
    h.airborne()
    h.state = replace(HOVER_10M, att_rpy_rad=(math.radians(40), 0.0, 0.0))
    h.operator = OperatorInput(takeover=True)
    assert h.tick().authority is Authority.OPERATOR  # condition present at takeover: grace
    h.state = HOVER_10M
    assert h.tick().authority is Authority.OPERATOR  # cleared: grace consumed
    h.state = replace(HOVER_10M, att_rpy_rad=(math.radians(40), 0.0, 0.0))
    assert h.tick().authority is Authority.TRUSTED  # a new violation within the grace window is caught


def test_mission_commanded_on_the_ground_takes_off_first_to_the_lower_of_the_take_off_and_first_waypoint() -> None:
    cfg = MerlinConfig.model_validate({"trusted": {"mission_ned_m": [[20.0, 0.0, -6.0], [20.0, 20.0, -6.0]]}})
    h = Harness(cfg=cfg)
    h.command(GcsCommandKind.ARM)
    d = h.command(GcsCommandKind.MISSION)
    assert events_of(d, EventKind.COMMAND_ACK)[0].accepted
    assert d.authority is Authority.TRUSTED and d.behavior is Behavior.TAKEOFF
    assert h.core.state.arbiter.after_takeoff is Behavior.MISSION
    assert h.core.state.arbiter.takeoff_alt_m == 6.0  # the first waypoint is lower than the take-off height


def test_mission_current_sets_the_waypoint_flown_next_on_the_ground_and_in_the_mission() -> None:
    """MISSION_SET_CURRENT as PX4 takes it: on the ground, disarmed, it sets where a later start flies from; in
    the mission it flies on to that waypoint at once; outside the mission's range it is refused."""
    wps = [[20.0, 0.0, -6.0], [20.0, 20.0, -6.0], [0.0, 20.0, -6.0]]
    h = Harness(cfg=MerlinConfig.model_validate({"trusted": {"mission_ned_m": wps}}))
    h.state = replace(HOVER_10M, pos_ned_m=(0.0, 0.0, 0.0), landed=True, armed=False)
    [ack] = events_of(h.command(GcsCommandKind.MISSION_CURRENT, 1.0), EventKind.COMMAND_ACK)
    assert ack.accepted and h.core.state.mission_index == 1  # disarmed: kept for the flight to come
    for bad in (3.5, -1.0, math.nan, 4.0):
        [ack] = events_of(h.command(GcsCommandKind.MISSION_CURRENT, bad), EventKind.COMMAND_ACK)
        assert not ack.accepted and ack.reason.code is ReasonCode.INVALID_INPUT, bad
    h.command(GcsCommandKind.ARM)
    h.command(GcsCommandKind.TAKEOFF, 6.0)
    h.state = replace(HOVER_10M, pos_ned_m=(0.0, 0.0, -6.0))
    h.run(0.5)
    assert h.command(GcsCommandKind.MISSION).behavior is Behavior.MISSION
    assert h.core.state.guidance.mission_index == 1  # started at the waypoint set on the ground
    [ack] = events_of(h.command(GcsCommandKind.MISSION_CURRENT, 2.0), EventKind.COMMAND_ACK)
    assert ack.accepted and h.core.state.guidance.mission_index == 2
    h.command(GcsCommandKind.MISSION_CURRENT, 3.0)  # the end: the mission is done, its end behaviour follows
    assert h.core.state.guidance.done or h.core.state.guidance.behavior is not Behavior.MISSION


def test_mission_current_without_a_mission_is_refused() -> None:
    h = Harness()
    [ack] = events_of(h.command(GcsCommandKind.MISSION_CURRENT, 0.0), EventKind.COMMAND_ACK)
    assert not ack.accepted and "the mission has 0" in ack.reason.text


def test_goto_and_orbit_without_a_finite_target_or_radius_are_refused_as_invalid() -> None:
    h = Harness()
    h.airborne()
    for cmd in (GcsCommand(GcsCommandKind.GOTO, target_ned_m=None),
                GcsCommand(GcsCommandKind.GOTO, target_ned_m=(math.nan, 0.0, -10.0)),
                GcsCommand(GcsCommandKind.ORBIT, param=0.0, target_ned_m=(0.0, 10.0, -10.0)),
                GcsCommand(GcsCommandKind.ORBIT, param=math.inf, target_ned_m=(0.0, 10.0, -10.0))):
        [ack] = events_of(h.tick(commands=(cmd,)), EventKind.COMMAND_ACK)
        assert not ack.accepted and ack.reason.code is ReasonCode.INVALID_INPUT
    assert h.core.state.arbiter.target_ned_m is None


def test_goto_with_the_fence_disabled_is_not_judged_against_it() -> None:
    cfg = MerlinConfig.model_validate({"geofence": {"enabled": False}})
    h = Harness(cfg=cfg)
    h.airborne()
    d = h.tick(commands=(GcsCommand(GcsCommandKind.GOTO, target_ned_m=(900.0, 0.0, -10.0)),))
    assert events_of(d, EventKind.COMMAND_ACK)[0].accepted and d.behavior is Behavior.HOLD


# ---------------------------------------------------------------------------------- minimum grant height


def test_a_request_below_the_minimum_grant_height_is_denied_with_the_height_and_the_limit() -> None:
    """Below ``handover.min_grant_height_m`` a revocation could not recover above the floor: the request is
    denied naming the height and the limit; at the limit it is granted."""
    cfg = _cfg(handover=HandoverConfig(min_grant_height_m=12.0))
    h = Harness(cfg=cfg)
    h.airborne()  # hovering at 10 m
    d = h.request()
    (denied,) = events_of(d, EventKind.DENIED)
    r = denied.reason
    assert (r.code, r.monitor, r.parameter, r.value, r.limit) == (ReasonCode.PRECONDITION, "arbiter", "altitude_m",
                                                                  10.0, 12.0)
    assert "minimum grant height 12.0 m" in r.text and not events_of(d, EventKind.GRANTED)
    h.state = replace(HOVER_10M, pos_ned_m=(0.0, 0.0, -12.0))
    h.grant()


def test_the_grant_height_precondition_refuses_a_height_that_is_not_a_number() -> None:
    from merlin.core.config import HandoverParams

    assert arbiter.grant_height_block(HandoverParams(), 0.0) is None  # no limit
    limited = HandoverParams(min_grant_height_m=50.0)
    assert arbiter.grant_height_block(limited, 50.0) is None
    assert arbiter.grant_height_block(limited, 49.9) is not None
    assert arbiter.grant_height_block(limited, math.nan) is not None
def test_a_behaviour_completed_on_the_previous_tick_hands_over_to_what_follows_it() -> None:
    """Take-off completion reaches the next tick's arbiter as data: TAKEOFF hands over to what it was started
    for; a flown MISSION to ``trusted.mission_end``, and with HOLD there it stays MISSION (holding at its last
    waypoint)."""
    cfg = Harness().core.cfg
    view = TickView(1.0, {}, {}, frozenset(), None, None, None, False, False, completed=Behavior.TAKEOFF)
    st, events = arbiter.update(ArbiterState(armed=True, base=Behavior.TAKEOFF, after_takeoff=Behavior.MISSION),
                                view, cfg)
    assert (st.base, st.after_takeoff, events) == (Behavior.MISSION, Behavior.HOLD, [])
    flown = view._replace(completed=Behavior.MISSION)
    in_mission = ArbiterState(armed=True, base=Behavior.MISSION)
    assert arbiter.update(in_mission, flown, cfg)[0].base is Behavior.MISSION
    to_rtl = replace(cfg, trusted=replace(cfg.trusted, mission_end=Behavior.RTL))
    assert arbiter.update(in_mission, flown, to_rtl)[0].base is Behavior.RTL
    assert arbiter.update(in_mission, view._replace(completed=None), to_rtl)[0].base is Behavior.MISSION
