"""Mode numbers and autopilot detection against pymavlink's generated enums (ardupilotmega.xml)."""

from __future__ import annotations

import pytest

from merlin.guard.dialects import (
    CopterMode,
    Dialect,
    FallbackMode,
    PlaneMode,
    UnsupportedAutopilot,
    VehicleClass,
    detect,
    mode_table,
)
from merlin.link import autopilot_wire as wire
from merlin.link.px4_modes import Px4AutoSubMode, Px4MainMode, Px4Mode

M = wire.dialect_module()


def test_copter_and_plane_numbers_match_ardupilotmega_xml() -> None:
    for m in CopterMode:
        assert getattr(M, f"COPTER_MODE_{m.name}") == m.value, m
    for m in PlaneMode:
        assert getattr(M, f"PLANE_MODE_{m.name}") == m.value, m


def test_autopilot_ids_match_common_xml() -> None:
    assert detect(M.MAV_AUTOPILOT_PX4, M.MAV_TYPE_QUADROTOR, 1, 1).dialect is Dialect.PX4  # type: ignore[union-attr]
    ap = detect(M.MAV_AUTOPILOT_ARDUPILOTMEGA, M.MAV_TYPE_FIXED_WING, 7, 1)
    assert ap is not None and ap.dialect is Dialect.ARDUPILOT and ap.vehicle is VehicleClass.FIXED_WING
    assert detect(M.MAV_AUTOPILOT_INVALID, M.MAV_TYPE_GCS, 255, 190) is None  # a ground station


def test_unsupported_autopilot_names_the_field_and_value() -> None:
    with pytest.raises(UnsupportedAutopilot, match=r"HEARTBEAT.autopilot=4"):
        detect(4, M.MAV_TYPE_QUADROTOR, 1, 1)
    with pytest.raises(UnsupportedAutopilot, match=r"HEARTBEAT.type=12"):
        detect(M.MAV_AUTOPILOT_PX4, 12, 1, 1)  # a submarine


def test_px4_table_packs_custom_modes_as_px4_does() -> None:
    t = mode_table(detect(M.MAV_AUTOPILOT_PX4, M.MAV_TYPE_QUADROTOR, 1, 1))  # type: ignore[arg-type]
    assert t.offboard == 6 << 16
    assert t.fallback[FallbackMode.RTL] == Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.RTL).custom_mode
    assert t.name(t.offboard) == "OFFBOARD"
    p1, p2, p3 = t.set_mode_params(t.fallback[FallbackMode.LAND])
    assert (p1, p2, p3) == (1.0, 4.0, 6.0)
    assert t.requested_mode(p2, p3) == t.fallback[FallbackMode.LAND]


def test_copter_table_offboard_is_guided_and_brake_is_17() -> None:
    t = mode_table(detect(M.MAV_AUTOPILOT_ARDUPILOTMEGA, M.MAV_TYPE_HEXAROTOR, 1, 1))  # type: ignore[arg-type]
    assert t.offboard == M.COPTER_MODE_GUIDED
    assert t.fallback[FallbackMode.BRAKE] == M.COPTER_MODE_BRAKE == 17
    assert t.fallback[FallbackMode.SMART_RTL] == M.COPTER_MODE_SMART_RTL
    assert t.requested_mode(*t.set_mode_params(t.offboard)[1:]) == t.offboard
    assert M.COPTER_MODE_STABILIZE not in t.release_modes  # a manual mode is never the controller's to pick


def test_fixed_wings_fall_back_to_the_autopilots_modes() -> None:
    plane = mode_table(detect(M.MAV_AUTOPILOT_ARDUPILOTMEGA, M.MAV_TYPE_FIXED_WING, 1, 1))  # type: ignore[arg-type]
    assert not plane.streams_setpoints and plane.offboard == M.PLANE_MODE_GUIDED


def test_a_fixed_wing_without_vtol_lands_by_returning_home() -> None:
    """Merlin's LAND on a fixed wing is a return over home; only a VTOL lands where it is."""
    from merlin.core.types import Behavior

    plane = mode_table(detect(M.MAV_AUTOPILOT_ARDUPILOTMEGA, M.MAV_TYPE_FIXED_WING, 1, 1))  # type: ignore[arg-type]
    assert plane.fallback[FallbackMode.LAND] == plane.behaviour_modes[Behavior.LAND] == M.PLANE_MODE_RTL
    qplane = mode_table(detect(M.MAV_AUTOPILOT_ARDUPILOTMEGA, M.MAV_TYPE_VTOL_QUADROTOR, 1, 1))  # type: ignore[arg-type]
    assert qplane.fallback[FallbackMode.LAND] == qplane.behaviour_modes[Behavior.LAND] == M.PLANE_MODE_QLAND
    rtl = Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.RTL).custom_mode
    land = Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.LAND).custom_mode
    px4_fw = mode_table(detect(M.MAV_AUTOPILOT_PX4, M.MAV_TYPE_FIXED_WING, 1, 1))  # type: ignore[arg-type]
    assert px4_fw.fallback[FallbackMode.LAND] == px4_fw.behaviour_modes[Behavior.LAND] == rtl
    assert not px4_fw.streams_setpoints
    px4_vtol = mode_table(detect(M.MAV_AUTOPILOT_PX4, M.MAV_TYPE_VTOL_QUADROTOR, 1, 1))  # type: ignore[arg-type]
    assert px4_vtol.fallback[FallbackMode.LAND] == px4_vtol.behaviour_modes[Behavior.LAND] == land
    px4_mc = mode_table(detect(M.MAV_AUTOPILOT_PX4, M.MAV_TYPE_QUADROTOR, 1, 1))  # type: ignore[arg-type]
    assert px4_mc.fallback[FallbackMode.LAND] == land and px4_mc.streams_setpoints


def test_px4_integer_parameters_are_read_bytewise_and_ardupilots_as_cast() -> None:
    import struct

    five_bytewise = struct.unpack("<f", struct.pack("<i", 5))[0]
    assert wire.param_number(wire.ParamValue("COM_OBL_RC_ACT", five_bytewise, 6), bytewise=True) == 5.0
    minus_one = struct.unpack("<f", struct.pack("<i", -1))[0]  # NaN's bit pattern: still -1
    assert wire.param_number(wire.ParamValue("COM_OBL_RC_ACT", minus_one, 6), bytewise=True) == -1.0
    assert wire.param_number(wire.ParamValue("FS_GCS_ENABLE", 1.0, 2), bytewise=False) == 1.0
    assert wire.param_number(wire.ParamValue("COM_OF_LOSS_T", 0.5, 9), bytewise=True) == 0.5
