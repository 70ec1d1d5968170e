"""One tick of the trusted core: state and inputs in, a decision out.

The stages run in one direction, each reading what the previous one produced (``docs/architecture.md``):

    validate inputs -> monitors (envelope, geofence, watchdogs, nav, battery, redundancy) -> preconditions
        -> arbiter (authority, latched actions, exchange) -> trusted guidance / operator / experimental
        -> command shaping (bumpless) -> decision

:func:`step` is a pure function of ``(config, state, now, inputs)``: no clock, no I/O, no randomness, so a
recorded run replays decision for decision. :class:`TrustedCore` is the convenience wrapper that keeps the
state between calls. Nothing an input contains -- NaN, infinity, absurd magnitudes, missing setpoints --
makes :func:`step` raise: bad values become the ``invalid_input`` faults of the monitors.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from types import MappingProxyType
from typing import Final, NamedTuple

from merlin.core import arbiter, envelope, geofence, watchdog
from merlin.core.arbiter import ArbiterState, TickView
from merlin.core.config import CoreConfig, WatchdogTimeouts
from merlin.core.guidance_policy import GuidanceMemory
from merlin.core.shaping import (
    Blend,
    OperatorMemory,
    blend_start,
    clamp_command,
    demanded_velocity,
    loop_bounded_demand,
    operator_command,
    setpoint_to_command,
    shape,
    track_command,
)
from merlin.core.types import (
    NO_REASON,
    Action,
    Authority,
    AuthorityRequest,
    Behavior,
    Command,
    CommandKind,
    Decision,
    Event,
    EventKind,
    Inputs,
    MonitorId,
    MonitorStatus,
    NavMode,
    OperatorInput,
    Reason,
    ReasonCode,
    RedundancyReport,
    RequestKind,
    Setpoint,
    SetpointKind,
    Vec3,
    VehicleState,
    new_command,
    new_record,
)
from merlin.core.types import finite as _isfinite

# math functions with no native form in mypyc, bound once: compiled, reading a module's attribute costs
# more than the call (docs/benchmarks/sim.md, "Module constants, enum members and math functions in the tick")
_dist: Final = math.dist
_degrees: Final = math.degrees

#: Magnitudes beyond these are not a vehicle state or a setpoint but a fault (``invalid_input``).
MAX_ABS_POSITION_M: Final = 1.0e6
MAX_ABS_VELOCITY_MPS: Final = 500.0
MAX_ABS_RATE_RADPS: Final = 100.0
MAX_ABS_ACCEL_MPS2: Final = 1000.0
MAX_SETPOINT_POSITION_M: Final = 1.0e5
MAX_SETPOINT_VELOCITY_MPS: Final = 100.0
MAX_SETPOINT_YAW_RATE_RADPS: Final = 20.0

# Enum members the tick reads, bound once (``merlin.core.types``, "Enum members on the hot path").
_TRUSTED: Final = Authority.TRUSTED
_OPERATOR: Final = Authority.OPERATOR
_EXPERIMENTAL: Final = Authority.EXPERIMENTAL
_SHADOW: Final = Authority.SHADOW
_IDLE: Final = Behavior.IDLE
_TAKEOFF: Final = Behavior.TAKEOFF
_HOLD: Final = Behavior.HOLD
_MISSION: Final = Behavior.MISSION
_TERMINATE: Final = Behavior.TERMINATE
_ORBIT: Final = Behavior.ORBIT
_NAV_VO: Final = NavMode.VO
_NAV_INERTIAL: Final = NavMode.INERTIAL
_NAV_LOST: Final = NavMode.LOST
_CMD_IDLE: Final = CommandKind.IDLE
_CMD_VELOCITY: Final = CommandKind.VELOCITY
_CMD_TERMINATE: Final = CommandKind.TERMINATE
_NO_ACTION: Final = Action.NONE
_NO_MONITORS: Final[frozenset[MonitorId]] = frozenset()
_M_STATE_INVALID: Final = MonitorId.STATE_INVALID
_M_ENVELOPE: Final = MonitorId.ENVELOPE
_M_GEOFENCE: Final = MonitorId.GEOFENCE
_M_CONTROLLER_HEARTBEAT: Final = MonitorId.CONTROLLER_HEARTBEAT
_M_SETPOINT_STALE: Final = MonitorId.SETPOINT_STALE
_M_SETPOINT_INVALID: Final = MonitorId.SETPOINT_INVALID
_M_RC_LINK: Final = MonitorId.RC_LINK
_M_GCS_LINK: Final = MonitorId.GCS_LINK
_M_NAV_GPS_LOST: Final = MonitorId.NAV_GPS_LOST
_M_NAV_INERTIAL_TIMEOUT: Final = MonitorId.NAV_INERTIAL_TIMEOUT
_M_NAV_LOST: Final = MonitorId.NAV_LOST
_M_BATTERY_LOW: Final = MonitorId.BATTERY_LOW
_M_BATTERY_CRITICAL: Final = MonitorId.BATTERY_CRITICAL
_M_NAV_REDUNDANCY: Final = MonitorId.NAV_REDUNDANCY
# The names SHADOW's reasons carry: the monitor's own name, marked as judged on the commanded values.
_SHADOW_ENVELOPE_NAME: Final = f"{MonitorId.ENVELOPE.value} (commanded)"
_SHADOW_GEOFENCE_NAME: Final = f"{MonitorId.GEOFENCE.value} (commanded)"
#: The watchdogs (and the state's validity) that refuse a grant before anything else is looked at.
_GRANT_WATCHDOGS: Final = (_M_STATE_INVALID, _M_CONTROLLER_HEARTBEAT, _M_SETPOINT_STALE, _M_SETPOINT_INVALID)
#: The monitors of the controller's own link: their establishment before a grant is judged by the heartbeat's
#: unbroken time and the first setpoint's checks, not by a probation (``_revoking_trip``).
_CONTROLLER_LINK: Final = frozenset((_M_CONTROLLER_HEARTBEAT, _M_SETPOINT_STALE, _M_SETPOINT_INVALID))

#: ``nav_gps_lost``'s reason depends on the navigation mode alone (it trips on every tick of a GPS outage):
#: built once per mode. Read-only.
_GPS_NOT_TRUSTED: Final = MappingProxyType({
    mode: Reason(ReasonCode.NAV_DEGRADED, MonitorId.NAV_GPS_LOST, "nav_mode", float(mode), float(NavMode.GPS), 0.0,
                 f"GPS not trusted: navigating on {mode.name}")
    for mode in (NavMode.VO, NavMode.INERTIAL)
})


class CoreState(NamedTuple):
    t_s: float | None = None
    arbiter: ArbiterState = ArbiterState()
    env_since: tuple[float | None, ...] = ()
    shadow_env_since: tuple[float | None, ...] = ()
    hb_alive_since_s: float | None = None
    reported: frozenset[MonitorId] = frozenset()  # monitors whose trip has been reported and not yet cleared
    guidance: GuidanceMemory | None = None  # the trusted behaviour's memory (cfg.guidance's)
    operator: OperatorMemory = OperatorMemory(0.0, None)
    blend: Blend | None = None
    last_command: Command | None = None
    last_source: tuple[Authority, Behavior] | None = None
    last_valid_state: VehicleState = VehicleState()
    clear_statuses: tuple[MonitorStatus, ...] = ()  # one untripped status per table row, built once
    checked_setpoint: Setpoint | None = None
    checked_setpoint_bad: Reason | None = None
    inertial_land_due: bool = False  # nav_inertial_timeout has tripped and navigation is still inertial-only
    mission_index: int = 0  # the mission waypoint to resume at (MISSION left for HOLD and entered again)
    # the envelope's exceedance-budget rings (merlin.core.envelope) and the authority they are charged to
    env_budget: tuple[envelope.BudgetRing, ...] = ()
    env_budget_authority: Authority = Authority.TRUSTED
    # the fence floor applies: from the start (a vehicle first seen airborne, e.g. a fixed wing in flight, is
    # judged at once), not while on the ground, and after a take-off once the vehicle has climbed clear of it,
    # so that the take-off passes through it (scenario adv_floor_takeoff)
    floor_reached: bool = True
    # a controller asking for, or holding, authority granted on the ground flies its own take-off (PX4's
    # offboard flows): the altitude floors are deferred for it until the vehicle is above them; the time it
    # left the ground (None: no such take-off). See _ground_takeoff.
    ground_takeoff_since_s: float | None = None
    # the trusted behaviour that completed on this tick (TAKEOFF at its height, MISSION flown): the next tick's
    # arbiter hands over to what follows it
    completed: Behavior | None = None
    # the last tick a monitor of the vehicle's state whose action would revoke the controller was tripped, and
    # its reason (None: never): a grant waits until it has been clear for handover.monitors_clear_min_s
    revoking_trip: tuple[float, Reason] | None = None


def initial_state(cfg: CoreConfig) -> CoreState:
    n = len(cfg.envelope)
    return CoreState(
        env_since=(None,) * n,
        shadow_env_since=(None,) * n,
        env_budget=(envelope.EMPTY_RING,) * n,
        clear_statuses=tuple(MonitorStatus(r.monitor, False) for r in cfg.rules),
    )


# ------------------------------------------------------------------------------------------ validation


def _finite3(v: object) -> bool:
    return (
        isinstance(v, tuple)
        and len(v) == 3
        and all(isinstance(x, (int, float)) and _isfinite(x) for x in v)
    )


def _bad(monitor: str, param: str, value: object, text: str) -> Reason:
    num = value if isinstance(value, (int, float)) and not isinstance(value, bool) else math.nan
    return Reason(ReasonCode.INVALID_INPUT, monitor, param, float(num), math.nan, 0.0, f"{monitor}: {param} {text}")


def _state_ok(s: VehicleState) -> bool:
    """Fast path: every field finite and within its magnitude bound (NaN fails every comparison)."""
    try:
        p, v, a, w, f = s.pos_ned_m, s.vel_ned_mps, s.att_rpy_rad, s.rates_frd_radps, s.accel_frd_mps2
        lp, lv, la, lw, lf = MAX_ABS_POSITION_M, MAX_ABS_VELOCITY_MPS, 4.0 * math.pi, MAX_ABS_RATE_RADPS, MAX_ABS_ACCEL_MPS2
        return bool(
            len(p) == 3 and len(v) == 3 and len(a) == 3 and len(w) == 3 and len(f) == 3
            and -lp <= p[0] <= lp and -lp <= p[1] <= lp and -lp <= p[2] <= lp
            and -lv <= v[0] <= lv and -lv <= v[1] <= lv and -lv <= v[2] <= lv
            and -la <= a[0] <= la and -la <= a[1] <= la and -la <= a[2] <= la
            and -lw <= w[0] <= lw and -lw <= w[1] <= lw and -lw <= w[2] <= lw
            and -lf <= f[0] <= lf and -lf <= f[1] <= lf and -lf <= f[2] <= lf
            and 0.0 <= s.airspeed_mps <= lv
            and 0.0 <= s.pos_sigma_h_m <= lp and 0.0 <= s.pos_sigma_v_m <= lp
            and 0.0 <= s.nav_inertial_s <= 1.0e7 and 0.0 <= s.battery_frac <= 1.0
            and -math.pi <= s.alpha_rad <= math.pi
            and isinstance(s.nav_mode, NavMode)
            and type(p[0]) is not bool
        )
    except (TypeError, IndexError):
        return False


def validate_state(s: VehicleState) -> Reason | None:
    """None for a usable navigation solution; else the first offending field."""
    if _state_ok(s):
        return None
    checks: tuple[tuple[str, object, float], ...] = (
        ("pos_ned_m", s.pos_ned_m, MAX_ABS_POSITION_M),
        ("vel_ned_mps", s.vel_ned_mps, MAX_ABS_VELOCITY_MPS),
        ("att_rpy_rad", s.att_rpy_rad, 4.0 * math.pi),
        ("rates_frd_radps", s.rates_frd_radps, MAX_ABS_RATE_RADPS),
        ("accel_frd_mps2", s.accel_frd_mps2, MAX_ABS_ACCEL_MPS2),
    )
    for name, v, lim in checks:
        if not _finite3(v):
            return _bad(MonitorId.STATE_INVALID, name, math.nan, f"is not three finite numbers: {v!r}")
        assert isinstance(v, tuple)
        for x in v:
            if abs(x) > lim:
                return _bad(MonitorId.STATE_INVALID, name, x, f"magnitude {x!r} exceeds {lim:g}")
    scalars: tuple[tuple[str, object, float, float], ...] = (
        ("airspeed_mps", s.airspeed_mps, 0.0, MAX_ABS_VELOCITY_MPS),
        ("pos_sigma_h_m", s.pos_sigma_h_m, 0.0, MAX_ABS_POSITION_M),
        ("pos_sigma_v_m", s.pos_sigma_v_m, 0.0, MAX_ABS_POSITION_M),
        ("nav_inertial_s", s.nav_inertial_s, 0.0, 1.0e7),
        ("battery_frac", s.battery_frac, 0.0, 1.0),
        ("alpha_rad", s.alpha_rad, -math.pi, math.pi),
    )
    for name, x, lo, hi in scalars:
        if not isinstance(x, (int, float)) or not _isfinite(x) or x < lo or x > hi:
            return _bad(MonitorId.STATE_INVALID, name, x, f"= {x!r} is outside [{lo:g}, {hi:g}]")
    if not isinstance(s.nav_mode, NavMode):
        return _bad(MonitorId.STATE_INVALID, "nav_mode", math.nan, f"= {s.nav_mode!r} is not a navigation mode")
    return None


def _setpoint_ok(sp: Setpoint) -> bool:
    """Fast path of :func:`validate_setpoint` (NaN fails every comparison)."""
    try:
        if sp.kind is SetpointKind.ATTITUDE:
            a, pi = sp.att_rpy_rad, math.pi
            return bool(len(a) == 3 and -pi <= a[0] <= pi and -pi <= a[1] <= pi and -pi <= a[2] <= pi
                        and 0.0 <= sp.thrust <= 1.0)
        if sp.kind is SetpointKind.POSITION or sp.kind is SetpointKind.VELOCITY:
            p, v = sp.pos_ned_m, sp.vel_ned_mps
            lp, lv, ly, lr = MAX_SETPOINT_POSITION_M, MAX_SETPOINT_VELOCITY_MPS, 4.0 * math.pi, MAX_SETPOINT_YAW_RATE_RADPS
            return bool(len(p) == 3 and len(v) == 3
                        and -lp <= p[0] <= lp and -lp <= p[1] <= lp and -lp <= p[2] <= lp
                        and -lv <= v[0] <= lv and -lv <= v[1] <= lv and -lv <= v[2] <= lv
                        and -ly <= sp.yaw_rad <= ly and -lr <= sp.yaw_rate_radps <= lr)
    except (TypeError, IndexError):
        return False
    return False


def validate_setpoint(sp: Setpoint) -> Reason | None:
    """None for a setpoint the core can act on; else the first offending field (reason ``invalid_input``)."""
    if _setpoint_ok(sp):
        return None
    if not isinstance(sp.kind, SetpointKind):
        return _bad(MonitorId.SETPOINT_INVALID, "kind", math.nan, f"= {sp.kind!r} is not a setpoint kind")
    fields: tuple[tuple[str, object, float], ...]
    if sp.kind is SetpointKind.ATTITUDE:
        fields = (("att_rpy_rad", sp.att_rpy_rad, math.pi),)
        t = sp.thrust
        if not isinstance(t, (int, float)) or not _isfinite(t) or not 0.0 <= t <= 1.0:
            return _bad(MonitorId.SETPOINT_INVALID, "thrust", t, f"= {t!r} is outside [0, 1]")
    else:
        fields = (
            ("pos_ned_m", sp.pos_ned_m, MAX_SETPOINT_POSITION_M),
            ("vel_ned_mps", sp.vel_ned_mps, MAX_SETPOINT_VELOCITY_MPS),
        )
        for name, x, lim in (
            ("yaw_rad", sp.yaw_rad, 4.0 * math.pi),
            ("yaw_rate_radps", sp.yaw_rate_radps, MAX_SETPOINT_YAW_RATE_RADPS),
        ):
            if not isinstance(x, (int, float)) or not _isfinite(x) or abs(x) > lim:
                return _bad(MonitorId.SETPOINT_INVALID, name, x, f"= {x!r} is not finite within +-{lim:g}")
    for name, v, lim in fields:
        if not _finite3(v):
            return _bad(MonitorId.SETPOINT_INVALID, name, math.nan, f"is not three finite numbers: {v!r}")
        assert isinstance(v, tuple)
        for x in v:
            if abs(x) > lim:
                return _bad(MonitorId.SETPOINT_INVALID, name, x, f"magnitude {x!r} exceeds {lim:g}")
    return None


# ---------------------------------------------------------------------------------------------- monitors

def _status(
    clear: MonitorStatus, reason: Reason | None, detail: tuple[tuple[str, float], ...] = ()
) -> MonitorStatus:
    if reason is None and not detail:
        return clear
    name = clear.name
    return MonitorStatus(name, reason is not None, reason if reason is not None else NO_REASON, detail)


def _fence_reason(res: geofence.FenceResult, monitor: str = MonitorId.GEOFENCE) -> Reason:
    return Reason(
        ReasonCode.GEOFENCE,
        monitor,
        res.kind or "fence",
        res.stopping_distance_m,
        res.clearance_m,
        0.0,
        f"{monitor}: projected path of {res.stopping_distance_m:.1f} m reaches the {res.kind or 'fence'}"
        f" boundary (clearance {res.clearance_m:.1f} m)",
    )


def _setpoint_consistency(sp: Setpoint, s: VehicleState, cfg: CoreConfig) -> Reason | None:
    h = cfg.handover
    if sp.kind is SetpointKind.POSITION:
        err = _dist(sp.pos_ned_m, s.pos_ned_m)
        if err > h.max_setpoint_position_error_m:
            return Reason(ReasonCode.SETPOINT_INCONSISTENT, "handover", "position_error_m", err,
                          h.max_setpoint_position_error_m, 0.0,
                          f"refused: first position setpoint is {err:.1f} m from the vehicle")
    if sp.kind is SetpointKind.VELOCITY:
        err = _dist(sp.vel_ned_mps, s.vel_ned_mps)
        if err > h.max_setpoint_velocity_error_mps:
            return Reason(ReasonCode.SETPOINT_INCONSISTENT, "handover", "velocity_error_mps", err,
                          h.max_setpoint_velocity_error_mps, 0.0,
                          f"refused: first velocity setpoint differs by {err:.1f} m/s from the vehicle's")
    if sp.kind is SetpointKind.ATTITUDE:
        err = max(abs(sp.att_rpy_rad[0] - s.att_rpy_rad[0]), abs(sp.att_rpy_rad[1] - s.att_rpy_rad[1]))
        if err > h.max_setpoint_attitude_error_rad:
            return Reason(ReasonCode.SETPOINT_INCONSISTENT, "handover", "attitude_error_deg", _degrees(err),
                          _degrees(h.max_setpoint_attitude_error_rad), 0.0,
                          f"refused: first attitude setpoint is {_degrees(err):.1f} deg from the vehicle's")
    return None


def _grant_block(
    cfg: CoreConfig,
    s: VehicleState,
    inputs: Inputs,
    report: MonitorReport,
    now: float,
    shadow: bool,
    last_trip: tuple[float, Reason] | None = None,
) -> Reason | None:
    """The first precondition for a grant (to SHADOW with ``shadow``) that does not hold now (None: all hold).
    ``last_trip``: when a monitor of the vehicle's state that would revoke the controller last tripped, and why
    (:data:`CoreState.revoking_trip`)."""
    tripped = report.tripped
    for name in _GRANT_WATCHDOGS:
        r = tripped.get(name)
        if r is not None:
            return r
    hb_alive_since = report.hb_alive_since_s
    alive = 0.0 if hb_alive_since is None else now - hb_alive_since
    need = cfg.handover.heartbeat_alive_min_s
    if hb_alive_since is None or alive + envelope.TIME_EPS_S < need:
        return Reason(ReasonCode.HEARTBEAT_NOT_ESTABLISHED, "handover", "heartbeat_alive_s", alive, need, alive,
                      f"refused: controller heartbeat unbroken for {alive:.2f} s, {need:.2f} s required")
    sp = inputs.experimental.setpoint
    if sp is None:
        return Reason(ReasonCode.PRECONDITION, "handover", text="refused: no setpoint received yet")
    if shadow:
        return None
    for row in cfg.rules:
        r = tripped.get(row.monitor)
        if r is not None and row.experimental >= Action.HOLD:
            return r
    probation = _probation_block(cfg.handover.monitors_clear_min_s, last_trip, now)
    if probation is not None:
        return probation
    env = envelope.all_inside(cfg.envelope, report.env_values)  # as the monitor judged them this tick
    if env is not None:
        return env
    nav = cfg.nav
    if nav.experimental_requires_gps and s.nav_mode is not NavMode.GPS:
        return Reason(ReasonCode.NAV_DEGRADED, "nav", "nav_mode", float(s.nav_mode), float(NavMode.GPS), 0.0,
                      f"refused: navigation is {s.nav_mode.name}, GPS required")
    if s.pos_sigma_h_m > nav.max_pos_sigma_h_m:
        return Reason(ReasonCode.NAV_DEGRADED, "nav", "pos_sigma_h_m", s.pos_sigma_h_m, nav.max_pos_sigma_h_m,
                      0.0, f"refused: position sigma {s.pos_sigma_h_m:.2f} m above {nav.max_pos_sigma_h_m:.2f} m")
    cv = envelope.commanded_values(sp, s)
    cmd_env = envelope.all_inside(tuple(lim for lim in cfg.envelope if not math.isnan(cv[lim.index])), cv)
    if cmd_env is not None:
        return replace(cmd_env, text=f"refused: the setpoint commands {cmd_env.parameter}={cmd_env.value:.4g}"
                       f" outside [{cmd_env.limit:.4g}]")
    # below the minimum grant height a revocation would not recover above the floor (a fixed wing's stall
    # recovery: scenario fw_adv_grant_below_recovery_height)
    return (_setpoint_consistency(sp, s, cfg) or _floor_block(cfg, s, report)
            or arbiter.grant_height_block(cfg.handover, s.alt_m))


def _probation_block(clear_min_s: float, last_trip: tuple[float, Reason] | None, now: float) -> Reason | None:
    """A monitor of the vehicle's state trips at once and clears only after a probation: no grant until every
    one whose action would revoke the controller has been clear for ``clear_min_s`` (a monitor flickering at
    its threshold, clear for a tick in the middle of a trusted fence escape, is not a vehicle back within its
    limits: scenario ``fw_adv_grant_during_escape``)."""
    if last_trip is None:
        return None
    t, reason = last_trip
    clear_s = now - t
    if clear_s + envelope.TIME_EPS_S >= clear_min_s:
        return None
    last = f" (last tripped: {reason.text})" if reason.text else ""
    return Reason(ReasonCode.PRECONDITION, reason.monitor, "clear_s", clear_s, clear_min_s, clear_s,
                  f"refused: {reason.monitor} clear for only {clear_s:.2f} s, {clear_min_s:.2f} s required{last}")


def _revoking_trip(cfg: CoreConfig, st: CoreState, now: float, tripped: Mapping[MonitorId, Reason],
                   landed: bool) -> tuple[float, Reason] | None:
    """This tick's :data:`CoreState.revoking_trip`: now, if a monitor of the vehicle's state (not the
    controller's link) whose action would revoke the controller is tripped in flight, else the previous one.
    On the ground a grant is judged on its tick alone, as PX4 starts its position probation at the take-off:
    the altitude floors a landed vehicle is below are the ground take-off's to defer (``_ground_takeoff``)."""
    if tripped and not landed:
        for row in cfg.rules:
            r = tripped.get(row.monitor)
            if r is not None and row.experimental >= Action.HOLD and row.monitor not in _CONTROLLER_LINK:
                return (now, r)
    return st.revoking_trip


def _floor_block(cfg: CoreConfig, s: VehicleState, report: MonitorReport) -> Reason | None:
    """The fence floor does not protect a vehicle below it yet (scenario adv_floor_takeoff): no grant until
    the vehicle has climbed clear of it, unless the controller flies its own take-off (_ground_takeoff)."""
    if report.floor_reached or report.ground_takeoff_since_s is not None or cfg.fence is None:
        return None
    fl = cfg.fence.params.altitude_floor_m
    if fl is None or not cfg.fence.params.enabled:
        return None
    return Reason(ReasonCode.PRECONDITION, _M_GEOFENCE, "altitude_m", s.alt_m, fl, 0.0,
                  f"refused: {s.alt_m:.1f} m is not yet clear of the fence floor {fl:g} m")


def _inertial_landing_due(cfg: CoreConfig, s: VehicleState, already_due: bool) -> Reason | None:
    """``nav_inertial_timeout``: LAND is due when the inertial-only time at touchdown would reach the limit.

    The trusted inertial time (``nav.inertial_time_limit_s``) bounds the landing, not its start: LAND is due
    once ``nav_inertial_s + land_s >= limit``, where ``land_s`` is the vehicle's own LAND from the present
    height above home (the guidance policy's ``land_duration_s``) plus ``nav.inertial_land_margin_s``. On the
    ground there is nothing to land (``land_s = 0``): the rule is then the limit itself. Once due, the landing
    stays due while navigation stays inertial-only (``already_due``): descending as LAND does keeps the sum
    about constant, and noise in the height or the vertical speed must not un-trip and re-trip the monitor.
    """
    limit_s = cfg.nav.inertial_time_limit_s
    if s.landed:
        if s.nav_inertial_s < limit_s and not already_due:
            return None
        return Reason(ReasonCode.NAV_DEGRADED, _M_NAV_INERTIAL_TIMEOUT, "inertial_at_touchdown_s",
                      s.nav_inertial_s, limit_s, s.nav_inertial_s,
                      f"inertial-only navigation on the ground for {s.nav_inertial_s:.1f} s: at its {limit_s:g} s limit")
    height_m = s.alt_m
    land_s = cfg.guidance.land_duration_s(height_m, s.vel_ned_mps[2], cfg.trusted) + cfg.nav.inertial_land_margin_s
    due_s = s.nav_inertial_s + land_s  # a non-finite height gives land_s = inf: due now
    if due_s < limit_s and not already_due:
        return None
    return Reason(ReasonCode.NAV_DEGRADED, _M_NAV_INERTIAL_TIMEOUT, "inertial_at_touchdown_s", due_s, limit_s,
                  s.nav_inertial_s,
                  f"inertial-only navigation for {s.nav_inertial_s:.1f} s: landing from {height_m:.1f} m takes"
                  f" {land_s:.1f} s, due by the {limit_s:g} s limit")


_LEVEL_NAMES: Final = ("NONE", "SIMPLEX", "DUPLEX", "TRIPLEX")


def _redundancy_reason(red: RedundancyReport, min_lanes: int) -> Reason:
    """``nav_redundancy``: a redundant channel is down to fewer healthy lanes than ``min_lanes``. The
    action is the rule table's (default: warn, no change of authority); the text names the level, the
    channels and the nav health the redundancy stage hands on."""
    lanes = red.lanes
    level = _LEVEL_NAMES[lanes] if 0 <= lanes < len(_LEVEL_NAMES) else str(lanes)
    return Reason(ReasonCode.REDUNDANCY_DEGRADED, MonitorId.NAV_REDUNDANCY, "lanes", float(lanes),
                  float(min_lanes), 0.0, f"redundancy degraded to {level}: {red.cause or 'a redundant channel'};"
                  f" nav health {red.nav_health:.2f}")


def _arm_block(cfg: CoreConfig, s: VehicleState, tripped: Mapping[MonitorId, Reason]) -> Reason | None:
    r = tripped.get(MonitorId.STATE_INVALID)
    if r is not None:
        return r
    if cfg.fence is not None and not geofence.contains(cfg.fence, s.pos_ned_m):
        # The estimated position itself, not the fence widened by its sigma: near an edge a GPS-aided start
        # carries the receiver's slow wander and may lie outside with the truth inside. Say by how much, and
        # how sure the estimate is, so that the refusal can be read without the log.
        out_m = -geofence.signed_margin_m(cfg.fence, s.pos_ned_m)
        if not _isfinite(out_m):
            return Reason(ReasonCode.OUTSIDE_FENCE, MonitorId.GEOFENCE,
                          text="refused: arming outside the geofence: no finite position estimate")
        return Reason(ReasonCode.OUTSIDE_FENCE, MonitorId.GEOFENCE, "position", out_m, 0.0, 0.0,
                      f"refused: arming outside the geofence: the estimated position is {out_m:.2f} m outside"
                      f" (position sigma {s.pos_sigma_h_m:.2f} m)")
    for name in (MonitorId.BATTERY_CRITICAL, MonitorId.NAV_LOST):
        r = tripped.get(name)
        if r is not None:
            return r
    return None


def _ground_takeoff(cfg: CoreConfig, st: CoreState, s: VehicleState, now: float,
                    requests: tuple[AuthorityRequest, ...], floor_reached: bool, alt_m: float) -> float | None:
    """When the vehicle left the ground under a take-off flown by the experimental controller (PX4's offboard
    flows: OFFBOARD granted on the ground, the controller's setpoints lift the vehicle), or None when there is
    none and the altitude floors apply as usual.

    Such a take-off starts on the ground, armed, with a request or an exchange under way or authority already
    granted there; while the vehicle is on the ground its clock restarts. It ends, and the floors (the
    envelope's altitude minimum, the fence floor) apply from then on, once the vehicle is above both, once the
    authority is no longer the controller's, at the disarm, and ``handover.ground_takeoff_s`` after it left the
    ground whatever its height: a controller may climb through the floors, not stay below them. Every other
    limit (speeds, attitude, rates, ceiling, fence walls, watchdogs) judges it from the first tick."""
    arb = st.arbiter
    controller = arb.authority is _EXPERIMENTAL or arb.authority is _SHADOW
    exchange = arb.pending is not None or arb.switch is not None
    if arb.armed and s.landed and (controller or exchange or any(
            r.kind is RequestKind.REQUEST or r.kind is RequestKind.REQUEST_SHADOW for r in requests)):
        return now
    since = st.ground_takeoff_since_s
    if since is None or not arb.armed or not (controller or exchange):
        return None
    low = _altitude_floor_m(cfg)
    above = alt_m >= low and (cfg.fence is None or floor_reached)  # (a NaN height is never above)
    if above or now - since > cfg.handover.ground_takeoff_s:
        return None
    return since


def _altitude_floor_m(cfg: CoreConfig) -> float:
    for lim in cfg.envelope:
        if lim.index == envelope.PARAMETER_INDEX["altitude_m"]:
            return lim.min
    return -math.inf


def _floor_deferred(cfg: CoreConfig, values: tuple[float, ...]) -> tuple[float, ...]:
    """The envelope's values with the altitude held at the envelope's minimum while below it (a deferred floor
    judges nothing; its maximum still does)."""
    k = envelope.PARAMETER_INDEX["altitude_m"]
    alt = values[k]
    low = _altitude_floor_m(cfg)
    if not alt < low:  # (NaN stays: never inside)
        return values
    return (*values[:k], low, *values[k + 1:])


# ------------------------------------------------------------------------------------------ the stages


class Checked(NamedTuple):
    """The tick's inputs after validation."""

    s: VehicleState  # the state the tick judges and flies on: the last valid one when the new one is not
    state_bad: Reason | None  # why the state given is unusable (None: usable)
    setpoint: Setpoint | None  # the experimental controller's latest setpoint
    setpoint_bad: Reason | None  # why that setpoint is unusable (None: usable, or none given)


def _validate(st: CoreState, inputs: Inputs) -> Checked:
    raw = inputs.state
    state_bad = None if _state_ok(raw) else validate_state(raw)  # validate_state's fast path, without its call
    s = st.last_valid_state if state_bad is not None else raw
    if state_bad is not None:
        s = replace(s, armed=bool(raw.armed), landed=bool(raw.landed))
    sp = inputs.experimental.setpoint
    # A setpoint is validated once: the edge passes the same immutable object until a new one arrives.
    if sp is None:
        sp_bad = None
    elif sp is st.checked_setpoint:
        sp_bad = st.checked_setpoint_bad
    else:
        sp_bad = validate_setpoint(sp)
    return new_record(Checked, (s, state_bad, sp, sp_bad))


class MonitorReport(NamedTuple):
    """The monitor stage's verdict on this tick, and what the monitors carry to the next one."""

    tripped: dict[MonitorId, Reason]  # the monitors tripped on the vehicle's state, with their reasons
    shadow_tripped: dict[MonitorId, Reason]  # under SHADOW: those tripped on what the controller commands
    env: envelope.EnvelopeResult  # the envelope's timers, exceedance budget and offending parameters
    env_values: tuple[float, ...]  # the envelope's values as judged (the altitude held while a floor is deferred)
    shadow_env_since: tuple[float | None, ...]  # the envelope's timers on the SHADOW controller's commands
    budget_authority: Authority  # the authority the exceedance budget is charged to
    floor_reached: bool  # the fence floor applies (the vehicle has climbed clear of it since it took off)
    ground_takeoff_since_s: float | None  # a take-off the controller flies: the floors deferred (_ground_takeoff)
    hb_alive_since_s: float | None  # the controller's heartbeat unbroken since
    rc_lost: bool  # the RC link has timed out


def monitor(cfg: CoreConfig, st: CoreState, now: float, dt: float, inputs: Inputs, c: Checked) -> MonitorReport:
    """The monitor stage: every monitor of the rule table on this tick's inputs, in the table's terms."""
    s = c.s
    tripped: dict[MonitorId, Reason] = {}
    if c.state_bad is not None:
        tripped[_M_STATE_INVALID] = c.state_bad
    # The budget charges the interval since the previous tick to the authority that was in force over it;
    # a new authority starts from an empty budget (its own time outside only).
    budget_auth = st.arbiter.authority
    budget = st.env_budget if budget_auth is st.env_budget_authority else (envelope.EMPTY_RING,) * len(cfg.envelope)
    # The floor applies unless the vehicle has been on the ground and not yet climbed clear of it since (a NaN
    # height compares False: never clear), so the trusted take-off climbs through it instead of tripping it.
    floor_reached = not s.landed and cfg.fence is not None and (
        st.floor_reached or geofence.clear_of_floor(cfg.fence, s.pos_ned_m, s.pos_sigma_v_m))
    env_values = envelope.envelope_values(inputs.state)
    ground_takeoff = _ground_takeoff(cfg, st, s, now, inputs.experimental.requests, floor_reached, env_values[1])
    if ground_takeoff is not None:
        env_values = _floor_deferred(cfg, env_values)
    env = envelope.update(cfg.envelope, st.env_since, env_values, now, False, budget, dt)
    if env.reason is not None:
        tripped[_M_ENVELOPE] = env.reason
    wind_ne = (0.0, 0.0)
    if cfg.fence is not None:
        if cfg.fence.params.vehicle == "fixed_wing":  # a fixed wing's escape turn drifts with the wind
            wind_ne = geofence.wind_triangle_ne(s.vel_ned_mps, s.airspeed_mps, s.att_rpy_rad[2])
        fence_trip = _fence_monitor(cfg, cfg.fence, st.last_command, c, floor_reached, wind_ne)
        if fence_trip is not None:
            tripped[_M_GEOFENCE] = fence_trip
    rc_lost = _watchdog_monitors(cfg.watchdogs, now, inputs, c.setpoint_bad, tripped)
    if c.state_bad is None:
        _nav_and_battery_monitors(cfg, s, st.inertial_land_due, tripped)
    red = inputs.redundancy
    if red is not None and red.lanes < cfg.nav.redundancy_min_lanes:
        tripped[_M_NAV_REDUNDANCY] = _redundancy_reason(red, cfg.nav.redundancy_min_lanes)
    hb_since = watchdog.alive_since(now, inputs.experimental.heartbeat_t_s, cfg.watchdogs.controller_heartbeat_s,
                                    st.hb_alive_since_s)
    shadow_tripped: dict[MonitorId, Reason] = {}
    shadow_since: tuple[float | None, ...] = (None,) * len(cfg.envelope)
    if st.arbiter.authority is _SHADOW:
        shadow_tripped, shadow_since = _shadow_monitors(cfg, st.shadow_env_since, now, c, tripped, floor_reached,
                                                        wind_ne)
    return new_record(MonitorReport, (tripped, shadow_tripped, env, env_values, shadow_since, budget_auth,
                                      floor_reached, ground_takeoff, hb_since, rc_lost))


def _fence_monitor(cfg: CoreConfig, fence: geofence.Fence, last: Command | None, c: Checked, floor_reached: bool,
                   wind_ne: tuple[float, float]) -> Reason | None:
    """``geofence``: the projected path of the vehicle, driven by the command being flown, against the fence."""
    s, sp = c.s, c.setpoint
    # the command being flown (the last actuated one) drives the vehicle during the reaction time too;
    # an experimental velocity command is a ramp towards its clamped setpoint (track_command) that goes on
    # during the reaction time: the projection takes the setpoint itself, the commanded intent
    flown = last
    if (flown is not None and flown.source is _EXPERIMENTAL and flown.kind is _CMD_VELOCITY
            and cfg.clamp is not None and sp is not None and c.setpoint_bad is None):
        flown = clamp_command(setpoint_to_command(sp, s, _EXPERIMENTAL, cfg.trusted), cfg.clamp)
    prm = fence.params
    demand = None if prm.vehicle == "fixed_wing" else demanded_velocity(flown, s, prm.reaction_time_s,
                                                                        prm.gravity_mps2)
    if demand is not None and cfg.clamp is not None and flown is not None and flown.kind is _CMD_VELOCITY:
        # as far as the velocity loop flying the command can take the vehicle in the reaction time
        demand = loop_bounded_demand(demand, last, s, prm.reaction_time_s, cfg.clamp, prm.gravity_mps2)
    # a fixed wing's escape first rolls out a bank towards the other side (geofence.fixed_wing_turn)
    bank = s.att_rpy_rad[0] if prm.vehicle == "fixed_wing" else 0.0
    res = geofence.check(fence, s.pos_ned_m, s.vel_ned_mps, s.pos_sigma_h_m, s.pos_sigma_v_m, floor_reached,
                         wind_ne, demand, bank)
    return _fence_reason(res) if res.tripped else None


def _watchdog_monitors(wd: WatchdogTimeouts, now: float, inputs: Inputs, sp_bad: Reason | None,
                       tripped: dict[MonitorId, Reason]) -> bool:
    """The controller's heartbeat and setpoint, the RC and ground-station links; True when the RC link is lost."""
    exp = inputs.experimental
    hb_t, sp_t = exp.heartbeat_t_s, exp.setpoint_t_s
    if hb_t is None or not now - hb_t <= wd.controller_heartbeat_s:  # "not <=": a NaN time is expired too
        tripped[_M_CONTROLLER_HEARTBEAT] = watchdog.reason(
            ReasonCode.CONTROLLER_HEARTBEAT, _M_CONTROLLER_HEARTBEAT, now, hb_t, wd.controller_heartbeat_s)
    if sp_t is None or not now - sp_t <= wd.setpoint_stale_s:
        tripped[_M_SETPOINT_STALE] = watchdog.reason(
            ReasonCode.SETPOINT_STALE, _M_SETPOINT_STALE, now, sp_t, wd.setpoint_stale_s)
    if sp_bad is not None:
        tripped[_M_SETPOINT_INVALID] = sp_bad
    rc_t, gcs_t = inputs.operator.link_t_s, inputs.gcs_link_t_s
    rc_lost = rc_t is not None and not now - rc_t <= wd.rc_link_s
    if rc_lost:
        tripped[_M_RC_LINK] = watchdog.reason(ReasonCode.RC_LINK, _M_RC_LINK, now, rc_t, wd.rc_link_s)
    if gcs_t is not None and not now - gcs_t <= wd.gcs_link_s:
        tripped[_M_GCS_LINK] = watchdog.reason(ReasonCode.GCS_LINK, _M_GCS_LINK, now, gcs_t, wd.gcs_link_s)
    return rc_lost


def _nav_and_battery_monitors(cfg: CoreConfig, s: VehicleState, inertial_land_due: bool,
                              tripped: dict[MonitorId, Reason]) -> None:
    """The navigation mode's monitors and the battery's, on a valid state."""
    mode = s.nav_mode
    if mode is _NAV_VO or mode is _NAV_INERTIAL:
        tripped[_M_NAV_GPS_LOST] = _GPS_NOT_TRUSTED[mode]
    if mode is _NAV_INERTIAL:
        r = _inertial_landing_due(cfg, s, inertial_land_due)
        if r is not None:
            tripped[_M_NAV_INERTIAL_TIMEOUT] = r
    if mode is _NAV_LOST:
        tripped[_M_NAV_LOST] = Reason(ReasonCode.NAV_LOST, _M_NAV_LOST, "nav_mode", float(mode), 0.0, 0.0,
                                      "navigation lost")
    bat = cfg.battery
    if s.battery_frac < bat.critical_frac:
        tripped[_M_BATTERY_CRITICAL] = Reason(ReasonCode.BATTERY_CRITICAL, _M_BATTERY_CRITICAL, "battery_frac",
                                              s.battery_frac, bat.critical_frac)
    if s.battery_frac < bat.low_frac:
        tripped[_M_BATTERY_LOW] = Reason(ReasonCode.BATTERY_LOW, _M_BATTERY_LOW, "battery_frac", s.battery_frac,
                                         bat.low_frac)


def _shadow_monitors(cfg: CoreConfig, since: tuple[float | None, ...], now: float, c: Checked,
                     tripped: dict[MonitorId, Reason], floor_reached: bool, wind_ne: tuple[float, float],
                     ) -> tuple[dict[MonitorId, Reason], tuple[float | None, ...]]:
    """SHADOW: judge what the controller commands, not what the vehicle does (the envelope on the commanded
    values, the fence on the commanded velocity); the other monitors as on the vehicle's state."""
    shadow: dict[MonitorId, Reason] = {k: v for k, v in tripped.items() if k is not _M_ENVELOPE and k is not _M_GEOFENCE}
    s, sp = c.s, c.setpoint
    if sp is None or c.setpoint_bad is not None:
        return shadow, since
    senv = envelope.update(cfg.envelope, since, envelope.commanded_values(sp, s), now, skip_nan=True)
    if senv.reason is not None:
        shadow[_M_ENVELOPE] = replace(senv.reason, monitor=_SHADOW_ENVELOPE_NAME)
    if cfg.fence is not None and sp.kind is not SetpointKind.ATTITUDE:
        cmd = setpoint_to_command(sp, s, _SHADOW, cfg.trusted)
        fr = geofence.check(cfg.fence, s.pos_ned_m, cmd.vel_ned_mps, s.pos_sigma_h_m, s.pos_sigma_v_m,
                            floor_reached, wind_ne)
        if fr.tripped:
            shadow[_M_GEOFENCE] = _fence_reason(fr, _SHADOW_GEOFENCE_NAME)
    return shadow, senv.since


def _tick_view(cfg: CoreConfig, st: CoreState, now: float, inputs: Inputs, c: Checked,
               report: MonitorReport) -> TickView:
    """What the arbiter reads: the monitors' verdict, and the preconditions where an exchange or a command
    needs them."""
    exp, op, tripped = inputs.experimental, inputs.operator, report.tripped
    need_block = bool(exp.requests) or st.arbiter.switch is not None
    grant_block = _grant_block(cfg, c.s, inputs, report, now, False, st.revoking_trip) if need_block else None
    shadow_block = _grant_block(cfg, c.s, inputs, report, now, True) if need_block else None
    arm_block = _arm_block(cfg, c.s, tripped) if inputs.gcs_commands else None
    newly = frozenset(k for k in tripped if k not in st.reported) if tripped else _NO_MONITORS
    return new_record(TickView, (
        now, tripped, report.shadow_tripped, newly, grant_block, shadow_block, arm_block,
        bool(op.takeover) and not report.rc_lost and op.link_t_s is not None,  # takeover
        bool(c.s.landed), exp.requests, inputs.gcs_commands, st.completed,
    ))


class TrustedStep(NamedTuple):
    """What the trusted behaviour flew this tick."""

    memory: GuidanceMemory | None  # the behaviour's memory (None: Merlin's own autopilot does not fly)
    setpoint: Setpoint | None  # the behaviour's setpoint, to be shaped into the command
    mission_index: int  # the mission waypoint to resume at
    completed: Behavior | None  # TAKEOFF at its height or MISSION flown: the arbiter hands over next tick


def _fly_trusted(cfg: CoreConfig, st: CoreState, arb: ArbiterState, behavior: Behavior, now: float, dt: float,
                 s: VehicleState, events: list[Event]) -> TrustedStep:
    """Merlin's own behaviour, flown by the vehicle's guidance policy while it holds authority (or SHADOW)."""
    policy, g, before = cfg.guidance, st.guidance, st.arbiter
    # a new flight starts the mission from its start (the index is reset at the disarm), unless a
    # MISSION_CURRENT sets where it goes on from (in flight or on the ground, as PX4's MISSION_SET_CURRENT)
    mission_index = st.mission_index if arb.armed or not before.armed else 0
    jumped = arb.mission_jump_seq != before.mission_jump_seq
    if jumped:
        mission_index = arb.mission_jump_index
    if not (arb.authority in (_TRUSTED, _SHADOW) and arb.armed) or behavior is _IDLE or behavior is _TERMINATE:
        return new_record(TrustedStep, (None, None, mission_index, None))
    if g is None or g.behavior is not behavior or arb.target_seq != before.target_seq or (
            arb.target_ned_m is None and before.target_ned_m is not None):  # new behaviour, GOTO/ORBIT, or target dropped
        g = policy.enter(behavior, s, cfg.trusted, cfg.fence, g, arb.takeoff_alt_m, mission_index)
        if g.note:  # the behaviour cannot fly as asked inside the range (no route home, a moved hold point)
            _route_warning(events, now, "no_route" if g.fallback else "safe_point", g.note)
    elif jumped and behavior is _MISSION:
        g = policy.mission_jump(g, mission_index)  # flying the mission: on to the new waypoint
    if arb.target_ned_m is not None and g.goto_ned_m != arb.target_ned_m and (behavior is _HOLD or behavior is _ORBIT):
        g = policy.goto(g, arb.target_ned_m, s, cfg.fence)  # GOTO's point, ORBIT's centre (at the command)
        if g.note:  # GOTO has no route inside the range: it holds where it is
            _route_warning(events, now, "no_route", g.note)
    tp = cfg.trusted if not arb.speed_mps else cfg.trusted.at_speed(arb.speed_mps)
    if behavior is _ORBIT:
        g, setpoint = policy.orbit_step(g, s, tp, dt, arb.orbit_radius_m, arb.orbit_speed_mps)
    else:
        g, setpoint = policy.step(g, s, tp, dt)
    completed = None
    if behavior is _TAKEOFF and g.done:
        completed = _TAKEOFF
    elif behavior is _MISSION:
        mission_index = g.mission_index
        if g.done:  # flown: a later start flies it again from the first waypoint
            mission_index, completed = 0, _MISSION
    return new_record(TrustedStep, (g, setpoint, mission_index, completed))


def _route_warning(events: list[Event], now: float, what: str, note: str) -> None:
    events.append(Event(now, EventKind.WARNING, reason=Reason(ReasonCode.GEOFENCE, "route", what, text=note)))


def _incoming(cfg: CoreConfig, st: CoreState, arb: ArbiterState, source: tuple[Authority, Behavior], dt: float,
              op: OperatorInput, c: Checked, floor_reached: bool, trusted_sp: Setpoint | None,
              trusted_ff: Vec3 | None = None) -> tuple[OperatorMemory, Command]:
    """The command of the source in authority, before bumpless shaping (and the operator's memory)."""
    authority, behavior = source
    s, sp = c.s, c.setpoint
    op_mem = st.operator
    if source != st.last_source and authority is _OPERATOR:
        op_mem = _operator_memory(st, s, _M_GEOFENCE in arb.grace_monitors)
    flies_trusted = (authority is _TRUSTED or authority is _SHADOW) and arb.armed
    if not arb.armed or (flies_trusted and behavior is _IDLE):
        return op_mem, new_command(_CMD_IDLE, authority)
    if flies_trusted and behavior is _TERMINATE:
        return op_mem, new_command(_CMD_TERMINATE, authority)
    if authority is _OPERATOR:
        return operator_command(op, s, op_mem, dt, cfg.operator, cfg.trusted, cfg.fence, floor_reached)
    if authority is _EXPERIMENTAL and sp is not None and c.setpoint_bad is None:
        # commanded intent counts: what the validator accepts is flown only within the vehicle's limits
        incoming = setpoint_to_command(sp, s, authority, cfg.trusted)
        if cfg.clamp is not None:
            incoming = track_command(clamp_command(incoming, cfg.clamp), st.last_command, s, dt, cfg.clamp)
        return op_mem, incoming
    if trusted_sp is not None:
        own = setpoint_to_command(trusted_sp, s, _TRUSTED, cfg.trusted)
        return op_mem, own if trusted_ff is None else own._replace(accel_ned_mps2=trusted_ff)
    # unreachable in practice: EXPERIMENTAL without a valid setpoint is revoked this tick
    return op_mem, new_command(_CMD_VELOCITY, _TRUSTED, yaw_rad=s.att_rpy_rad[2])


def _feedforward(memory: GuidanceMemory | None) -> Vec3 | None:
    """The acceleration Merlin's own command follows by construction (its braking ramp), for the velocity
    loop; None when there is none."""
    if memory is None:
        return None
    a = memory.accel_ff_ned_mps2
    return a if (a[0] != 0.0 or a[1] != 0.0 or a[2] != 0.0) else None


def _operator_memory(st: CoreState, s: VehicleState, fenced: bool) -> OperatorMemory:
    """The operator's memory at a takeover. A takeover during a fence trip (its override grace) fences the pilot
    for the rest of the session, and the fenced pilot's stick ramps on from the command Merlin was braking with,
    not from the measured velocity: that lags the braking command, and restarting from it undid the braking the
    fence counted on (scenario adv_pilot_regrab_keepout)."""
    last = st.last_command
    ramp_from = (last.vel_ned_mps if fenced and last is not None and last.kind is _CMD_VELOCITY
                 and _isfinite(last.vel_ned_mps[0] + last.vel_ned_mps[1] + last.vel_ned_mps[2]) else None)
    return OperatorMemory(s.att_rpy_rad[2], None, ramp_from, fenced)


def _bumpless(cfg: CoreConfig, st: CoreState, source: tuple[Authority, Behavior], flies_trusted: bool,
              now: float, dt: float, s: VehicleState, incoming: Command) -> tuple[Blend | None, Command]:
    """Command shaping: a change of source blends from the last actuated command (see merlin.core.shaping)."""
    if incoming.kind is _CMD_IDLE or incoming.kind is _CMD_TERMINATE:
        return None, incoming
    if flies_trusted and incoming.kind is _CMD_VELOCITY:
        # Merlin's own command is bumpless by construction: each behaviour starts from the vehicle's
        # measured velocity and moves at most at the braking deceleration the fence projection assumes.
        # Blending it with the revoked source's last command would keep flying that command for the blend
        # window (scenario adv_velocity_step_30mps_100m), so after a safety revocation Merlin brakes from the
        # first tick.
        return None, incoming
    blend = st.blend
    last_cmd = st.last_command
    if source != st.last_source or (last_cmd is not None and last_cmd.kind is not incoming.kind):
        # (on the ground the collective a transfer starts from is none: a controller granted there, which flies
        # its own take-off, starts from motors at rest, not from a hover thrust that nearly lifts off)
        blend = Blend(now, blend_start(last_cmd, incoming, s, 0.0 if s.landed else cfg.trusted.hover_thrust))
        last = blend.start
    else:
        last = last_cmd if last_cmd is not None else incoming
    if blend is None:  # no transition: what shape() returns first thing, without the call
        return None, incoming
    return shape(blend, last, incoming, now, dt, cfg.handover)


class Statuses(NamedTuple):
    """What the monitor stage's verdict says in the table's terms under the tick's authority."""

    statuses: tuple[MonitorStatus, ...]  # every row's status (and SHADOW's commanded ones)
    reported: frozenset[MonitorId]  # the monitors whose trip is reported and not yet cleared
    failsafe: Action  # the worst action the table gives a tripped monitor (the decision's ``failsafe``)


def _statuses(cfg: CoreConfig, st: CoreState, now: float, authority: Authority, report: MonitorReport,
              events: list[Event]) -> Statuses:
    """Every row's status, the edges of the monitors the table gives a consequence under ``authority``
    (reported when tripped, again when cleared), and the failsafe in force."""
    tripped, was_reported, violating = report.tripped, st.reported, report.env.violating
    if not tripped and not was_reported and not violating and not report.shadow_tripped:
        return new_record(Statuses, (st.clear_statuses, _NO_MONITORS, _NO_ACTION))  # a quiet tick: every row clear
    statuses: list[MonitorStatus] = []
    reported: set[MonitorId] = set()
    failsafe = _NO_ACTION
    for row, clear in zip(cfg.rules, st.clear_statuses, strict=True):
        name = row.monitor
        reason = tripped.get(name)
        if reason is None and name not in was_reported and name is not _M_ENVELOPE:
            statuses.append(clear)  # clear, and not reported before: what the steps below give, cheaply
            continue
        statuses.append(_status(clear, reason, violating if name is _M_ENVELOPE else ()))
        action = arbiter.column(row, authority) if reason is not None else _NO_ACTION
        if action > failsafe:
            failsafe = action
        if reason is not None and action is not _NO_ACTION:
            reported.add(name)
            if name not in was_reported:
                events.append(Event(now, EventKind.MONITOR_TRIPPED, reason=reason))
        elif name in was_reported and reason is None:
            events.append(Event(now, EventKind.MONITOR_CLEARED, reason=Reason(ReasonCode.NONE, name)))
        elif name in was_reported:
            reported.add(name)
    for name, reason in report.shadow_tripped.items():
        if name is _M_ENVELOPE or name is _M_GEOFENCE:
            statuses.append(MonitorStatus(f"shadow_{name}", True, reason))
    return new_record(Statuses, (tuple(statuses), frozenset(reported) if reported else _NO_MONITORS, failsafe))


# -------------------------------------------------------------------------------------------------- step


def _start(cfg: CoreConfig, st: CoreState, now: float) -> tuple[float, float, CoreState]:
    """The tick's time (a non-finite one is the previous tick's), its interval, and the state fitted to the
    configuration (a new configuration with other tables starts its timers afresh)."""
    if not isinstance(now, (int, float)) or not _isfinite(now):
        now = st.t_s if st.t_s is not None else 0.0
    dt = 0.0 if st.t_s is None else max(0.0, now - st.t_s)
    if (len(st.env_since) != len(cfg.envelope) or len(st.clear_statuses) != len(cfg.rules)
            or len(st.env_budget) != len(cfg.envelope)):
        st = initial_state(cfg)._replace(arbiter=st.arbiter, t_s=st.t_s, completed=st.completed)
    return now, dt, st


def step(cfg: CoreConfig, st: CoreState, now: float, inputs: Inputs) -> tuple[CoreState, Decision]:
    """Advance the trusted core by one tick: the stages of the module docstring, each called once."""
    now, dt, st = _start(cfg, st, now)
    checked = _validate(st, inputs)
    report = monitor(cfg, st, now, dt, inputs, checked)
    arb, arb_events = arbiter.update(st.arbiter, _tick_view(cfg, st, now, inputs, checked, report), cfg)
    authority, behavior = arb.authority, arb.behavior
    events: list[Event] = []
    trusted = _fly_trusted(cfg, st, arb, behavior, now, dt, checked.s, events)
    if behavior is not (st.last_source[1] if st.last_source is not None else _IDLE):
        events.append(Event(now, EventKind.BEHAVIOR, behavior=behavior))
    source = (authority, behavior)
    op_mem, incoming = _incoming(cfg, st, arb, source, dt, inputs.operator, checked, report.floor_reached,
                                 trusted.setpoint, _feedforward(trusted.memory))
    flies_trusted = (authority is _TRUSTED or authority is _SHADOW) and arb.armed
    blend, command = _bumpless(cfg, st, source, flies_trusted, now, dt, checked.s, incoming)
    statuses, reported, failsafe = _statuses(cfg, st, now, authority, report, events)
    # in field order (built every tick); the names are CoreState's
    new_state = new_record(CoreState, (
        now,  # t_s
        arb,  # arbiter
        report.env.since,  # env_since
        report.shadow_env_since,  # shadow_env_since
        report.hb_alive_since_s,  # hb_alive_since_s
        reported,  # reported
        trusted.memory,  # guidance
        op_mem,  # operator
        blend,  # blend
        command,  # last_command
        source,  # last_source
        checked.s,  # last_valid_state
        st.clear_statuses,  # clear_statuses
        checked.setpoint,  # checked_setpoint
        checked.setpoint_bad,  # checked_setpoint_bad
        # inertial_land_due: stays due while navigation stays inertial-only (an invalid state changes nothing)
        _M_NAV_INERTIAL_TIMEOUT in report.tripped if checked.state_bad is None else st.inertial_land_due,
        trusted.mission_index,  # mission_index
        report.env.budget,  # env_budget
        report.budget_authority,  # env_budget_authority
        report.floor_reached,  # floor_reached
        report.ground_takeoff_since_s,  # ground_takeoff_since_s
        trusted.completed,  # completed
        _revoking_trip(cfg, st, now, report.tripped, checked.s.landed),  # revoking_trip
    ))
    decision = new_record(Decision, (now, authority, behavior, command, statuses, (*arb_events, *events), arb.armed,
                                     arb.pending.seq if arb.pending is not None else 0, arb.revocations, failsafe))
    return new_state, decision


class TrustedCore:
    """Keeps the core's state between ticks: ``core.step(now, inputs) -> Decision``."""

    def __init__(self, cfg: CoreConfig, state: CoreState | None = None) -> None:
        self.cfg = cfg
        self.state = state if state is not None else initial_state(cfg)

    def step(self, now: float, inputs: Inputs) -> Decision:
        self.state, decision = step(self.cfg, self.state, now, inputs)
        return decision
