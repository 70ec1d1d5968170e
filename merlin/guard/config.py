"""The guard's own settings: the ``guard:`` section of the configuration file ``merlin guard --config``
reads; everything else in that file is the usual Merlin configuration (limits, fence, rules).

The limits here are the guard's promises about the autopilot underneath it (how soon its own failsafe
must take over when the guard dies) and about its telemetry (how old a position may be before it is a
navigation fault). They are a pydantic model, as every limit in Merlin is, so a bad value is refused with
its field, value and allowed range.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from merlin.guard.dialects import FallbackMode


class GuardConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    rate_hz: float = Field(50.0, gt=0, le=400, description="the guard's tick: core decisions and trusted setpoints, Hz")
    max_offboard_loss_s: float = Field(
        1.0, gt=0, le=10,
        description="the longest the autopilot may keep flying the last setpoint once the guard's stream stops: "
                    "PX4's COM_OF_LOSS_T and ArduPilot's GUID_TIMEOUT must be at most this, s")
    max_gcs_loss_s: float = Field(
        5.0, gt=0, le=60,
        description="ArduPilot: the longest its GCS failsafe may wait for the guard's heartbeat "
                    "(FS_GCS_TIMEOUT, Plane FS_LONG_TIMEOUT) before it takes over, s")
    allow_pilot_fallback: bool = Field(
        False, description="PX4: accept COM_OBL_RC_ACT 0..2 (Position, Altitude, Stabilized), which hand the "
                           "vehicle to the RC pilot's sticks; only with a safety pilot holding the transmitter")
    fallback_mode: FallbackMode | None = Field(
        None, description="on revocation, brake for brake_s then hand the vehicle to this autopilot mode; "
                          "none: stream Merlin's own trusted behaviour (hold, return on a safe path, land)")
    brake_s: float = Field(1.0, ge=0, le=10,
                           description="how long the guard streams a braking setpoint before fallback_mode, s")
    telemetry_stale_s: float = Field(
        0.5, gt=0, le=5, description="attitude or position telemetry older than this is a navigation fault, s")
    telemetry_rate_hz: float = Field(
        50.0, gt=0, le=400, description="rate requested (MAV_CMD_SET_MESSAGE_INTERVAL) for attitude and position")
    param_timeout_s: float = Field(
        5.0, gt=0, le=60, description="how long the start-up failsafe check waits for the autopilot's parameters, s")
    heartbeat_timeout_s: float = Field(
        10.0, gt=0, le=120, description="how long start-up waits for the autopilot's HEARTBEAT, s")
    system_id: int = Field(1, ge=1, le=255, description="the guard's MAVLink system id (PX4; see gcs_system_id)")
    component_id: int = Field(191, ge=1, le=255,
                              description="the guard's component id (191: MAV_COMP_ID_ONBOARD_COMPUTER)")
