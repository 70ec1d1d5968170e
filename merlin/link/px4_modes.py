"""PX4 custom modes, so that QGroundControl, MAVSDK and MAVProxy show Merlin's state unchanged.

PX4 packs its mode into HEARTBEAT.custom_mode as a little-endian union (PX4-Autopilot,
``src/modules/commander/px4_custom_mode.h``): bytes 0-1 reserved, byte 2 the main mode, byte 3 the
sub-mode; so ``custom_mode = main << 16 | sub << 24``. Main modes: MANUAL 1, ALTCTL 2, POSCTL 3, AUTO 4,
ACRO 5, OFFBOARD 6, STABILIZED 7, RATTITUDE_LEGACY 8, SIMPLE 9, TERMINATION 10. AUTO sub-modes: READY 1,
TAKEOFF 2, LOITER 3, MISSION 4, RTL 5, LAND 6, (7 retired), FOLLOW_TARGET 8, PRECLAND 9.

Merlin's state maps onto them as the ICD states (icd/ICD.md, "HEARTBEAT and modes"): EXPERIMENTAL is
OFFBOARD, so a revocation is visible to every standard tool as a mode change out of OFFBOARD; OPERATOR is
POSCTL (the operator's sticks command velocities, as in PX4's position mode); TRUSTED and SHADOW show
the trusted autopilot's behaviour as the matching AUTO sub-mode.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

from merlin.core.types import Authority, Behavior, GcsCommandKind


class Px4MainMode(IntEnum):
    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7
    RATTITUDE_LEGACY = 8
    SIMPLE = 9
    TERMINATION = 10


class Px4AutoSubMode(IntEnum):
    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6
    FOLLOW_TARGET = 8
    PRECLAND = 9


# MAV_MODE_FLAG (common.xml): the base_mode bits PX4 sets alongside its custom mode.
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_AUTO_ENABLED = 4
MAV_MODE_FLAG_GUIDED_ENABLED = 8
MAV_MODE_FLAG_STABILIZE_ENABLED = 16
MAV_MODE_FLAG_MANUAL_INPUT_ENABLED = 64
MAV_MODE_FLAG_SAFETY_ARMED = 128


@dataclass(frozen=True, slots=True)
class Px4Mode:
    main: Px4MainMode
    sub: int = 0

    @property
    def custom_mode(self) -> int:
        return (int(self.main) << 16) | (int(self.sub) << 24)

    @classmethod
    def from_custom_mode(cls, custom_mode: int) -> Px4Mode | None:
        """Decode HEARTBEAT.custom_mode; None when the main mode is not one PX4 defines."""
        main = (custom_mode >> 16) & 0xFF
        sub = (custom_mode >> 24) & 0xFF
        try:
            return cls(Px4MainMode(main), sub)
        except ValueError:
            return None

    def name(self) -> str:
        if self.main is Px4MainMode.AUTO:
            try:
                return f"AUTO_{Px4AutoSubMode(self.sub).name}"
            except ValueError:
                return f"AUTO_{self.sub}"
        return self.main.name


OFFBOARD = Px4Mode(Px4MainMode.OFFBOARD)
POSCTL = Px4Mode(Px4MainMode.POSCTL)
TERMINATION = Px4Mode(Px4MainMode.TERMINATION)
#: PX4 flies MAV_CMD_DO_ORBIT in its orbit navigation state, reported as POSCTL with sub-mode ORBIT (1)
#: (px4_custom_mode.h, PX4_CUSTOM_SUB_MODE_POSCTL_ORBIT).
PX4_SUB_MODE_POSCTL_ORBIT = 1
ORBIT = Px4Mode(Px4MainMode.POSCTL, PX4_SUB_MODE_POSCTL_ORBIT)

_BEHAVIOR_MODE: dict[Behavior, Px4Mode] = {
    Behavior.IDLE: Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.READY),
    Behavior.TAKEOFF: Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.TAKEOFF),
    Behavior.HOLD: Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.LOITER),
    Behavior.MISSION: Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.MISSION),
    Behavior.RTL: Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.RTL),
    Behavior.LAND: Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.LAND),
    Behavior.TERMINATE: TERMINATION,
    Behavior.ORBIT: ORBIT,
}


def mode_for(authority: Authority, behavior: Behavior) -> Px4Mode:
    """The PX4 mode HEARTBEAT reports for Merlin's authority and trusted behaviour."""
    if authority is Authority.EXPERIMENTAL:
        return OFFBOARD
    if authority is Authority.OPERATOR:
        return POSCTL
    return _BEHAVIOR_MODE[behavior]


def base_mode_for(mode: Px4Mode, armed: bool) -> int:
    """HEARTBEAT.base_mode as PX4 fills it for ``mode`` (custom-mode flag plus the descriptive bits)."""
    flags = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if armed:
        flags |= MAV_MODE_FLAG_SAFETY_ARMED
    if mode.main in (Px4MainMode.MANUAL, Px4MainMode.ALTCTL, Px4MainMode.POSCTL, Px4MainMode.STABILIZED):
        flags |= MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
    if mode.main not in (Px4MainMode.MANUAL, Px4MainMode.ACRO, Px4MainMode.TERMINATION):
        flags |= MAV_MODE_FLAG_STABILIZE_ENABLED
    if mode.main in (Px4MainMode.AUTO, Px4MainMode.OFFBOARD):
        flags |= MAV_MODE_FLAG_GUIDED_ENABLED
    if mode.main is Px4MainMode.AUTO:
        flags |= MAV_MODE_FLAG_AUTO_ENABLED
    return flags


#: What a requested PX4 mode (MAV_CMD_DO_SET_MODE) asks the trusted autopilot to do. OFFBOARD is absent:
#: it is the standard form of an authority REQUEST (see :mod:`merlin.link.commands`).
MODE_COMMANDS: dict[Px4Mode, GcsCommandKind] = {
    Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.LOITER): GcsCommandKind.HOLD,
    Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.TAKEOFF): GcsCommandKind.TAKEOFF,
    Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.MISSION): GcsCommandKind.MISSION,
    Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.RTL): GcsCommandKind.RTL,
    Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.LAND): GcsCommandKind.LAND,
    Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.PRECLAND): GcsCommandKind.LAND,
    TERMINATION: GcsCommandKind.TERMINATE,
}
