"""The core's runtime configuration: plain, frozen, SI units and radians, cheap to read in the tick.

Built once, at the edge, from the validated pydantic models by :func:`merlin.config.runtime.build_core_config`;
the core never imports pydantic or reads a file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Any

from merlin.core.geofence import Fence
from merlin.core.guidance_policy import GuidancePolicy
from merlin.core.types import Action, Behavior, MonitorId


class Clear(StrEnum):
    """When a latched action ends (cf. PX4 failsafe framework's clear conditions). The values are the
    configuration file's spelling (``arbiter.rules.<monitor>.clear``)."""

    WHEN_CLEAR = "when_clear"  # the action ends when the monitor clears
    ON_REQUEST = "on_request"  # the action holds until a new authority exchange or mode command
    NEVER = "never"  # until disarm


class Takeover(StrEnum):
    """Who may take over while a monitor is tripped, and how the pilot who does is judged by it (cf. PX4
    failsafe framework's user-takeover policy). The operator can always take authority with the takeover
    switch; this column says what the monitor then does to the pilot."""

    JUDGED = "judged"  # judged at once by the table's operator column
    GRACE = "grace"  # a trip present at the takeover waits operator.override_grace_s: the pilot flies out of it
    EXEMPT = "exempt"  # the pilot is not judged by this monitor (operator.oversight_* switched off)


@dataclass(frozen=True, slots=True)
class EnvelopeLimit:
    """One envelope parameter in SI units. ``index`` selects the value from :func:`envelope_values`."""

    name: str  # as in the configuration file, with its display unit, e.g. "roll_deg"
    index: int
    min: float
    max: float
    duration_s: float
    display_scale: float = 1.0  # SI value * display_scale = value in the configuration's unit
    wraps: bool = False  # an angle that wraps at +-pi (yaw)
    min_display: float = math.nan  # the bounds exactly as configured (no degree round trip in reports)
    max_display: float = math.nan
    # exceedance budget (a Merlin extension, merlin.core.envelope): at most budget_s outside within any
    # budget_window_s; inf: no budget (the paper's continuous duration alone)
    budget_s: float = math.inf
    budget_window_s: float = 0.0

    def shown_limit(self, value_si: float) -> float:
        """The configured bound a value violates, in the configuration's unit."""
        low = value_si < self.min
        if low:
            return self.min_display if math.isfinite(self.min_display) else self.min * self.display_scale
        return self.max_display if math.isfinite(self.max_display) else self.max * self.display_scale


@dataclass(frozen=True, slots=True)
class RuleRow:
    """One row of the arbiter's table: the monitor, its action under each authority, when a latched action
    ends, and who may take over while it is tripped."""

    monitor: MonitorId
    experimental: Action
    operator: Action
    trusted: Action
    clear: Clear = Clear.ON_REQUEST
    takeover: Takeover = Takeover.JUDGED


@dataclass(frozen=True, slots=True)
class WatchdogTimeouts:
    controller_heartbeat_s: float = 0.5
    setpoint_stale_s: float = 0.5
    rc_link_s: float = 1.0
    gcs_link_s: float = 5.0


@dataclass(frozen=True, slots=True)
class HandoverParams:
    ack_timeout_s: float = 1.0
    heartbeat_alive_min_s: float = 1.0
    monitors_clear_min_s: float = 1.0  # the vehicle's monitors that revoke clear this long before a grant
    max_setpoint_position_error_m: float = 10.0
    max_setpoint_velocity_error_mps: float = 3.0
    max_setpoint_attitude_error_rad: float = 0.2618
    cooldown_s: float = 5.0
    max_revocations_per_flight: int = 3
    blend_window_s: float = 1.0
    max_accel_mps2: float = 6.0
    max_attitude_rate_radps: float = 1.5708
    max_thrust_rate_per_s: float = 1.0
    min_grant_height_m: float | None = None  # no grant below this height above home (None: no limit)
    ground_takeoff_s: float = 10.0


@dataclass(frozen=True, slots=True)
class OperatorParams:
    oversight_envelope: bool = True
    oversight_geofence: bool = True
    override_grace_s: float = 5.0
    max_speed_h_mps: float = 8.0
    max_speed_up_mps: float = 3.0
    max_speed_down_mps: float = 1.5
    max_yaw_rate_radps: float = 1.0472
    stick_deadband: float = 0.05


@dataclass(frozen=True, slots=True)
class TrustedParams:
    rtl_altitude_m: float = 30.0
    cruise_speed_mps: float = 6.0
    climb_speed_mps: float = 2.5
    land_speed_mps: float = 0.8
    land_final_height_m: float = 3.0
    rtl_acceptance_m: float = 2.0
    rtl_direct_radius_m: float = 10.0
    position_gain_per_s: float = 1.0
    takeoff_altitude_m: float = 10.0
    max_horizontal_decel_mps2: float = 4.0
    max_vertical_decel_mps2: float = 3.0
    hover_thrust: float = 0.5
    mission_ned_m: tuple[tuple[float, float, float], ...] = ()
    mission_acceptance_m: float = 2.0
    no_route_fallback: str = "land"  # RTL with no route home inside the range: "hold" or "land" (at a safe point)
    # the speed of the leg towards each mission waypoint (0: cruise speed; never above it), and what the
    # trusted autopilot flies after the last waypoint: HOLD there, RTL or LAND (scenario trusted_mission_rtl)
    mission_speed_mps: tuple[float, ...] = ()
    mission_end: Behavior = Behavior.HOLD

    def at_speed(self, speed_mps: float) -> TrustedParams:
        """These parameters flying at ``speed_mps`` (MAV_CMD_DO_CHANGE_SPEED), never faster than the cruise
        speed, which is also the trusted autopilot's limit."""
        return replace(self, cruise_speed_mps=min(self.cruise_speed_mps, speed_mps))


@dataclass(frozen=True, slots=True)
class NavParams:
    experimental_requires_gps: bool = True
    max_pos_sigma_h_m: float = 5.0
    inertial_time_limit_s: float = 30.0
    inertial_land_margin_s: float = 3.0  # added to LAND's own descent time (guidance.land_duration_s)
    # nav_redundancy trips when a redundant channel has fewer healthy lanes than this: 2 = at simplex
    # (one lane left, no fault can be detected any more), 3 = already at duplex
    redundancy_min_lanes: int = 2


@dataclass(frozen=True, slots=True)
class BatteryParams:
    low_frac: float = 0.25
    critical_frac: float = 0.10


@dataclass(frozen=True, slots=True)
class SetpointClamp:
    """What an experimental setpoint may command, as PX4 clamps offboard setpoints (MPC_XY_VEL_MAX,
    MPC_Z_VEL_MAX_UP, MPC_Z_VEL_MAX_DN, MPC_TILTMAX_AIR), and how fast the trusted inner loops are moved
    onto a new velocity setpoint (MPC_ACC_HOR, MPC_ACC_UP_MAX, MPC_ACC_DOWN_MAX, MPC_YAWRAUTO_MAX).
    SI units and radians."""

    max_speed_h_mps: float = 15.0
    max_speed_up_mps: float = 3.0
    max_speed_down_mps: float = 1.5
    max_tilt_rad: float = 0.7853981633974483  # 45 deg
    max_accel_h_mps2: float = 3.0
    max_accel_up_mps2: float = 4.0
    max_accel_down_mps2: float = 3.0
    max_yaw_rate_radps: float = 0.7853981633974483  # 45 deg/s
    # The trusted velocity loop that flies a velocity command (merlin.autopilot.multirotor_control): its
    # proportional gain, integrator limit, derivative gain on the measured acceleration and tilt limit bound
    # the acceleration a velocity command can still add during the fence's reaction time
    # (merlin.core.shaping.loop_bounded_demand). A gain of 0: not known, and the projection assumes the
    # vehicle's full tilt acceleration towards any demand.
    loop_vel_p_per_s: float = 0.0
    loop_vel_i_max_mps2: float = 0.0
    loop_vel_d_s: float = 0.0
    loop_max_tilt_rad: float = 0.0


@dataclass(frozen=True, slots=True)
class CoreConfig:
    envelope: tuple[EnvelopeLimit, ...]
    rules: tuple[RuleRow, ...]
    fence: Fence | None
    # how the trusted behaviours are flown, per vehicle (merlin.core.guidance_policy); built at the edge
    guidance: GuidancePolicy[Any]
    watchdogs: WatchdogTimeouts = field(default_factory=WatchdogTimeouts)
    handover: HandoverParams = field(default_factory=HandoverParams)
    operator: OperatorParams = field(default_factory=OperatorParams)
    trusted: TrustedParams = field(default_factory=TrustedParams)
    nav: NavParams = field(default_factory=NavParams)
    battery: BatteryParams = field(default_factory=BatteryParams)
    termination_enabled: bool = False
    config_sha256: str = ""
    clamp: SetpointClamp | None = field(default_factory=SetpointClamp)  # None: not clamped (fixed wing)

    def rule(self, monitor: MonitorId | str) -> RuleRow:
        for r in self.rules:
            if r.monitor == monitor:
                return r
        raise KeyError(monitor)
