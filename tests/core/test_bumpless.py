"""Bumpless transfer (Merlin paper: "initialize reference commands and internal parameters to achieve
smooth, bumpless control switching"): the command at a change of authority starts from the last actuated
command and is blended in; a naive switch jumps. Checked in the core and in closed loop."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

from merlin.config.models import HandoverConfig, MerlinConfig
from merlin.core.types import Authority, CommandKind, Setpoint, SetpointKind
from sims.runner import run_scenario
from sims.scenario import ControllerSpec, load_scenario
from tests.core.harness import DT, HOVER_10M, Harness

NAIVE = HandoverConfig(blend_window_s=0.0, max_accel_mps2=1.0e9, max_attitude_rate_degps=1.0e9,
                       max_thrust_rate_per_s=1.0e9)


def _switch_jump(cfg: MerlinConfig) -> tuple[float, list[float]]:
    h = Harness(cfg=cfg)
    h.airborne()
    # the controller asks for 2.5 m/s east (within the 3 m/s consistency tolerance) while hovering
    h.setpoint = Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(0.0, 2.5, 0.0))
    before = h.tick().command
    d = h.grant()
    jump = math.dist(before.vel_ned_mps, d.command.vel_ned_mps)
    ramp = [h.tick().command.vel_ned_mps[1] for _ in range(round(1.2 / DT))]
    return jump, ramp


def _naive(cfg: MerlinConfig) -> MerlinConfig:
    """``cfg`` switching naively: no blend, and the experimental velocity setpoint not ramped either (its
    acceleration limits opened, shaping.track_command), so the setpoint step reaches the inner loops whole."""
    opened = cfg.vehicle.model_copy(update={"max_accel_h_mps2": 1.0e9, "max_vertical_accel_mps2": 1.0e9,
                                            "max_accel_down_mps2": 1.0e9})
    return cfg.model_copy(update={"handover": NAIVE, "vehicle": opened})


def test_grant_is_blended_and_a_naive_switch_jumps() -> None:
    jump, ramp = _switch_jump(MerlinConfig())
    naive_jump, naive_ramp = _switch_jump(_naive(MerlinConfig()))
    assert naive_jump > 2.4  # the whole setpoint step lands on one tick
    # without the blend but with the setpoint's tracking ramp, the step is bounded per tick all the same
    ramped_jump, ramped = _switch_jump(MerlinConfig(handover=NAIVE))
    assert ramped_jump <= MerlinConfig().vehicle.max_accel_h_mps2 * DT + 1e-9
    assert max(b - a for a, b in itertools.pairwise(ramped)) <= MerlinConfig().vehicle.max_accel_h_mps2 * DT + 1e-9
    assert jump <= MerlinConfig().handover.max_accel_mps2 * DT + 1e-9  # at most one tick of the slew limit
    steps = [b - a for a, b in itertools.pairwise(ramp)]
    assert max(steps) <= MerlinConfig().handover.max_accel_mps2 * DT + 1e-9
    assert abs(ramp[-1] - 2.5) < 1e-9  # and the experimental command is fully in force after the window
    assert naive_ramp[0] == 2.5


def test_revocation_from_attitude_starts_from_the_vehicle_state() -> None:
    """EXPERIMENTAL commanded attitude; TRUSTED commands velocity: the first trusted command is the
    vehicle's own velocity (no step), not the guidance's target."""
    h = Harness(setpoint=Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(0.05, 0.0, 0.0), thrust=0.5))
    h.airborne()
    h.grant()
    moving = replace(HOVER_10M, vel_ned_mps=(3.0, 1.0, 0.0), att_rpy_rad=(0.05, 0.0, 0.0))
    h.tick(state=moving)
    h.heartbeat = False
    while True:
        d = h.tick()
        if d.authority is Authority.TRUSTED:
            break
    assert d.command.kind is CommandKind.VELOCITY
    assert math.dist(d.command.vel_ned_mps, moving.vel_ned_mps) <= MerlinConfig().handover.max_accel_mps2 * DT + 1e-9


def test_closed_loop_motor_commands_stay_smooth_at_the_switch_compared_with_a_naive_switch() -> None:
    """In closed loop the blended grant keeps the velocity command continuous; the naive switch steps it."""
    sc, cfg = load_scenario("examples/scenarios/nominal.yaml")
    ctrl = ControllerSpec(type="tests.core.step_controller:EastStep", params={"request_at_s": 9.0})
    sc = sc.model_copy(update={"duration_s": 12.0, "controller": ctrl})
    blended = run_scenario(sc, cfg)
    naive = run_scenario(sc, _naive(cfg))
    assert any(e["type"] == "authority" and e["to"] == "EXPERIMENTAL" for e in blended.events)
    j_blend = blended.metrics["max_authority_change_command_jump_mps"]
    j_naive = naive.metrics["max_authority_change_command_jump_mps"]
    assert j_naive > 2.0, j_naive  # the naive switch steps the command by the whole difference
    assert j_blend <= MerlinConfig().handover.max_accel_mps2 * DT + 1e-9, j_blend
    # and the vehicle feels it: the largest tilt in the second after the switch is much smaller blended
    def tilt_after_grant(r) -> float:
        t0 = next(e["t"] for e in r.events if e["type"] == "authority" and e["to"] == "EXPERIMENTAL")
        m = (r.log["t"] >= t0) & (r.log["t"] <= t0 + 1.0)
        return float(max(abs(r.log["truth_roll"][m]).max(), abs(r.log["truth_pitch"][m]).max()))
    assert tilt_after_grant(blended) < tilt_after_grant(naive)
