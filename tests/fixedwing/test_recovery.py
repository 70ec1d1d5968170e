"""The underspeed recovery of the fixed-wing inner loops and the height bound derived for it
(``merlin/autopilot/fixedwing_control.py``, ``merlin/autopilot/fixedwing_recovery.py``). The closed-loop
evidence is ``fw_adv_push_before_stall_*`` (tests/scenarios_fixedwing) and ``benchmarks/bench_fw_recovery.py``."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.autopilot import fixedwing_control as fc
from merlin.autopilot import fixedwing_recovery as rec
from merlin.config.loader import load_config
from merlin.core.types import VehicleState

ROOT = Path(__file__).resolve().parents[2]
CONFIG = load_config(ROOT / "examples" / "configs" / "fixedwing_default.yaml")


def _state(airspeed: float, pitch: float, roll: float, q: float, sink: float) -> VehicleState:
    return VehicleState(pos_ned_m=(0.0, 0.0, -100.0), vel_ned_mps=(math.sqrt(max(airspeed**2 - sink**2, 1.0)), 0.0,
                                                                   sink),
                        att_rpy_rad=(roll, pitch, 0.0), rates_frd_radps=(0.0, q, 0.0),
                        accel_frd_mps2=(0.0, 0.0, -9.8), airspeed_mps=airspeed, armed=True, landed=False)


@settings(max_examples=100, deadline=None)
@given(airspeed=st.floats(14.0, 18.4), pitch=st.floats(-0.5, 0.5), roll=st.floats(-0.8, 0.8),
       q=st.floats(-0.8, 0.8), sink=st.floats(-3.0, 8.0), throttle=st.floats(0.0, 1.0))
def test_below_the_minimum_airspeed_the_loops_recover_full_power_wings_level(
        airspeed: float, pitch: float, roll: float, q: float, sink: float, throttle: float) -> None:
    """Whatever the state and the throttle taken over: full power in the first tick, the bank setpoint on
    its way to wings level, and the pitch target within the angle-of-attack cap."""
    cp = fc.FixedWingControlParams()
    s = _state(airspeed, pitch, roll, q, sink)
    targets = fc.FixedWingTargets(airspeed_mps=22.0, height_m=120.0, roll_rad=0.6)
    before = fc.SurfaceCommand(throttle=throttle, elevator=0.4)
    state = fc.reset_from_state(cp, s, before, targets)
    state, out = fc.control_step(cp, state, s, targets, 0.01)
    assert out.recovering and state.recovering
    assert out.surfaces.throttle == cp.throttle_max
    assert abs(out.roll_sp_rad) <= abs(roll) + 1e-12
    gamma = math.asin(-sink / math.sqrt(sum(c * c for c in s.vel_ned_mps)))
    assert out.pitch_target_rad <= gamma + cp.alpha_protect_rad * math.cos(roll) + 1e-9


def test_the_recovery_ends_once_fast_enough_and_the_sink_is_arrested() -> None:
    cp = fc.FixedWingControlParams()
    targets = fc.FixedWingTargets(airspeed_mps=22.0, height_m=100.0)
    state = fc.FixedWingControlState(recovering=True, throttle=1.0, initialized=True)
    fast_sinking = _state(cp.airspeed_min_mps + cp.recovery_exit_margin_mps + 0.5, 0.0, 0.0, 0.0, 3.0)
    assert fc.control_step(cp, state, fast_sinking, targets, 0.01)[0].recovering
    slow_level = _state(cp.airspeed_min_mps + 1.0, 0.1, 0.0, 0.0, 0.0)
    assert fc.control_step(cp, state, slow_level, targets, 0.01)[0].recovering
    recovered = _state(cp.airspeed_min_mps + cp.recovery_exit_margin_mps + 0.5, 0.1, 0.0, 0.0, 0.5)
    new, out = fc.control_step(cp, state, recovered, targets, 0.01)
    assert not new.recovering and not out.recovering
    assert out.surfaces.throttle < 1.0  # TECS again, slewing down from full power


def test_an_attitude_command_is_not_taken_over_by_the_recovery() -> None:
    """An experimental ATTITUDE command keeps its pitch and throttle below the minimum airspeed: the envelope
    revokes it, the inner loops do not fly their own recovery under it."""
    cp = fc.FixedWingControlParams()
    targets = fc.FixedWingTargets(airspeed_mps=22.0, height_m=None, pitch_rad=0.2, throttle=0.0)
    s = _state(17.0, 0.2, 0.0, 0.0, 0.0)
    state = fc.reset_from_state(cp, s, fc.SurfaceCommand(throttle=0.0), targets)
    _, out = fc.control_step(cp, state, s, targets, 0.01)
    assert not out.recovering and out.surfaces.throttle == 0.0


def test_the_derived_bound_grows_with_the_sink_and_shrinks_with_the_speed() -> None:
    cp = fc.FixedWingControlParams()
    alpha = math.radians(-8.0)
    losses = [rec._height_lost_m(rec.AEROSONDE, cp, 20.0, w, alpha) for w in (0.0, 2.0, 4.0, 6.0)]
    assert losses == sorted(losses) and losses[0] > 0.0
    by_speed = [rec._height_lost_m(rec.AEROSONDE, cp, v, 4.0, alpha) for v in (17.0, 20.0, 25.0, 30.0)]
    assert by_speed == sorted(by_speed, reverse=True)


def test_the_bound_and_the_minimum_grant_height_for_the_shipped_configuration() -> None:
    """The bound covers the worst the closed loop was measured to lose (benchmarks/bench_fw_recovery.py) and
    the minimum grant height is the floor plus its margin plus the bound."""
    bound = rec.recovery_height_bound_m(CONFIG)
    assert math.isfinite(bound) and 8.0 < bound < 25.0
    assert rec.AEROSONDE.stall_speed_mps() == pytest.approx(15.5, abs=0.1)
    floor = CONFIG.geofence.altitude_floor_m + CONFIG.geofence.margin_m
    assert rec.min_grant_height_m(CONFIG) == floor + bound


def _fly_takeover(cp: fc.FixedWingControlParams, surfaces: fc.SurfaceCommand) -> tuple[list[tuple[float, ...]],
                                                                                    fc.FixedWingControlState]:
    s = _state(22.0, math.radians(8.0), 0.0, 0.0, 0.0)
    targets = fc.FixedWingTargets(airspeed_mps=22.0, height_m=100.0)
    state = fc.reset_from_state(cp, s, surfaces, targets)
    seq = [(surfaces.aileron, surfaces.elevator, surfaces.rudder)]
    for _ in range(200):
        state, out = fc.control_step(cp, state, s, targets, 0.01)
        seq.append((out.surfaces.aileron, out.surfaces.elevator, out.surfaces.rudder))
    return seq, state


@settings(max_examples=50, deadline=None)
@given(elevator=st.floats(-1.0, 1.0), aileron=st.floats(-1.0, 1.0), rudder=st.floats(-1.0, 1.0))
def test_a_takeover_slews_from_the_surfaces_taken_over_and_does_not_keep_them(
        elevator: float, aileron: float, rudder: float) -> None:
    """From any deflection the revoked controller left: no surface steps beyond the takeover's slew per tick,
    and after 2 s the surfaces differ from a takeover at trim by at most the takeover band (the integrators
    did not inherit the deflection; the loops' state here is held fixed, so both wind the same way)."""
    cp = fc.FixedWingControlParams()
    seq, state = _fly_takeover(cp, fc.SurfaceCommand(aileron, elevator, rudder, 0.7))
    ref, _ = _fly_takeover(cp, fc.SurfaceCommand(0.0, cp.elevator_trim, 0.0, 0.7))
    step = fc.takeover_slew_per_s(cp) * 0.01 + 1e-12
    assert all(abs(a - b) <= step for prev, now in itertools.pairwise(seq) for a, b in zip(now, prev, strict=True))
    assert state.handover is None
    assert all(abs(a - b) <= cp.takeover_integrator_band + 1e-9 for a, b in zip(seq[-1], ref[-1], strict=True))


@settings(max_examples=50, deadline=None)
@given(aileron=st.floats(-1.0, 1.0), rudder=st.floats(-1.0, 1.0))
def test_a_takeover_inherits_no_aileron_or_rudder(aileron: float, rudder: float) -> None:
    """The lateral integrators start at their zero trim whatever the revoked controller left: once the takeover
    slew has met the loops' own command, the aileron and the rudder are exactly those of a takeover at trim.
    An aileron inherited through the integrator held Merlin's escape turn 10 deg short of its bank for
    seconds after a revocation (scenario fw_adv_grant_during_escape)."""
    cp = fc.FixedWingControlParams()
    seq, state = _fly_takeover(cp, fc.SurfaceCommand(aileron, cp.elevator_trim, rudder, 0.7))
    ref, _ = _fly_takeover(cp, fc.SurfaceCommand(0.0, cp.elevator_trim, 0.0, 0.7))
    assert state.handover is None
    assert seq[-1][0] == ref[-1][0] and seq[-1][2] == ref[-1][2], (seq[-1], ref[-1])
