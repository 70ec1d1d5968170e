"""What the controller link may send, per authority state (the ICD's controller-link rules)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from merlin.core.types import GcsCommandKind
from merlin.guard.dialects import (
    MAV_AUTOPILOT_ARDUPILOTMEGA,
    MAV_AUTOPILOT_PX4,
    CopterMode,
    detect,
    mode_table,
)
from merlin.guard.gate import GateContext, Route, classify
from merlin.link import autopilot_wire as w

PX4 = mode_table(detect(MAV_AUTOPILOT_PX4, 2, 1, 1))  # type: ignore[arg-type]
COPTER = mode_table(detect(MAV_AUTOPILOT_ARDUPILOTMEGA, 2, 1, 1))  # type: ignore[arg-type]


def ctx(modes=PX4, experimental=False, trusted=False, landed=False, refusal=None,  # type: ignore[no-untyped-def]
        offboard=None) -> GateContext:
    offboard = experimental or trusted if offboard is None else offboard
    return GateContext(modes, experimental, offboard, trusted, landed, refusal, {w.ATTITUDE: 20_000.0})


def cmd(command: int, *p: float) -> w.CommandIn:
    params = tuple(p) + (0.0,) * (7 - len(p))
    return w.CommandIn(command, params, 1, 1, False)  # type: ignore[arg-type]


def test_setpoints_fly_only_with_authority() -> None:
    assert classify(w.SET_POSITION_TARGET_LOCAL_NED, None, ctx(experimental=True)).route is Route.FORWARD
    # the autopilot in its offboard mode without a grant (someone else switched it): dropped
    assert classify(w.SET_POSITION_TARGET_LOCAL_NED, None, ctx(offboard=True)).route is Route.DROP
    assert classify(w.SET_ATTITUDE_TARGET, None, ctx(trusted=True)).route is Route.DROP
    assert classify(w.SET_ATTITUDE_TARGET, None, ctx(trusted=True, offboard=False)).route is Route.DROP
    # outside the offboard mode the autopilot ignores them: they pass as PX4's proof of life
    assert classify(w.SET_POSITION_TARGET_LOCAL_NED, None, ctx(offboard=False)).route is Route.FORWARD


def test_offboard_and_guided_are_requests() -> None:
    assert classify(w.COMMAND_LONG, cmd(w.MAV_CMD_DO_SET_MODE, 1, 6), ctx()).route is Route.REQUEST
    sm = w.SetModeIn(1, int(CopterMode.GUIDED), 1)
    assert classify(w.SET_MODE, sm, ctx(COPTER)).route is Route.REQUEST


def test_leaving_for_a_safe_mode_releases_and_manual_modes_are_denied() -> None:
    hold = cmd(w.MAV_CMD_DO_SET_MODE, 1, 4, 3)  # PX4 AUTO.LOITER
    assert classify(w.COMMAND_LONG, hold, ctx(experimental=True)).route is Route.RELEASE
    # Merlin is flying: the autopilot's mode is not changed; the core gets the hold as a command
    v = classify(w.COMMAND_LONG, hold, ctx(trusted=True))
    assert v.route is Route.BEHAVIOUR and v.behaviour is GcsCommandKind.HOLD
    posctl = cmd(w.MAV_CMD_DO_SET_MODE, 1, 3)
    v = classify(w.COMMAND_LONG, posctl, ctx(experimental=True))
    assert v.route is Route.DENY and "POSCTL" in v.reason
    stab = w.SetModeIn(1, int(CopterMode.STABILIZE), 1)
    assert classify(w.SET_MODE, stab, ctx(COPTER, experimental=True)).route is Route.DENY


def test_while_merlin_flies_hold_return_and_land_are_commands_to_the_core() -> None:
    """As merlin serve takes a controller's hold, return or land after a revocation (MAVSDK's offboard.stop()
    and action.land()): Merlin's trusted autopilot flies them if the core accepts; never forwarded."""
    for c, kind in ((w.MAV_CMD_NAV_LAND, GcsCommandKind.LAND), (w.MAV_CMD_NAV_RETURN_TO_LAUNCH, GcsCommandKind.RTL),
                    (w.MAV_CMD_NAV_LOITER_UNLIM, GcsCommandKind.HOLD)):
        v = classify(w.COMMAND_LONG, cmd(c), ctx(trusted=True))
        assert v.route is Route.BEHAVIOUR and v.behaviour is kind, c
        assert classify(w.COMMAND_LONG, cmd(c), ctx()).route is Route.FORWARD  # nobody flies: the autopilot's
    for mode, kind in ((CopterMode.BRAKE, GcsCommandKind.HOLD), (CopterMode.SMART_RTL, GcsCommandKind.RTL),
                       (CopterMode.LAND, GcsCommandKind.LAND)):
        v = classify(w.SET_MODE, w.SetModeIn(1, int(mode), 1), ctx(COPTER, trusted=True))
        assert v.route is Route.BEHAVIOUR and v.behaviour is kind, mode
    stab = w.SetModeIn(1, int(CopterMode.STABILIZE), 1)
    assert classify(w.SET_MODE, stab, ctx(COPTER, trusted=True)).route is Route.DENY


def test_arming_follows_the_cores_pre_arm_and_kill_passes() -> None:
    arm = cmd(w.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert classify(w.COMMAND_LONG, arm, ctx(landed=True)).route is Route.FORWARD
    v = classify(w.COMMAND_LONG, arm, ctx(landed=True, refusal="outside the fence"))
    assert v.route is Route.DENY and "fence" in v.reason
    assert classify(w.COMMAND_LONG, cmd(w.MAV_CMD_COMPONENT_ARM_DISARM, 0), ctx()).route is Route.DENY
    assert classify(w.COMMAND_LONG, cmd(w.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196), ctx()).route is Route.FORWARD


def test_the_controller_never_rewrites_the_autopilot() -> None:
    for mid in (w.PARAM_SET, w.MISSION_COUNT, w.MISSION_ITEM_INT):
        assert classify(mid, None, ctx(experimental=True)).route is Route.DENY
    assert classify(w.COMMAND_LONG, cmd(w.MAV_CMD_DO_SET_PARAMETER), ctx(experimental=True)).route is Route.DENY
    assert classify(w.MANUAL_CONTROL, None, ctx(experimental=True)).route is Route.DROP


def test_flying_commands_need_authority_and_stream_rates_the_guard_needs_are_kept() -> None:
    repos = cmd(w.MAV_CMD_DO_REPOSITION)
    assert classify(w.COMMAND_INT, repos, ctx()).route is Route.DENY
    assert classify(w.COMMAND_INT, repos, ctx(experimental=True)).route is Route.FORWARD
    slow = cmd(w.MAV_CMD_SET_MESSAGE_INTERVAL, w.ATTITUDE, 1e6)
    assert classify(w.COMMAND_LONG, slow, ctx()).route is Route.ACCEPT  # met by the guard's faster stream
    off = cmd(w.MAV_CMD_SET_MESSAGE_INTERVAL, w.ATTITUDE, -1)
    assert classify(w.COMMAND_LONG, off, ctx()).route is Route.DENY
    fast = cmd(w.MAV_CMD_SET_MESSAGE_INTERVAL, w.ATTITUDE, 10_000)
    assert classify(w.COMMAND_LONG, fast, ctx()).route is Route.FORWARD
    other = cmd(w.MAV_CMD_SET_MESSAGE_INTERVAL, 147, -1)  # BATTERY_STATUS off: not the guard's
    assert classify(w.COMMAND_LONG, other, ctx()).route is Route.FORWARD


@given(experimental=st.booleans(), offboard=st.booleans(), trusted=st.booleans(), landed=st.booleans(),
       msg_id=st.sampled_from(sorted(w.SETPOINT_IDS)))
def test_no_setpoint_flies_the_vehicle_without_authority(experimental: bool, offboard: bool, trusted: bool,
                                                         landed: bool, msg_id: int) -> None:
    """Safety invariant: a controller's setpoint reaches an autopilot that flies setpoints (its offboard mode)
    only while the controller holds EXPERIMENTAL authority, and never while Merlin's trusted autopilot flies."""
    v = classify(msg_id, None, ctx(experimental=experimental, trusted=trusted and not experimental, landed=landed,
                                   offboard=offboard))
    if v.route is Route.FORWARD and not experimental:
        assert not offboard and not trusted


@given(main=st.integers(0, 255), sub=st.integers(0, 255), experimental=st.booleans(), trusted=st.booleans())
def test_no_mode_command_from_the_controller_reaches_a_manual_mode(main: int, sub: int, experimental: bool,
                                                                   trusted: bool) -> None:
    """Safety invariant: whatever PX4 mode the controller asks for, it is forwarded only if it is the
    offboard mode under authority or one of the autopilot's own safe modes, and never while Merlin flies."""
    c = cmd(w.MAV_CMD_DO_SET_MODE, 1, main, sub)
    v = classify(w.COMMAND_LONG, c, ctx(experimental=experimental, trusted=trusted and not experimental))
    custom = PX4.requested_mode(main, sub)
    if v.route in (Route.FORWARD, Route.RELEASE):
        assert custom in PX4.release_modes or (custom == PX4.offboard and experimental)
        assert not (trusted and not experimental)


def test_arduplane_guided_goto_passes_only_with_authority_and_other_mission_items_are_refused() -> None:
    from merlin.guard.dialects import Autopilot, Dialect, VehicleClass, mode_table
    from merlin.guard.gate import GateContext, Route, classify
    from merlin.link import autopilot_wire as w

    modes = mode_table(Autopilot(Dialect.ARDUPILOT, VehicleClass.FIXED_WING, 1, 1, 1))
    goto = w.MissionItemIn(w.MAV_CMD_NAV_WAYPOINT, 2, 6, 29.65, -82.32, 100.0, 1, 1)
    upload = w.MissionItemIn(w.MAV_CMD_NAV_WAYPOINT, 0, 6, 29.65, -82.32, 100.0, 1, 1)

    def ctx(experimental: bool) -> GateContext:
        return GateContext(modes, experimental, experimental, False, False, None, {})

    assert classify(w.MISSION_ITEM_INT, goto, ctx(True)).route is Route.FORWARD
    assert classify(w.MISSION_ITEM_INT, goto, ctx(False)).route is Route.DENY
    assert classify(w.MISSION_ITEM_INT, upload, ctx(True)).route is Route.DENY
