"""Build the core's plain runtime configuration from the validated models (degrees -> radians here)."""

from __future__ import annotations

import math
from typing import Any

from merlin.autopilot.guidance import MultirotorGuidance
from merlin.autopilot.multirotor_control import DEFAULT_GAINS
from merlin.config.fence_build import build_fence
from merlin.config.loader import config_sha256
from merlin.config.models import ENVELOPE_PARAMETERS, MerlinConfig
from merlin.core.config import (
    BatteryParams,
    CoreConfig,
    EnvelopeLimit,
    HandoverParams,
    NavParams,
    OperatorParams,
    RuleRow,
    SetpointClamp,
    Takeover,
    TrustedParams,
    WatchdogTimeouts,
)
from merlin.core.envelope import PARAMETER_INDEX
from merlin.core.geofence import Fence
from merlin.core.guidance_policy import GuidancePolicy
from merlin.core.types import Action, Behavior, MonitorId

_DEG = math.pi / 180.0
_ANGLE_PARAMS = {
    "roll_deg", "pitch_deg", "yaw_deg", "roll_rate_degps", "pitch_rate_degps", "yaw_rate_degps", "alpha_deg",
}


def envelope_limits(cfg: MerlinConfig, stage: str | None = None) -> tuple[EnvelopeLimit, ...]:
    """The enabled limits of a stage (the active one by default), in SI units, Table 2 order."""
    limits = cfg.envelope.resolve(stage or cfg.envelope.active_stage)
    out = []
    for name in ENVELOPE_PARAMETERS:
        lim = limits[name]
        if not lim.enabled:
            continue
        scale = _DEG if name in _ANGLE_PARAMS else 1.0
        out.append(
            EnvelopeLimit(
                name=name,
                index=PARAMETER_INDEX[name],
                min=lim.min * scale,
                max=lim.max * scale,
                duration_s=lim.duration_s,
                display_scale=1.0 / scale,
                wraps=name == "yaw_deg",
                min_display=lim.min,
                max_display=lim.max,
                budget_s=lim.budget.outside_s if lim.budget is not None else math.inf,
                budget_window_s=lim.budget.window_s if lim.budget is not None else 0.0,
            )
        )
    return tuple(out)


def min_grant_height_m(cfg: MerlinConfig) -> float | None:
    """The height above home below which the arbiter refuses a grant: the configuration's
    ``handover.min_grant_height_m``, else, for a fixed wing, the height from which its stall recovery keeps
    the floor (:func:`merlin.autopilot.fixedwing_recovery.min_grant_height_m`), else none."""
    if cfg.handover.min_grant_height_m is not None:
        return float(cfg.handover.min_grant_height_m)
    if cfg.vehicle.type.value != "fixed_wing":
        return None
    # the autopilot's recovery law and the aircraft model (the config layer may read the autopilot; the core
    # only receives the number)
    from merlin.autopilot import fixedwing_recovery

    return fixedwing_recovery.min_grant_height_m(cfg)
def _recovery_height_m(cfg: MerlinConfig) -> float:
    """The height a fixed wing's stall recovery may lose, which the fence's floor projection counts: the same
    number the minimum grant height adds to the floor (:func:`merlin.autopilot.fixedwing_recovery.
    recovery_height_bound_m`), so that the floor trips where a grant would be refused. A configuration that
    sets ``handover.min_grant_height_m`` below the derived height (cross-check XC025 warns) accepts that much
    less room above the floor for the floor's trip too (``fixedwing_low_grant.yaml``: none). 0 for a
    multirotor."""
    if cfg.vehicle.type.value != "fixed_wing":
        return 0.0
    from merlin.autopilot import fixedwing_recovery

    bound = fixedwing_recovery.recovery_height_bound_m(cfg)
    configured = cfg.handover.min_grant_height_m
    if configured is None:
        return bound
    floor = fixedwing_recovery.min_grant_height_m(cfg) - bound
    return min(bound, max(0.0, float(configured) - floor))


def _takeover(monitor: MonitorId, oversight_envelope: bool, oversight_geofence: bool) -> Takeover:
    """The table's takeover column: a pilot who takes over during an envelope or geofence trip is given the
    override grace to fly out of it (or is not judged by it at all when its oversight is switched off);
    every other monitor judges the pilot at once."""
    if monitor is MonitorId.ENVELOPE:
        return Takeover.GRACE if oversight_envelope else Takeover.EXEMPT
    if monitor is MonitorId.GEOFENCE:
        return Takeover.GRACE if oversight_geofence else Takeover.EXEMPT
    return Takeover.JUDGED


def guidance_policy(cfg: MerlinConfig, fence: Fence | None) -> GuidancePolicy[Any]:
    """The vehicle's trusted behaviours as the core flies them (:mod:`merlin.core.guidance_policy`): the
    multirotor's (:class:`merlin.autopilot.guidance.MultirotorGuidance`), or the fixed wing's
    (:class:`merlin.autopilot.fixedwing_policy.FixedWingGuidance`: LAND's loiter height over home from the
    fence, its descent at the inner loops' sink limit)."""
    if cfg.vehicle.type.value != "fixed_wing":
        return MultirotorGuidance()
    from merlin.autopilot.fixedwing_behaviours import land_height_m
    from merlin.autopilot.fixedwing_control import FixedWingControlParams
    from merlin.autopilot.fixedwing_policy import FixedWingGuidance

    return FixedWingGuidance(land_height_m(fence), FixedWingControlParams().sink_max_mps)


def _handover_params(cfg: MerlinConfig) -> HandoverParams:
    """The exchange's and the takeover's parameters in the core's units."""
    h = cfg.handover
    return HandoverParams(
        ack_timeout_s=h.ack_timeout_s,
        heartbeat_alive_min_s=h.heartbeat_alive_min_s,
        monitors_clear_min_s=h.monitors_clear_min_s,
        max_setpoint_position_error_m=h.max_setpoint_position_error_m,
        max_setpoint_velocity_error_mps=h.max_setpoint_velocity_error_mps,
        max_setpoint_attitude_error_rad=h.max_setpoint_attitude_error_deg * _DEG,
        cooldown_s=h.cooldown_s,
        max_revocations_per_flight=h.max_revocations_per_flight,
        blend_window_s=h.blend_window_s,
        max_accel_mps2=h.max_accel_mps2,
        max_attitude_rate_radps=h.max_attitude_rate_degps * _DEG,
        max_thrust_rate_per_s=h.max_thrust_rate_per_s,
        min_grant_height_m=min_grant_height_m(cfg),
        ground_takeoff_s=h.ground_takeoff_s,
    )


def build_core_config(cfg: MerlinConfig, source: str = "<config>") -> CoreConfig:
    o, t, v = cfg.operator, cfg.trusted, cfg.vehicle
    rules = tuple(
        RuleRow(
            monitor=MonitorId(name),
            experimental=Action[r.experimental.name],
            operator=Action[r.operator.name],
            trusted=Action[r.trusted.name],
            clear=r.clear,
            takeover=_takeover(MonitorId(name), o.oversight_envelope, o.oversight_geofence),
        )
        for name, r in cfg.arbiter.rules.items()
        # nav_redundancy exists only on a vehicle that reports its redundancy (redundancy.enabled)
        if name != MonitorId.NAV_REDUNDANCY or cfg.redundancy.enabled
    )
    fence = (build_fence(cfg.geofence, cfg.home, cfg.vehicle, source=source,
                         recovery_height_m=_recovery_height_m(cfg)) if cfg.geofence.enabled else None)
    return CoreConfig(
        envelope=envelope_limits(cfg),
        rules=rules,
        fence=fence,
        guidance=guidance_policy(cfg, fence),
        watchdogs=WatchdogTimeouts(
            controller_heartbeat_s=cfg.watchdogs.controller_heartbeat.timeout_s,
            setpoint_stale_s=cfg.watchdogs.setpoint_stale.timeout_s,
            rc_link_s=cfg.watchdogs.rc_link.timeout_s,
            gcs_link_s=cfg.watchdogs.gcs_link.timeout_s,
        ),
        handover=_handover_params(cfg),
        operator=OperatorParams(
            oversight_envelope=o.oversight_envelope,
            oversight_geofence=o.oversight_geofence,
            override_grace_s=o.override_grace_s,
            max_speed_h_mps=o.max_speed_h_mps,
            max_speed_up_mps=o.max_speed_up_mps,
            max_speed_down_mps=o.max_speed_down_mps,
            max_yaw_rate_radps=o.max_yaw_rate_degps * _DEG,
            stick_deadband=o.stick_deadband,
        ),
        trusted=TrustedParams(
            rtl_altitude_m=t.rtl_altitude_m,
            cruise_speed_mps=t.cruise_speed_mps,
            climb_speed_mps=t.climb_speed_mps,
            land_speed_mps=t.land_speed_mps,
            land_final_height_m=t.land_final_height_m,
            rtl_acceptance_m=t.rtl_acceptance_m,
            rtl_direct_radius_m=t.rtl_direct_radius_m,
            position_gain_per_s=t.position_gain_per_s,
            takeoff_altitude_m=t.takeoff_altitude_m,
            max_horizontal_decel_mps2=v.max_horizontal_decel_mps2,
            max_vertical_decel_mps2=v.max_vertical_decel_mps2,
            hover_thrust=v.hover_thrust,
            mission_ned_m=tuple((float(a), float(b), float(c)) for a, b, c in t.mission_ned_m),
            mission_acceptance_m=t.mission_acceptance_m,
            no_route_fallback=t.no_route_fallback,
            mission_speed_mps=tuple(float(v) for v in t.mission_speed_mps),
            mission_end={"hold": Behavior.HOLD, "rtl": Behavior.RTL, "land": Behavior.LAND}[t.mission_end],
        ),
        nav=NavParams(
            experimental_requires_gps=cfg.nav.experimental_requires_gps,
            max_pos_sigma_h_m=cfg.nav.max_pos_sigma_h_m,
            inertial_time_limit_s=cfg.nav.inertial_time_limit_s,
            inertial_land_margin_s=cfg.nav.inertial_land_margin_s,
            redundancy_min_lanes=3 if cfg.redundancy.warn_at == "duplex" else 2,
        ),
        battery=BatteryParams(low_frac=cfg.battery.low_frac, critical_frac=cfg.battery.critical_frac),
        termination_enabled=cfg.arbiter.termination_enabled,
        config_sha256=config_sha256(cfg),
        # a fixed wing flies its speed, not a velocity to hold: its setpoints are judged by the envelope
        clamp=None if v.type.value == "fixed_wing" else SetpointClamp(
            max_speed_h_mps=v.max_speed_h_mps,
            max_speed_up_mps=v.max_speed_up_mps,
            max_speed_down_mps=v.max_speed_down_mps,
            max_tilt_rad=v.max_tilt_deg * _DEG,
            max_accel_h_mps2=v.max_accel_h_mps2,
            max_accel_up_mps2=v.max_vertical_accel_mps2,
            max_accel_down_mps2=v.max_accel_down_mps2,
            max_yaw_rate_radps=v.max_yaw_rate_degps * _DEG,
            # the loop the actuator stage flies (merlin.autopilot.multirotor_stage, its default gains): the
            # fence's projection of a velocity command and the loop are one model
            loop_vel_p_per_s=DEFAULT_GAINS.vel_p_xy_per_s,
            loop_vel_i_max_mps2=DEFAULT_GAINS.vel_i_xy_max_mps2,
            loop_vel_d_s=DEFAULT_GAINS.vel_d_xy,
            loop_max_tilt_rad=DEFAULT_GAINS.tilt_max_rad,
        ),
    )
