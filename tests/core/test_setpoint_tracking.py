"""How an experimental velocity setpoint is handed to the trusted inner loops (shaping.track_command): moved
from the last actuated command towards the clamped setpoint at PX4's acceleration limits, its heading turned
at the yaw-rate limit. The closed-loop consequence (a step inside the envelope is flown inside it) is pinned by
the scenario ``offboard_velocity_steps_in_envelope``."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core.config import SetpointClamp
from merlin.core.geofence import check
from merlin.core.shaping import track_command
from merlin.core.types import Authority, Command, CommandKind, Setpoint, SetpointKind, VehicleState
from tests.core.harness import Harness

LIM = SetpointClamp()
DT = 0.01
speed = st.floats(-20.0, 20.0, allow_nan=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False)
vec = st.tuples(speed, speed, speed)


def _vel(v: tuple[float, float, float], yaw: float = 0.0, rate: float = 0.0) -> Command:
    return Command(CommandKind.VELOCITY, Authority.EXPERIMENTAL, vel_ned_mps=v, yaw_rad=yaw, yaw_rate_radps=rate)


def _wrap(x: float) -> float:
    return math.atan2(math.sin(x), math.cos(x))


@settings(max_examples=300, deadline=None)
@given(prev=vec, target=vec, prev_yaw=angle, yaw=angle, rate=st.floats(-10.0, 10.0))
def test_one_tick_moves_at_most_the_acceleration_limits_and_never_past_the_setpoint(
        prev: tuple[float, float, float], target: tuple[float, float, float], prev_yaw: float, yaw: float,
        rate: float) -> None:
    out = track_command(_vel(target, yaw, rate), _vel(prev, prev_yaw), VehicleState(), DT, LIM)
    dn, de, dd = (out.vel_ned_mps[k] - prev[k] for k in range(3))
    assert math.hypot(dn, de) <= LIM.max_accel_h_mps2 * DT + 1e-9
    assert -LIM.max_accel_up_mps2 * DT - 1e-9 <= dd <= LIM.max_accel_down_mps2 * DT + 1e-9
    # towards the setpoint, never beyond it
    h_before = math.hypot(target[0] - prev[0], target[1] - prev[1])
    h_after = math.hypot(target[0] - out.vel_ned_mps[0], target[1] - out.vel_ned_mps[1])
    assert h_after <= h_before + 1e-9
    assert abs(target[2] - out.vel_ned_mps[2]) <= abs(target[2] - prev[2]) + 1e-9
    assert (out.vel_ned_mps[2] - target[2]) * (prev[2] - target[2]) >= -1e-12
    # the heading turns at most at the yaw-rate limit, and the rate fed forward is within it
    assert abs(_wrap(out.yaw_rad - prev_yaw)) <= LIM.max_yaw_rate_radps * DT + 1e-9
    assert abs(out.yaw_rate_radps) <= LIM.max_yaw_rate_radps + 1e-12


@settings(max_examples=300, deadline=None)
@given(prev=vec, target=vec, prev_yaw=angle, yaw=angle)
def test_the_setpoint_is_reached_exactly_in_the_time_the_limits_give(
        prev: tuple[float, float, float], target: tuple[float, float, float], prev_yaw: float,
        yaw: float) -> None:
    cmd, last = _vel(target, yaw), _vel(prev, prev_yaw)
    h = math.hypot(target[0] - prev[0], target[1] - prev[1])
    v = abs(target[2] - prev[2])
    t_need = max(h / LIM.max_accel_h_mps2, v / min(LIM.max_accel_up_mps2, LIM.max_accel_down_mps2),
                 abs(_wrap(yaw - prev_yaw)) / LIM.max_yaw_rate_radps)
    for _ in range(math.ceil(t_need / DT) + 2):
        last = track_command(cmd, last, VehicleState(), DT, LIM)
    assert last.vel_ned_mps == target
    assert last.yaw_rad == yaw


def test_a_step_starts_from_the_last_command_or_the_measured_velocity() -> None:
    s = VehicleState(vel_ned_mps=(1.0, 0.0, 0.0), att_rpy_rad=(0.0, 0.0, 0.5))
    att = Command(CommandKind.ATTITUDE, Authority.TRUSTED, att_rpy_rad=(0.1, 0.0, 0.5), thrust=0.5)
    # after an attitude command there is no velocity command to continue: the vehicle's own velocity
    out = track_command(_vel((5.0, 0.0, 0.0), 0.5), att, s, 0.1, LIM)
    assert out.vel_ned_mps == (1.0 + LIM.max_accel_h_mps2 * 0.1, 0.0, 0.0)
    out = track_command(_vel((5.0, 0.0, -3.0), 0.5), None, s, 0.1, LIM)
    assert out.vel_ned_mps[2] == -LIM.max_accel_up_mps2 * 0.1
    # a yaw-rate setpoint (no heading) is clamped to the limit
    out = track_command(_vel((0.0, 0.0, 0.0), math.nan, 3.0), None, s, 0.1, LIM)
    assert math.isnan(out.yaw_rad) and out.yaw_rate_radps == LIM.max_yaw_rate_radps


def test_attitude_commands_pass_unchanged() -> None:
    att = Command(CommandKind.ATTITUDE, Authority.EXPERIMENTAL, att_rpy_rad=(0.3, -0.2, 1.0), thrust=0.6)
    assert track_command(att, _vel((3.0, 0.0, 0.0)), VehicleState(), DT, LIM) is att


def _square_range() -> MerlinConfig:
    data = MerlinConfig().model_dump(mode="json")
    data["geofence"].update(
        margin_m=3.0, sigma_k=2.0, altitude_ceiling_m=120.0, inclusion_circles=[], exclusion_circles=[],
        exclusion_polygons=[],
        inclusion_polygons=[{"name": "r", "vertices_ne_m": [[-300, -300], [300, -300], [300, 300], [-300, 300]]}],
    )
    data["envelope"]["active_stage"] = "expanded"
    for k in ("vel_n_mps", "vel_e_mps", "vel_d_mps"):
        data["envelope"]["stages"]["expanded"][k].update(min=-100.0, max=100.0)
    return MerlinConfig.model_validate(data)


def test_the_fence_projects_the_setpoint_a_ramp_is_heading_for_not_the_ramp() -> None:
    """The ramp goes on during the reaction time: projecting the ramped command (a fraction of the step so
    far) would credit the vehicle with a speed it is about to leave behind. Where the clamped setpoint's
    projection trips and the ramp's would not, the core trips."""
    cfg = _square_range()
    fence = build_core_config(cfg).fence
    assert fence is not None
    h = Harness(cfg=cfg)
    h.airborne()
    h.grant()
    h.setpoint = Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(15.0, 0.0, 0.0))
    for _ in range(10):  # the ramp has begun: the command flown is far below the setpoint
        d = h.tick()
        assert d.authority is Authority.EXPERIMENTAL
    assert d.command.vel_ned_mps[0] < 1.0
    v = (5.0, 0.0, 0.0)
    north = next(n for n in range(200, 300)
                 if check(fence, (float(n), 0.0, -10.0), v, 0.0, 0.0, True, (0.0, 0.0), (15.0, 0.0, 0.0)).tripped)
    assert not check(fence, (float(north), 0.0, -10.0), v, 0.0, 0.0, True, (0.0, 0.0), d.command.vel_ned_mps).tripped
    d = h.tick(state=VehicleState(pos_ned_m=(float(north), 0.0, -10.0), vel_ned_mps=v, armed=True, landed=False))
    assert any(m.name == "geofence" and m.tripped for m in d.monitors), d.monitors
