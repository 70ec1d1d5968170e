"""What the experimental controller's setpoints ask of the vehicle, as the core judges it (pure).

The controller talks to the autopilot underneath; the core must judge what *that autopilot* will fly, not
what the message could mean elsewhere. The messages are decoded and validated as ``merlin serve`` decodes
them (:func:`merlin.link.codec.decode`, through :class:`merlin.link.autopilot_wire.ControllerSetpoint`), and
turned into the core's :class:`~merlin.core.types.Setpoint` by the same conversions
(:class:`merlin.link.inbound.SetpointIn`, :class:`~merlin.link.inbound.GlobalSetpointIn`,
:class:`~merlin.link.inbound.AttitudeTargetIn` ``to_setpoint``): a position target is a place in the local
frame about home, which the core flies towards at ``trusted.cruise_speed_mps`` and judges by its height
(:func:`merlin.core.shaping.setpoint_to_command`, :func:`merlin.core.envelope.commanded_values`); on a fixed
wing that command is a course, a speed and a climb (:func:`merlin.autopilot.fixedwing_guidance.
targets_from_command`), as the autopilot's own navigation flies to a point and circles it there.

What each autopilot honours, from its documentation:

- **PX4** (multirotor and fixed wing) and **ArduPilot Copter** fly SET_POSITION_TARGET_LOCAL_NED and _GLOBAL_INT
  (position, velocity, or both) and SET_ATTITUDE_TARGET in OFFBOARD/GUIDED, streamed. PX4's fixed-wing
  offboard flies a position target as a point to reach and circle (its setpoint-type bits, 0x1000 take-off,
  0x2000 land, 0x3000 loiter, 0x4000 idle, are forwarded and judged as the position they carry).
- **ArduPilot Plane** (ArduPlane ``GCS_MAVLink_Plane.cpp``; ArduPilot dev docs, "Plane Commands in Guided
  Mode"): GUIDED flies to a point and loiters about it; the point comes from MAV_CMD_DO_REPOSITION
  (COMMAND_INT) or from MISSION_ITEM_INT with ``current`` 2 (a guided "goto"), and stands until replaced
  (GUIDED has no setpoint timeout). SET_POSITION_TARGET_GLOBAL_INT changes only the target's altitude (when
  its type_mask has any bit set besides the z bit: ``type_mask & 0xFFFB``), SET_POSITION_TARGET_LOCAL_NED
  only in MAV_FRAME_LOCAL_OFFSET_NED, by ``-z``; latitude, longitude and velocities are ignored.
  SET_ATTITUDE_TARGET forces roll, pitch, yaw and throttle. Entering GUIDED without a point, Plane
  loiters where it entered it. So on a Plane the core's setpoint is that *standing target*: the vehicle's own
  position until the controller is handed authority (the loiter GUIDED starts with), frozen at the
  transfer, moved by each goto and altitude change, and given to the core every tick while it stands.

**PX4's fixed wing** takes the controller's far point at the transfer as readily as any other: its
fixed-wing position controller (``FixedwingPositionControl::Run`` in ``src/modules/fw_pos_control``) makes
each offboard ``trajectory_setpoint`` position the current waypoint and flies to it, with no check of its
distance (Merlin's own trusted behaviour streams PX4 points two turn radii abeam and loiter centres
kilometres away). The core's first-setpoint rule (``handover.max_setpoint_position_error_m``) is Merlin's,
written for a multirotor, which a far position target sends off at its speed limit; a fixed wing flies any
point the same way, turning at its own bank limit, which the envelope judges, and the fence projection
judges the aircraft's state, not its target. So on a PX4 fixed wing, until the transfer (:meth:`enter`), a
position target is given to the core as the aircraft's own position: outside OFFBOARD PX4 only counts the
stream as proof of life, and the controller's point is judged from its first message after the transfer,
as a Plane's goto is. (A point the envelope would refuse, above its altitude limits, is then revoked on,
not denied at the request.)

A message the core cannot judge (a mask or frame :func:`merlin.link.codec.decode` refuses: acceleration,
terrain altitude, partial triples) never reaches the autopilot: :meth:`ControllerIntent.on_setpoint` returns
the rejection and the guard drops it, as ``merlin serve`` does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from merlin.core.types import Setpoint, SetpointKind, VehicleState
from merlin.geodesy import LocalFrame
from merlin.link import autopilot_wire as w
from merlin.link import codec
from merlin.link import inbound as i

#: ArduPlane's test on SET_POSITION_TARGET_GLOBAL_INT's type_mask: any bit but z's set -> altitude change
PLANE_ALT_MASK = 0xFFFB
MAV_DO_REPOSITION = w.MAV_CMD_DO_REPOSITION


@dataclass(frozen=True, slots=True)
class Refused:
    """A controller message the core cannot judge: not forwarded."""

    detail: str


def _height_m(frame: int, alt_m: float, local: LocalFrame) -> float | None:
    """Height above home of an altitude in a global MAV_FRAME; None for a frame Merlin does not read (terrain)."""
    if frame in i.GLOBAL_AMSL_FRAMES:
        return alt_m - local.alt0_amsl_m
    if frame in i.GLOBAL_RELATIVE_FRAMES:
        return alt_m
    return None


class ControllerIntent:
    """The core's setpoint from the controller's messages, for one autopilot (module docstring).

    ``standing``: the autopilot keeps a target of its own between messages (ArduPlane's GUIDED).
    ``enters_at_vehicle``: until the transfer a position target is the vehicle's own position (PX4's fixed
    wing, module docstring)."""

    def __init__(self, local: LocalFrame, standing: bool, enters_at_vehicle: bool = False) -> None:
        self.local = local
        self.standing = standing
        self.enters_at_vehicle = enters_at_vehicle
        self._entered = False
        self._target_ne_m: tuple[float, float] | None = None  # None: where the vehicle is (GUIDED's entry loiter)
        self._height_m: float | None = None  # None: the vehicle's height
        #: ArduPlane flies the controller's forced attitude instead of its target while they stream: the core
        #: then judges the attitude setpoints as they arrive (stale when they stop), not the standing target
        self.attitude = False

    @property
    def guided(self) -> bool:
        """The autopilot flies the controller's GUIDED (ArduPlane reads GUIDED messages only then)."""
        return self._target_ne_m is not None

    # ----------------------------------------------------------------------------------- streamed

    def on_setpoint(self, rec: object, s: VehicleState) -> Setpoint | Refused | None:
        """The core's setpoint after one of the controller's setpoint messages; None when the autopilot
        ignores it (the standing target is unchanged); :class:`Refused` when the core cannot judge it."""
        if not isinstance(rec, w.ControllerSetpoint):
            return Refused("undecodable setpoint")
        if self.standing:
            return self._plane_setpoint(rec, s)
        d = rec.decoded
        if isinstance(d, codec.Rejected):
            # what is wrong first: a STATUSTEXT keeps 50 characters
            return Refused(f"{d.detail} ({w.message_name(rec.msg_id)})")
        yaw = s.att_rpy_rad[2]
        if isinstance(d, i.SetpointIn):
            sp = d.to_setpoint(s.pos_ned_m, yaw)
        elif isinstance(d, i.GlobalSetpointIn):
            sp = d.to_setpoint(self.local, yaw)
        elif isinstance(d, i.AttitudeTargetIn):
            return d.to_setpoint()
        else:
            return Refused(f"{w.message_name(rec.msg_id)}: not a setpoint Merlin reads")
        if self.enters_at_vehicle and not self._entered and sp.kind is SetpointKind.POSITION:
            return Setpoint(SetpointKind.POSITION, s.pos_ned_m, yaw_rad=sp.yaw_rad)
        return sp

    def _plane_setpoint(self, rec: w.ControllerSetpoint, s: VehicleState) -> Setpoint | Refused | None:
        if rec.msg_id == w.SET_ATTITUDE_TARGET:
            d = rec.decoded
            if not isinstance(d, i.AttitudeTargetIn):
                return Refused(f"SET_ATTITUDE_TARGET: {d.detail if isinstance(d, codec.Rejected) else 'undecodable'}")
            if not self.guided:
                return None  # outside GUIDED Plane ignores it
            self.attitude = True
            return d.to_setpoint()
        if not self.guided:
            return None  # outside GUIDED Plane ignores position targets (and enters GUIDED at its own height)
        if rec.msg_id == w.SET_POSITION_TARGET_GLOBAL_INT:
            if not rec.type_mask & PLANE_ALT_MASK:
                return None
            h = _height_m(rec.frame, rec.z, self.local)
            if h is None or not math.isfinite(h):
                return Refused(f"SET_POSITION_TARGET_GLOBAL_INT: coordinate_frame={rec.frame} alt={rec.z!r}; "
                               "allowed GLOBAL(_INT) 0/5 and GLOBAL_RELATIVE_ALT(_INT) 3/6 with a finite alt")
            self._height_m, self.attitude = h, False
            return self.standing_setpoint(s)
        if rec.msg_id == w.SET_POSITION_TARGET_LOCAL_NED:
            if rec.frame != i.MAV_FRAME_LOCAL_OFFSET_NED:
                return None
            if not math.isfinite(rec.z) or abs(rec.z) > codec.MAX_LOCAL_POS_M:
                return Refused(f"SET_POSITION_TARGET_LOCAL_NED: z={rec.z!r} is not a finite offset")
            self._height_m, self.attitude = self._current_height(s) - rec.z, False
            return self.standing_setpoint(s)
        return None

    # ------------------------------------------------------------------------------ standing target

    def on_goto(self, frame: int, lat_deg: float, lon_deg: float, alt_m: float, s: VehicleState) -> Setpoint | Refused:
        """ArduPlane's GUIDED point (DO_REPOSITION as COMMAND_INT, or MISSION_ITEM_INT ``current`` 2): the
        new standing target. An altitude of NaN keeps the target's (MAVLink's "unchanged")."""
        if not (-90.0 <= lat_deg <= 90.0 and -180.0 <= lon_deg <= 180.0) or (lat_deg == 0.0 and lon_deg == 0.0):
            return Refused(f"goto: lat={lat_deg!r} lon={lon_deg!r} is not a point (degrees, not 0/0)")
        h = self._current_height(s) if math.isnan(alt_m) else _height_m(frame, alt_m, self.local)
        if h is None or not math.isfinite(h):
            return Refused(f"goto: frame={frame} alt={alt_m!r}; allowed GLOBAL(_INT) 0/5 and "
                           "GLOBAL_RELATIVE_ALT(_INT) 3/6")
        n, e, _ = self.local.to_ned(lat_deg, lon_deg)
        self._target_ne_m, self._height_m, self.attitude = (n, e), h, False
        return self.standing_setpoint(s)

    def enter(self, s: VehicleState) -> None:
        """The autopilot enters GUIDED for the controller (the transfer): it loiters where it is until given a
        point, at the height commanded so far (or its own)."""
        self._target_ne_m = (s.pos_ned_m[0], s.pos_ned_m[1])
        self._height_m = -s.pos_ned_m[2]
        self._entered = True

    def reset(self) -> None:
        """The controller's GUIDED is over (a revocation, a release): the next one starts from the vehicle."""
        self._target_ne_m = None
        self._height_m = None
        self.attitude = False
        self._entered = False

    def _current_height(self, s: VehicleState) -> float:
        return self._height_m if self._height_m is not None else -s.pos_ned_m[2]

    def standing_setpoint(self, s: VehicleState) -> Setpoint:
        """The standing target as the core's position setpoint."""
        ne = self._target_ne_m if self._target_ne_m is not None else (s.pos_ned_m[0], s.pos_ned_m[1])
        return Setpoint(SetpointKind.POSITION, (ne[0], ne[1], -self._current_height(s)), yaw_rad=s.att_rpy_rad[2])
