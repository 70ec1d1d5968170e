"""The guard's simulated autopilot speaking ArduPilot Plane (tests/guard/sim_autopilot.py's wire, a fixed
wing's flight underneath).

What the guard's behaviour on a Plane depends on, as ArduPlane documents it: HEARTBEAT with
MAV_TYPE_FIXED_WING and PLANE_MODE custom modes; the parameters of the start-up check (FS_GCS_ENABL,
FS_LONG_TIMEOUT, FS_LONG_ACTN, MAV_GCS_SYSID); TAKEOFF (climb out on the runway heading to the take-off
altitude, then LOITER); GUIDED circling where it was entered, then flying to the point of a
MAV_CMD_DO_REPOSITION (COMMAND_INT) or a MISSION_ITEM_INT with ``current`` 2 and circling it, with no
setpoint timeout of its own; SET_POSITION_TARGET_GLOBAL_INT in GUIDED changing only the target altitude
(ArduPlane's handler reads nothing else: ``type_mask & 0xFFFB``); LOITER circling where it was entered; RTL
flying home and circling there;
and the GCS failsafe: no HEARTBEAT from MAV_GCS_SYSID for FS_LONG_TIMEOUT with FS_GCS_ENABL 1 or 2 (3 only
in AUTO) runs FS_LONG_ACTN (0 Continue: an auto mode such as GUIDED stays; 1 RTL; 2 Glide as FBWA).

The aircraft is a point mass at a constant 22 m/s (the Aerosonde's cruise, above the envelope's 18.5 m/s
floor), turning at most at a 30 deg bank (0.26 rad/s) and climbing at most 3 m/s: enough to tell a mode
from another and a return from a flyaway, not a flight model. ``bank_deg`` sets another bank limit (Plane's
ROLL_LIMIT_DEG, PX4's FW_R_LIM) and ``roll_rate_degps`` a roll rate (the bank then rolls in and out at it,
as the autopilot's roll time constant and slew limit make it; None: at once), so that an autopilot turning
more weakly or later than a configuration assumes can be flown.
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mav

from merlin.guard.dialects import Dialect, PlaneMode
from merlin.link.px4_modes import Px4AutoSubMode, Px4MainMode, Px4Mode
from tests.guard.sim_autopilot import PX4_PARAMS, SimAutopilot

PLANE_PARAMS = {"FS_GCS_ENABL": 1.0, "FS_LONG_TIMEOUT": 2.0, "FS_LONG_ACTN": 1.0, "MAV_GCS_SYSID": 255.0}
CRUISE_MPS = 22.0
LOITER_RADIUS_M = 80.0
CLIMB_MPS = 3.0


class SimPlane(SimAutopilot):
    mav_type = mav.MAV_TYPE_FIXED_WING

    def __init__(self, guard_port: int, params: dict[str, float] | None = None,
                 flying: tuple[float, float, float] | None = None, bank_deg: float = 30.0,
                 roll_rate_degps: float | None = None, **kw: object) -> None:
        super().__init__(Dialect.ARDUPILOT, guard_port, dict(PLANE_PARAMS if params is None else params), **kw)  # type: ignore[arg-type]
        self.bank_limit_rad = math.radians(bank_deg)
        self.turn_rate_radps = 9.81 * math.tan(self.bank_limit_rad) / CRUISE_MPS
        self.roll_rate_radps = None if roll_rate_degps is None else math.radians(roll_rate_degps)
        self.hold_mode = self.mode = int(PlaneMode.LOITER)
        self.offboard = int(PlaneMode.GUIDED)
        self.course = 0.0
        self.alt_target = 0.0
        self.center: tuple[float, float] = (0.0, 0.0)
        self.airborne = False
        self.roll = 0.0
        if flying is not None:  # already in the air, loitering about (north, east, height) as after a take-off
            n, e, h = flying
            self.armed = self.airborne = True
            self.pos = [n, e - LOITER_RADIUS_M, -h]
            self.center, self.alt_target = (n, e), h
        self.gotos: list[tuple[float, tuple[float, float], float]] = []  # (monotonic, centre NE, height) per goto

    def mode_name(self, m: int | None = None) -> str:
        return PlaneMode(self.mode if m is None else m).name

    def _mode_of(self, name: str) -> int:
        return int({"HOLD": PlaneMode.LOITER, "RTL": PlaneMode.RTL, "TAKEOFF": PlaneMode.TAKEOFF,
                    "GLIDE": PlaneMode.FLY_BY_WIRE_A}[name])

    def _handle(self, msg: object, now: float) -> None:
        name = msg.get_type()  # type: ignore[attr-defined]
        if name == "SET_POSITION_TARGET_GLOBAL_INT":
            self.track.setpoints_t.append(now)
            if self.mode == self.offboard and msg.type_mask & 0xFFFB:  # type: ignore[attr-defined]
                self.alt_target = self._height(int(msg.coordinate_frame), float(msg.alt))  # type: ignore[attr-defined]
            return
        if name == "COMMAND_INT":
            src = (msg.get_srcSystem(), msg.get_srcComponent())  # type: ignore[attr-defined]
            if msg.command != mav.MAV_CMD_DO_REPOSITION:  # type: ignore[attr-defined]
                self._ack(msg.command, mav.MAV_RESULT_UNSUPPORTED, src)  # type: ignore[attr-defined]
                return
            if self.mode != self.offboard and not int(msg.param2) & 1:  # type: ignore[attr-defined]
                self._ack(msg.command, mav.MAV_RESULT_DENIED, src)  # type: ignore[attr-defined]
                return
            self.mode = self.offboard
            self._goto(int(msg.frame), msg.x * 1e-7, msg.y * 1e-7, float(msg.z))  # type: ignore[attr-defined]
            self.gotos.append((now, self.center, self.alt_target))
            self._ack(msg.command, mav.MAV_RESULT_ACCEPTED, src)  # type: ignore[attr-defined]
            return
        if name == "MISSION_ITEM_INT" and int(msg.current) == 2 and self.mode == self.offboard:  # type: ignore[attr-defined]
            self._goto(int(msg.frame), msg.x * 1e-7, msg.y * 1e-7, float(msg.z))  # type: ignore[attr-defined]
            self.gotos.append((now, self.center, self.alt_target))
            return
        super()._handle(msg, now)

    def _height(self, frame: int, alt: float) -> float:
        return alt - self.home[2] if frame in (mav.MAV_FRAME_GLOBAL, mav.MAV_FRAME_GLOBAL_INT) else alt

    def _goto(self, frame: int, lat: float, lon: float, alt: float) -> None:
        """Plane's GUIDED point: flown to, then circled."""
        n, e, _ = self.frame.to_ned(lat, lon, self.home[2])
        self.center = (n, e)
        if not math.isnan(alt):
            self.alt_target = self._height(frame, alt)

    def _set_mode(self, custom: int, now: float) -> int:
        if custom not in {int(m) for m in PlaneMode}:
            return mav.MAV_RESULT_DENIED
        self._enter(custom)
        return mav.MAV_RESULT_ACCEPTED

    def _enter(self, mode: int) -> None:
        self.mode = mode
        if mode in (int(PlaneMode.LOITER), int(PlaneMode.GUIDED)):
            self.center = (self.pos[0], self.pos[1])  # GUIDED loiters where it was entered until given a point
            self.alt_target = -self.pos[2]
        elif mode == int(PlaneMode.RTL):
            self.center = (0.0, 0.0)
            self.alt_target = max(-self.pos[2], 100.0)  # ALT_HOLD_RTL's default, 100 m

    def _command(self, msg: object, now: float) -> None:
        if msg.command == mav.MAV_CMD_NAV_TAKEOFF:  # type: ignore[attr-defined]
            src = (msg.get_srcSystem(), msg.get_srcComponent())  # type: ignore[attr-defined]
            self.mode, self.airborne = int(PlaneMode.TAKEOFF), True
            self.alt_target, self.course = float(msg.param7), 0.0  # type: ignore[attr-defined]
            self._ack(msg.command, mav.MAV_RESULT_ACCEPTED, src)  # type: ignore[attr-defined]
            return
        super()._command(msg, now)

    def _failsafes(self, now: float) -> None:
        enabled = int(self.params["FS_GCS_ENABL"])
        in_auto = self.mode == int(PlaneMode.AUTO)
        if (not self.armed or self.gcs_failsafe or enabled not in (1, 2, 3) or (enabled == 3 and not in_auto)
                or now - self.gcs_hb_t <= self.params["FS_LONG_TIMEOUT"]):
            return
        self.gcs_failsafe = True
        act = int(self.params["FS_LONG_ACTN"])
        if act == 1:
            self._enter(int(PlaneMode.RTL))
        elif act == 2:
            self.mode = int(PlaneMode.FLY_BY_WIRE_A)
        # 0 Continue: GUIDED is an auto mode, it stays

    def _step(self, dt: float, now: float) -> None:
        self._failsafes(now)
        if not (self.armed and self.airborne):
            self.vel = [0.0, 0.0, 0.0]
            return
        name = self.mode_name()
        if name in ("TAKEOFF", "AUTO_TAKEOFF"):
            want = 0.0
            if -self.pos[2] >= self.alt_target - 1.0:
                self._enter(int(PlaneMode.LOITER))
        else:
            dn, de = self.center[0] - self.pos[0], self.center[1] - self.pos[1]
            d = math.hypot(dn, de)
            bearing = math.atan2(de, dn)
            # toward the point, then around it clockwise at LOITER_RADIUS_M
            want = bearing if d > 2.0 * LOITER_RADIUS_M else bearing - math.pi / 2 * min(1.0, d / LOITER_RADIUS_M)
        err = (want - self.course + math.pi) % (2.0 * math.pi) - math.pi
        rate = self.turn_rate_radps
        turn = max(-rate * dt, min(rate * dt, err))
        if self.roll_rate_radps is None:
            self.roll = math.atan(CRUISE_MPS * (turn / dt) / 9.81)  # the coordinated turn's bank, at once
        else:
            want_roll = math.atan(CRUISE_MPS * (turn / dt) / 9.81)
            step = self.roll_rate_radps * dt
            self.roll += max(-step, min(step, want_roll - self.roll))
            turn = 9.81 * math.tan(self.roll) / CRUISE_MPS * dt
        self.course += turn
        climb = 0.0 if name == "FLY_BY_WIRE_A" else max(-CLIMB_MPS, min(CLIMB_MPS, self.alt_target + self.pos[2]))
        self.vel = [CRUISE_MPS * math.cos(self.course), CRUISE_MPS * math.sin(self.course), -climb]
        for i in range(3):
            self.pos[i] += self.vel[i] * dt

    def attitude_rpy(self) -> tuple[float, float, float]:
        """Banked in its turns, heading along its course (no wind: the air mass is still)."""
        flying = self.armed and self.airborne
        return (self.roll if flying else 0.0, 0.0, (self.course + math.pi) % (2.0 * math.pi) - math.pi)

    def _telemetry(self, now: float, n: int) -> None:
        super()._telemetry(now, n)
        if n % 5 == 0:
            speed = CRUISE_MPS if self.airborne and self.armed else 0.0
            self.send(self.m.vfr_hud_encode(speed, speed, int(math.degrees(self.course)) % 360, 50,
                                            -self.pos[2] + self.home[2], -self.vel[2]))


def _px4(main: Px4MainMode, sub: int = 0) -> int:
    return Px4Mode(main, sub).custom_mode


class SimPx4Plane(SimPlane):
    """The same aircraft speaking PX4's fixed wing (PX4 user guide, "Offboard Mode"; PX4's custom modes):
    OFFBOARD accepted only with a setpoint stream (PX4's proof of life), a position target
    (SET_POSITION_TARGET_GLOBAL_INT or _LOCAL_NED with x, y, z used) flown to and circled, AUTO.LOITER
    circling where it was entered, AUTO.RTL flying home; the offboard-loss failsafe: no setpoint for
    COM_OF_LOSS_T in OFFBOARD runs COM_OBL_RC_ACT (3 Return, 5 Hold; 4 Land corkscrews down)."""

    def __init__(self, guard_port: int, params: dict[str, float] | None = None,
                 flying: tuple[float, float, float] | None = None, **kw: object) -> None:
        super().__init__(guard_port, dict(PX4_PARAMS if params is None else params), flying, **kw)  # type: ignore[arg-type]
        self.dialect = Dialect.PX4
        self.hold_mode = self.mode = _px4(Px4MainMode.AUTO, Px4AutoSubMode.LOITER)
        self.offboard = _px4(Px4MainMode.OFFBOARD)
        self.rtl_mode = _px4(Px4MainMode.AUTO, Px4AutoSubMode.RTL)

    def mode_name(self, m: int | None = None) -> str:
        got = Px4Mode.from_custom_mode(self.mode if m is None else m)
        return got.name() if got else str(m)

    def _handle(self, msg: object, now: float) -> None:
        name = msg.get_type()  # type: ignore[attr-defined]
        if name in ("SET_POSITION_TARGET_GLOBAL_INT", "SET_POSITION_TARGET_LOCAL_NED"):
            self.track.setpoints_t.append(now)
            self.sp_t = now
            if self.mode == self.offboard and not msg.type_mask & 0b111:  # type: ignore[attr-defined]
                if name == "SET_POSITION_TARGET_GLOBAL_INT":
                    self._goto(int(msg.coordinate_frame), msg.lat_int * 1e-7, msg.lon_int * 1e-7,  # type: ignore[attr-defined]
                               float(msg.alt))  # type: ignore[attr-defined]
                else:
                    self.center, self.alt_target = (float(msg.x), float(msg.y)), -float(msg.z)  # type: ignore[attr-defined]
                self.gotos.append((now, self.center, self.alt_target))
            return
        SimAutopilot._handle(self, msg, now)

    def _set_mode(self, custom: int, now: float) -> int:
        if custom == self.offboard and now - self.sp_t > 0.5:
            return mav.MAV_RESULT_DENIED  # PX4: OFFBOARD needs a setpoint stream first
        if custom not in (self.offboard, self.hold_mode, self.rtl_mode):
            return mav.MAV_RESULT_UNSUPPORTED
        self._enter(custom)
        return mav.MAV_RESULT_ACCEPTED

    def _enter(self, mode: int) -> None:
        self.mode = mode
        if mode in (self.hold_mode, self.offboard):
            self.center = (self.pos[0], self.pos[1])
            self.alt_target = -self.pos[2]
        elif mode == self.rtl_mode:
            self.center = (0.0, 0.0)
            self.alt_target = max(-self.pos[2], 100.0)

    def _failsafes(self, now: float) -> None:
        if self.armed and self.mode == self.offboard and now - self.sp_t > self.params["COM_OF_LOSS_T"]:
            act = int(self.params["COM_OBL_RC_ACT"])
            self._enter(self.rtl_mode if act == 3 else self.hold_mode)
