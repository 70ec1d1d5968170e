"""Merlin's trusted behaviour flown on a foreign autopilot (pure).

After a revocation the trusted core's decision carries the command of its own behaviour (hold, return
on a safe path, land: :mod:`merlin.autopilot`, shaped by the core so the first command after a transfer
brakes from the vehicle's measured velocity). The guard flies it in one of two ways:

- **streamed** (default, multirotors): the command's NED velocity and yaw as SET_POSITION_TARGET_LOCAL_NED
  (velocity and yaw only), which PX4 flies in OFFBOARD and ArduPilot Copter in GUIDED. The vehicle stays in
  the mode the controller had, so the switch is one setpoint, not a mode change; the return keeps to the
  range because it is Merlin's own routed return.
- **streamed targets** (default, fixed wings, whose external-target modes take a point, not a velocity):
  Merlin's fixed-wing behaviour (escape turn, routed RTL, loiters) as the guided point of
  :mod:`merlin.guard.fixedwing_targets`, sent as ArduPlane's GUIDED DO_REPOSITION or PX4's fixed-wing
  offboard position target, the aircraft staying in GUIDED/OFFBOARD;
- **the autopilot's mode** (``guard.fallback_mode``): a braking setpoint (zero velocity: the autopilot
  decelerates at its own limit) for ``guard.brake_s``, then MAV_CMD_DO_SET_MODE to the configured mode (PX4
  AUTO.LOITER/RTL/LAND, Copter BRAKE/LOITER/RTL/SMART_RTL/LAND, Plane LOITER/RTL, QLAND on a QuadPlane). On
  a fixed wing the mode is sent at once (zero velocity does not brake a plane), and LAND is the autopilot's
  return unless it is a VTOL (:func:`merlin.guard.dialects.mode_table`). A fixed wing without a stream
  (none given) is handed to the mode of the core's behaviour.
"""

from __future__ import annotations

from dataclasses import dataclass

from merlin.core.types import CommandKind, Decision, Vec3, VehicleState
from merlin.guard.config import GuardConfig
from merlin.guard.dialects import ModeTable
from merlin.guard.fixedwing_targets import GuidedTarget

ZERO: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class TrustedOutput:
    vel_ned_mps: Vec3 | None = None  # a velocity setpoint to stream
    yaw_rad: float = 0.0
    mode: int | None = None  # or a mode to switch the autopilot to
    target: GuidedTarget | None = None  # or a fixed wing's guided point


def trusted_output(d: Decision, modes: ModeTable, cfg: GuardConfig, since_revocation_s: float,
                   state: VehicleState, fixed_wing_target: GuidedTarget | None = None) -> TrustedOutput:
    """What to send the autopilot ``since_revocation_s`` after Merlin took authority back; on a fixed wing,
    ``fixed_wing_target`` is Merlin's behaviour as a guided point (None: none streamed)."""
    if not modes.streams_setpoints:
        if cfg.fallback_mode is None and fixed_wing_target is not None:
            return TrustedOutput(target=fixed_wing_target)
        mode = modes.fallback[cfg.fallback_mode] if cfg.fallback_mode is not None else modes.behaviour_modes[d.behavior]
        return TrustedOutput(mode=mode)
    if cfg.fallback_mode is not None:
        if since_revocation_s < cfg.brake_s:
            return TrustedOutput(ZERO, state.att_rpy_rad[2])
        return TrustedOutput(mode=modes.fallback[cfg.fallback_mode])
    c = d.command
    if c.kind is CommandKind.VELOCITY:
        return TrustedOutput(c.vel_ned_mps, c.yaw_rad)
    return TrustedOutput(ZERO, state.att_rpy_rad[2])
