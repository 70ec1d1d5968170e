"""The underspeed recovery of the fixed-wing inner loops and the height bound derived for it
(``merlin/autopilot/fixedwing_control.py``, ``merlin/autopilot/fixedwing_recovery.py``). The closed-loop
evidence is ``fw_adv_push_before_stall_*`` (tests/scenarios_fixedwing) and ``benchmarks/bench_fw_recovery.py``."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace
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
    """The bound covers the worst the closed loop was measured to lose from the envelope's whole box
    (benchmarks/bench_fw_recovery.py --grid: 37.5 m, a slow dive rotating nose down with the elevator full
    down) and the minimum grant height is the floor plus its margin plus the bound."""
    bound = rec.recovery_height_bound_m(CONFIG)
    assert math.isfinite(bound) and 37.5 < bound < 50.0
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


def _fly_handover(st: dict[str, float], duration_s: float = 20.0) -> float:
    """The height Merlin's stage (RTL) loses from a state set directly in JSBSim, the surfaces and the throttle
    at the values given (as ``benchmarks/bench_fw_recovery.py``'s direct sweep)."""
    from dataclasses import replace

    from merlin.autopilot import fixedwing_guidance as fg
    from merlin.autopilot.fixedwing_behaviours import FixedWingBehaviours
    from merlin.config.runtime import build_core_config
    from merlin.core.types import Authority, Behavior, Command, CommandKind, Decision
    from sims.fixedwing import FixedWingSim

    sim = FixedWingSim(pos_ned_m=(0.0, 0.0, -160.0), rate_hz=400.0)
    surfaces = fc.SurfaceCommand(st["aileron"], st["elevator"], st["rudder"], st["throttle"])
    tr = sim.set_flight_state(pos_ned_m=(0.0, 0.0, -160.0), heading_rad=0.0, airspeed_mps=st["airspeed_mps"],
                              alpha_rad=math.radians(st["alpha_deg"]), pitch_rad=math.radians(st["pitch_deg"]),
                              roll_rad=math.radians(st["roll_deg"]),
                              rates_frd_radps=(math.radians(st["p_degps"]), math.radians(st["q_degps"]),
                                               math.radians(st["r_degps"])), surfaces=surfaces)
    stage = FixedWingBehaviours(None, fc.FixedWingControlParams(), fg.GuidanceParams(), (), surfaces,
                                tr.to_vehicle_state(), 1, 0.01, envelope=build_core_config(CONFIG).envelope)
    decision = Decision(0.0, Authority.TRUSTED, Behavior.RTL, Command(CommandKind.VELOCITY, Authority.TRUSTED),
                        (), (), True)
    h0 = h_min = tr.alt_m
    for k in range(round(duration_s * 100)):
        out = stage.step(k * 0.01, decision, replace(tr.to_vehicle_state(), alpha_rad=tr.alpha_rad), 0.0)
        tr = sim.advance(out, 4)
        h_min = min(h_min, tr.alt_m)
    return h0 - h_min


def _grid_state(v: float, sink: float, alpha_deg: float, q_degps: float, bank_deg: float, p_degps: float,
                elevator: float, aileron: float, throttle: float) -> dict[str, float]:
    gamma = -math.asin(sink / v)
    alpha = math.radians(alpha_deg)
    return {"airspeed_mps": v, "alpha_deg": alpha_deg,
            "pitch_deg": math.degrees(gamma + alpha * math.cos(math.radians(bank_deg))), "roll_deg": bank_deg,
            "p_degps": p_degps, "q_degps": q_degps, "r_degps": 0.0, "throttle": throttle, "aileron": aileron,
            "elevator": elevator, "rudder": 0.0}


#: The states of the envelope's box that lost the most in benchmarks/bench_fw_recovery.py
#: (docs/benchmarks/fixed-wing-recovery.md), each with the height it lost there: the worst of the bound's
#: own grid (--grid: the stall speed, sinking at the envelope's 8 m/s at its 17 deg angle of attack, the nose
#: rotating down at 90 deg/s with the elevator full down, banked 45 deg and rolling away at 150 deg/s), the
#: worst corner of the box with any deflection and with the loops' surfaces (--corners), the worst states
#: drawn uniformly with the loops' surfaces and with any deflection (--direct 150), and the state that lost
#: 39.85 m before the dive recovery flew wings level, pulled harder and took over faster (now 23.2 m).
WORST_BOX_STATES = (
    (_grid_state(15.527, 8.0, 17.0, -90.0, 45.0, 150.0, -1.0, 1.0, 1.0), 37.53),
    ({"airspeed_mps": 16.0, "alpha_deg": -8.0, "pitch_deg": -30.0, "roll_deg": -45.0, "p_degps": 150.0,
      "q_degps": -90.0, "r_degps": -90.0, "throttle": 1.0, "aileron": 1.0, "elevator": -1.0, "rudder": -1.0}, 37.21),
    ({"airspeed_mps": 16.0, "alpha_deg": -8.0, "pitch_deg": -30.0, "roll_deg": -45.0, "p_degps": 150.0,
      "q_degps": -90.0, "r_degps": -90.0, "throttle": 0.0, "aileron": 1.0, "elevator": 1.0, "rudder": 0.0}, 31.27),
    ({"airspeed_mps": 19.3, "alpha_deg": 4.93, "pitch_deg": -19.16, "roll_deg": 15.25, "p_degps": 135.77,
      "q_degps": -88.22, "r_degps": -29.77, "throttle": 0.99, "aileron": -0.9, "elevator": 1.0, "rudder": 0.49},
     19.47),
    ({"airspeed_mps": 19.3, "alpha_deg": 4.93, "pitch_deg": -19.16, "roll_deg": 15.25, "p_degps": 135.77,
      "q_degps": -88.22, "r_degps": -29.77, "throttle": 0.99, "aileron": 0.62, "elevator": -0.51, "rudder": 0.19},
     26.33),
    ({"airspeed_mps": 16.77, "alpha_deg": 0.95, "pitch_deg": -22.54, "roll_deg": -37.17, "p_degps": -68.68,
      "q_degps": -17.98, "r_degps": 39.25, "throttle": 0.2, "aileron": 0.65, "elevator": -0.54, "rudder": -0.13},
     23.21),
)


@pytest.mark.parametrize(("state", "measured_m"), WORST_BOX_STATES,
                         ids=("grid_worst", "corner_any_surfaces", "corner_loop_surfaces", "uniform_loop_surfaces",
                              "uniform_any_surfaces", "steep_banked_dive"))
def test_the_worst_states_of_the_box_recover_within_the_derived_bound(state: dict[str, float],
                                                                      measured_m: float) -> None:
    """Within the bound derived from the aircraft model, and no worse than measured (1.5 m of slack: a
    change to the recovery that loses more from these states is a regression to explain)."""
    loss = _fly_handover(state)
    assert loss <= rec.recovery_height_bound_m(CONFIG)
    assert loss <= measured_m + 1.5, loss


def test_the_bound_is_derived_from_the_envelope_s_rates() -> None:
    """The bound is taken over the envelope's box: halving the pitch-rate and roll-rate limits a controller
    may hand over at lowers it, and the same grid without any rate (the point-mass recovery of a steady
    state) loses far less than the rotating entries."""
    cp = fc.FixedWingControlParams()
    limits = rec._limits(CONFIG, cp)
    v_max, sink_max, a_min, a_max, pitch_max, bank_max, p_max, q_max = limits
    full = rec._bound_m(rec.AEROSONDE, rec.AEROSONDE_MOMENTS, rec.AEROSONDE_PROPULSION, cp, limits)
    assert full == rec.recovery_height_bound_m(CONFIG)
    half = rec._bound_m(rec.AEROSONDE, rec.AEROSONDE_MOMENTS, rec.AEROSONDE_PROPULSION, cp,
                        (v_max, sink_max, a_min, a_max, pitch_max, bank_max, p_max / 2, q_max / 2))
    steady = rec._bound_m(rec.AEROSONDE, rec.AEROSONDE_MOMENTS, rec.AEROSONDE_PROPULSION, cp,
                          (v_max, sink_max, a_min, a_max, pitch_max, 0.0, 0.0, 0.0))
    assert steady < half < full


def test_dropping_the_recovered_states_leaves_every_loss_bit_identical() -> None:
    """The array form drops a state from its arrays once it has recovered; with a trace it drops none and
    flies every state to the end of the longest recovery. Both give the same loss, bit for bit, for every
    state of the shipped configuration's grid and of a grid with a sink limit no envelope ships (states
    that recover at many different times); and so does height_lost_m without a trace, which flies each
    state alone in the scalar kernel (tests/fixedwing/test_recovery_kernel.py holds it to the array form on
    every shipped configuration and on random states)."""
    cp = fc.FixedWingControlParams()
    limits = rec._limits(CONFIG, cp)
    models = (rec.AEROSONDE, rec.AEROSONDE_MOMENTS, rec.AEROSONDE_PROPULSION, cp)
    for lim in (limits, (limits[0], 11.0, *limits[2:5], limits[5] * 0.5, limits[6] * 0.3, limits[7])):
        entry = rec.entry_states(rec.AEROSONDE, *lim)
        dropped = rec.height_lost_arrays(*models, entry)
        kept = rec.height_lost_arrays(*models, entry, trace=[])
        scalar = rec.height_lost_m(*models, entry)
        assert dropped.shape == kept.shape == scalar.shape == entry.airspeed_mps.shape
        assert dropped.tobytes() == kept.tobytes() == scalar.tobytes()


def test_the_dive_pull_out_gain_only_after_a_steep_sink_and_until_the_recovery_ends() -> None:
    """The pitch loop's raised gain is flown from the tick the recovery sinks beyond its trigger to the
    recovery's end, not in a recovery from a slow state alone (the push-before-stall handovers lost more
    with it)."""
    cp = fc.FixedWingControlParams()
    targets = fc.FixedWingTargets(airspeed_mps=22.0, height_m=120.0)
    slow = _state(17.0, 0.1, 0.0, 0.0, 1.0)
    state = fc.reset_from_state(cp, slow, fc.SurfaceCommand(throttle=0.5, elevator=0.4), targets)
    state, out = fc.control_step(cp, state, slow, targets, 0.01)
    assert out.recovering and not state.pulling_out
    diving = _state(20.0, -0.4, 0.3, 0.0, cp.sink_max_mps + cp.recovery_sink_margin_mps + 1.0)
    state, out = fc.control_step(cp, state, diving, targets, 0.01)
    assert state.pulling_out and out.roll_sp_rad == pytest.approx(0.0, abs=cp.roll_sp_rate_radps * 0.01)
    # the sink back below the trigger, still recovering: the pull-out goes on, wings level
    shallower = _state(23.0, -0.1, 0.3, 0.0, 3.0)
    state, out = fc.control_step(cp, state, shallower, targets, 0.01)
    assert out.recovering and state.pulling_out
    recovered = _state(cp.airspeed_min_mps + cp.recovery_exit_margin_mps + 0.5, 0.1, 0.0, 0.0, 0.0)
    state, out = fc.control_step(cp, state, recovered, targets, 0.01)
    assert not out.recovering and not state.pulling_out


@pytest.mark.parametrize(("pitch", "q", "sink"), [(0.5, 0.0, 0.0), (0.05, 1.2, 0.0), (-0.3, 0.0, -2.0)],
                         ids=("alpha_high", "pitch_rate", "alpha_low"))
def test_a_takeover_in_an_upset_slews_at_the_recovery_rate(pitch: float, q: float, sink: float) -> None:
    """Not recovering (fast, level, wings level), but the angle of attack on the air path beyond its band or
    the nose rotating beyond the upset rate: the surfaces taken over leave at the recovery's takeover slew,
    not the ordinary one; in steady flight at the same speed, at the ordinary one."""
    cp = fc.FixedWingControlParams()
    targets = fc.FixedWingTargets(airspeed_mps=22.0, height_m=100.0)
    taken = fc.SurfaceCommand(0.0, -1.0, 0.0, 0.7)

    def first_step(s: VehicleState) -> float:
        state = fc.reset_from_state(cp, s, taken, targets)
        state, out = fc.control_step(cp, state, s, targets, 0.01)
        assert not out.recovering
        return out.surfaces.elevator - taken.elevator

    upset = VehicleState(pos_ned_m=(0.0, 0.0, -100.0), vel_ned_mps=(22.0, 0.0, sink), att_rpy_rad=(0.0, pitch, 0.0),
                         rates_frd_radps=(0.0, q, 0.0), accel_frd_mps2=(0.0, 0.0, -9.8), airspeed_mps=22.0,
                         armed=True, landed=False)
    steady = replace(upset, att_rpy_rad=(0.0, 0.05, 0.0), rates_frd_radps=(0.0, 0.0, 0.0), vel_ned_mps=(22.0, 0.0, 0.0))
    assert first_step(upset) == pytest.approx(cp.recovery_takeover_slew_per_s * 0.01)
    assert first_step(steady) == pytest.approx(fc.takeover_slew_per_s(cp) * 0.01)
