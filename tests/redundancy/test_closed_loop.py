"""Hardware redundancy inside the closed loop (merlin/redundancy/lanes.py in the vehicle's tick): the IMU voter
before the EKF, the degradation chain, three autopilot lanes with the bumpless switch."""

from __future__ import annotations

import math
from functools import cache
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

import merlin.redundancy.lanes as lanes_mod
from merlin.autopilot.multirotor_control import DEFAULT_GAINS, MIX_PITCH, MIX_ROLL, MIX_YAW, ControllerState
from merlin.config.models import MerlinConfig
from merlin.measurements import BaroSample, GpsSample, ImuSample, MagSample
from merlin.redundancy.events import RedundancyLevel
from merlin.redundancy.lane_voter import BumplessSwitch
from merlin.redundancy.lanes import BUMPLESS_STEP_PER_S, track_actuated
from merlin.redundancy.sensor_suite import VOTED_LANE, SensorSuiteVoter
from sims.expectations import evaluate
from sims.runner import ClosedLoop, RunResult, run_scenario
from sims.scenario import Expectation, Scenario

TAKEOFF = [{"t": 0.5, "command": "arm"}, {"t": 1.0, "command": "takeoff", "param": 6}]


def _scenario(**kw: Any) -> Scenario:
    # the stand-in by name unless a test asks for the EKF: these tests were written when it was the default,
    # and "the stand-in path builds nothing" is what test_the_default_path_builds_nothing pins
    base: dict[str, Any] = {"name": "closed_loop_test", "duration_s": 7.0, "seed": 7, "gcs": TAKEOFF,
                            "estimator": "truth_plus_noise"}
    base.update(kw)
    return Scenario.model_validate(base)


@cache
def _ekf_run(fault_lane: int | None, every_tick: bool = False) -> RunResult:
    faults = [] if fault_lane is None else [{"type": "imu_stuck", "start_s": 5.0, "lane": fault_lane}]
    # camera-less, as written: the voter's isolation is the subject, and VO would move both runs' estimates
    periods = {"core_dt_s": None, "nav_dt_s": None} if every_tick else {}
    return run_scenario(_scenario(estimator="ekf", camera=None, faults=faults, **periods), MerlinConfig())


LANE_FAULT_T = 6.5  # after the take-off gate (fast preset: 5 s after the first flying tick, ~1 s)


@cache
def _lane_run(mode: str = "silent", tracking: bool = True) -> RunResult:
    sc = _scenario(duration_s=7.2, redundancy={"autopilot_lanes": 3},
                   faults=[{"type": "autopilot_lane_fail", "start_s": LANE_FAULT_T, "lane": 0, "mode": mode}])
    if tracking:
        return run_scenario(sc, MerlinConfig())
    saved = lanes_mod.TRACKING_GAIN
    lanes_mod.TRACKING_GAIN = 0.0
    try:
        return run_scenario(sc, MerlinConfig())
    finally:
        lanes_mod.TRACKING_GAIN = saved


def _of(r: RunResult, etype: str) -> list[dict[str, Any]]:
    return [e for e in r.events if e["type"] == etype]


# ----------------------------------------------------------------------------------- IMU voter in loop


@pytest.mark.parametrize("every_tick", [False, True], ids=["voter_at_100_hz", "voter_every_tick"])
def test_the_stuck_imu_lane_is_the_one_isolated_and_the_healthy_never_are(every_tick: bool) -> None:
    r = _ekf_run(2, every_tick)
    assert r.scenario.nav_every == (1 if every_tick else 4)
    iso = _of(r, "imu_isolated")
    assert [e["lane"] for e in iso] == [2]
    # 20 identical samples at 400 Hz = 50 ms; the voter at its default 10 ms counts 5 identical down-sampled
    # samples, and the first of them can end up to one of its periods after the fault
    assert 5.0 < iso[0]["t"] <= 5.0 + 0.06 + (0.0 if every_tick else 0.01)
    assert any(e["detail"] == "TRIPLEX -> DUPLEX" for e in _of(r, "imu_degraded"))
    ok = r.log["imu_lanes_ok"]
    t = r.log["t"]
    assert set(ok[t < 5.0]) == {3.0} and set(ok[t > 5.1]) == {2.0}
    assert set(r.log["imu_fdi_state"][t > 5.1]) == {1.0}  # the duplex FDI runs, in its normal state
    assert not _of(r, "revoked") and set(r.log["authority"]) == {0.0}


def test_with_the_voter_a_stuck_lane_does_not_move_the_estimate() -> None:
    """Same seed, same sensors: the run with lane 2 frozen estimates what the fault-free run does (the
    stuck lane is out of the vote after 50 ms; the two healthy lanes' mean replaces the median)."""
    faulty, clean = _ekf_run(2), _ekf_run(None)
    t = faulty.log["t"]
    assert np.array_equal(t, clean.log["t"])
    before = t < 5.0
    for c in ("est_n", "est_e", "est_d"):
        assert np.array_equal(faulty.log[c][before], clean.log[c][before])
        assert np.max(np.abs(faulty.log[c] - clean.log[c])) < 0.05, c
    # and the estimate's error against the truth stays at its fault-free size
    err = lambda r: np.hypot(r.log["est_n"] - r.log["truth_n"], r.log["est_e"] - r.log["truth_e"])  # noqa: E731
    assert np.max(err(faulty)[t > 5.0]) < np.max(err(clean)[t > 5.0]) + 0.05


def test_the_chain_walks_down_to_simplex_and_the_duplex_fdi_blames_the_faulty_lane() -> None:
    """3 -> 2 (lane 1 stuck, voter) -> duplex PF FDI -> 1 (lane 0 roll-gyro bias, FDI verdict)."""
    sc = _scenario(estimator="ekf", duration_s=6.5, faults=[
        {"type": "imu_stuck", "start_s": 3.5, "lane": 1},
        {"type": "imu_bias", "start_s": 5.5, "lane": 0, "gyro": [0.5, 0.0, 0.0]}])
    r = run_scenario(sc, MerlinConfig())
    iso = _of(r, "imu_isolated")
    assert [(e["lane"], e["detail"]) for e in iso] == [(1, "stuck"), (0, "duplex FDI verdict")]
    assert [e["lane"] for e in _of(r, "imu_fault_declared")] == [0]
    assert 5.5 < iso[1]["t"] < 6.5
    t, ok = r.log["t"], r.log["imu_lanes_ok"]
    assert ok[0] == 3.0 and 2.0 in set(ok[(t > 3.6) & (t < 5.5)]) and ok[-1] == 1.0
    assert r.log["imu_nav_health"][-1] == 0.5


# ------------------------------------------------------------------------------ autopilot lanes in loop


def test_a_silent_active_lane_is_replaced_within_three_exchange_periods_bumplessly() -> None:
    r = _lane_run()
    sw = _of(r, "autopilot_lane_switch")
    assert [e["lane"] for e in sw] == [1]
    last_msg = LANE_FAULT_T - 0.02  # lane 0's last exchange before its computer stops
    assert sw[0]["t"] - last_msg <= 3 * 0.02 + 1e-9
    silent = _of(r, "autopilot_peer_silent")
    assert {e["lane"] for e in silent} == {0} and len(silent) == 2  # both peers noticed
    t, sel = r.log["t"], r.log["ap_lane"]
    assert set(sel[t < LANE_FAULT_T]) == {0.0} and set(sel[t > sw[0]["t"]]) == {1.0}
    m = r.metrics
    assert m["lane_switches"] == 1.0
    assert m["max_lane_switch_added_step"] <= m["bumpless_limit"] + 1e-12
    assert m["bumpless_limit"] == pytest.approx(BUMPLESS_STEP_PER_S * 0.0025)
    v = evaluate(Expectation(type="max_lane_switch_step"), r.events, r.log, r.metrics)
    assert v.passed, v.detail
    assert not _of(r, "revoked")


def test_standby_tracking_keeps_the_hand_over_gap_small() -> None:
    """Seed 000 §5.3.1's standby lanes 'fight' the active one: without tracking their integrators wind
    on their own IMU lane's bias and the incoming lane's command is far from the actuated one."""
    with_t, without = _lane_run(), _lane_run(tracking=False)
    # With tracking the incoming lane's command is within what one tick may add (no fade needed); without it
    # the gap is well beyond that. (Every trusted command now starts from the vehicle's measured state after
    # a source change, which anchors even an untracked lane: the untracked gap fell from 0.046 to 0.041.)
    limit = with_t.metrics["bumpless_limit"]
    assert with_t.metrics["lane_switch_handover_gap"] < limit < 1.25 * limit < without.metrics["lane_switch_handover_gap"]
    assert with_t.metrics["lane_switch_handover_gap"] < 0.6 * without.metrics["lane_switch_handover_gap"]
    # without tracking the gap exceeds what one tick may add, so the fade is what bounds the step
    assert without.metrics["max_lane_switch_added_step"] <= without.metrics["bumpless_limit"] + 1e-12


def test_a_babbling_lane_is_voted_out_by_its_flags_and_never_selected_again() -> None:
    r = _lane_run("garbage")
    sw = _of(r, "autopilot_lane_switch")
    assert [e["lane"] for e in sw] == [1]
    assert {e["lane"] for e in _of(r, "autopilot_flag_fault")} == {0}
    # persistence 0.1 s (preset fast) plus at most two exchange periods
    assert LANE_FAULT_T + 0.1 <= sw[0]["t"] <= LANE_FAULT_T + 0.1 + 0.04 + 1e-9
    t = r.log["t"]
    assert set(r.log["ap_lane"][t > sw[0]["t"]]) == {1.0}
    d = r.log["truth_d"]
    d0 = d[np.searchsorted(t, LANE_FAULT_T)]
    assert np.max(np.abs(d[t > LANE_FAULT_T] - d0)) < 0.5  # the vehicle holds its altitude through it


def test_same_seed_gives_the_same_run_bit_for_bit() -> None:
    sc = _scenario(duration_s=6.8, redundancy={"autopilot_lanes": 3},
                   faults=[{"type": "autopilot_lane_fail", "start_s": LANE_FAULT_T, "lane": 0}])
    a, b = run_scenario(sc, MerlinConfig()), run_scenario(sc, MerlinConfig())
    assert a.decisions_digest == b.decisions_digest
    strip = lambda r: [{k: v for k, v in e.items() if k != "traceback"} for e in r.events]  # noqa: E731
    assert strip(a) == strip(b)


def test_the_default_path_builds_nothing() -> None:
    loop = ClosedLoop(_scenario(), MerlinConfig())
    assert loop.redundancy is None and loop.extra_log_row is None
    loop_ekf = ClosedLoop(_scenario(estimator="ekf"), MerlinConfig())
    assert loop_ekf.redundancy is not None and loop_ekf.redundancy.voter is not None
    assert loop_ekf.redundancy.lanes is None
    off = ClosedLoop(_scenario(estimator="ekf", redundancy={"sensor_voter": False}), MerlinConfig())
    assert off.redundancy is None


@pytest.mark.parametrize("bad", [{"autopilot_lanes": 2}, {"lane_preset": "slow"}, {"bumpless_step": 0.0},
                                 {"voter": True}])
def test_a_bad_redundancy_section_is_refused(bad: dict[str, Any]) -> None:
    with pytest.raises(ValidationError):
        _scenario(redundancy=bad)


# ------------------------------------------------------------------------------------------ unit parts


@settings(max_examples=60, deadline=None)
@given(cmds=st.lists(st.tuples(*[st.floats(0.0, 1.0)] * 4), min_size=4, max_size=40),
       switch_at=st.integers(1, 3), max_step=st.floats(0.005, 0.2))
def test_the_hand_over_adds_at_most_the_limit_per_tick_and_outputs_stay_in_range(cmds, switch_at, max_step):
    """Whatever the lanes command: while one lane stays selected its command passes unchanged; at and
    after a switch each actuator's step exceeds the incoming lane's own step by at most ``max_step``."""
    sw = BumplessSwitch(max_step)
    other = [tuple(1.0 - x for x in c) for c in cmds]  # lane 1 commands something else entirely
    prev_out = None
    for k, (c0, c1) in enumerate(zip(cmds, other, strict=True)):
        sel = 0 if k < switch_at else 1
        out = sw.step(sel, (c0, c1, c1))
        assert all(0.0 <= o <= 1.0 for o in out)
        if k < switch_at:
            assert out == c0
        else:
            assert prev_out is not None
            own, prev_own = c1, other[k - 1]
            for o, p, c, q in zip(out, prev_out, own, prev_own, strict=True):
                assert abs(o - p) <= abs(c - q) + max_step + 1e-9
        prev_out = out
    gap = max(abs(a - b) for a, b in zip(cmds[switch_at - 1], other[switch_at - 1], strict=True))
    if len(cmds) - switch_at > math.ceil(gap / max_step) + 1:
        assert sw.step(1, (cmds[-1], other[-1], other[-1])) == pytest.approx(other[-1])  # the fade is over


@given(own=st.tuples(*[st.floats(0.3, 0.7)] * 4), d=st.tuples(*[st.floats(-0.05, 0.05)] * 4),
       gain=st.floats(0.0, 1.0))
def test_tracking_moves_the_integrators_by_the_mixer_decomposition_of_the_gap(own, d, gain):
    st0 = ControllerState(active=True, hover_thrust_est=0.5)
    act = tuple(o + x for o, x in zip(own, d, strict=True))
    st1 = track_actuated(st0, own, act, gain, DEFAULT_GAINS)
    dd = [a - o for a, o in zip(act, own, strict=True)]
    rows = (MIX_ROLL, MIX_PITCH, MIX_YAW)
    for axis in range(3):
        want = gain * 0.25 * sum(m * x for m, x in zip(rows[axis], dd, strict=True))
        assert st1.rate_int[axis] == pytest.approx(want, abs=1e-12)
    assert st1.hover_thrust_est - 0.5 == pytest.approx(gain * 0.25 * sum(dd), abs=1e-12)
    # gain 1 and no clamping: the lane's own mixer output would now equal the actuated command
    if gain == 1.0:
        for i in range(4):
            rebuilt = own[i] + (st1.hover_thrust_est - 0.5) + sum(rows[a][i] * st1.rate_int[a] for a in range(3))
            assert rebuilt == pytest.approx(act[i], abs=1e-12)


def test_single_unit_channels_pass_through_without_lowering_nav_health() -> None:
    suite = SensorSuiteVoter(np.random.default_rng(0))
    for k in range(40):
        t = k * 0.0025
        imu = tuple(ImuSample(t, (0.01 * i + 1e-4 * math.sin(30 * t + i), 0.0, 0.0), (0.0, 0.0, -9.81), i)
                    for i in range(3))
        mag, baro = MagSample(t, (0.27, 0.0, 0.37)), BaroSample(t, 10.0)
        gps = GpsSample(t, (1.0, 2.0, -10.0), (0.0, 0.0, 0.0), 3, 12)
        out = suite.step(t, imu, (mag,), (baro,), (gps,))
    assert out.imu is not None and out.imu.lane == VOTED_LANE
    assert out.mag is mag and out.baro is baro and out.gps is gps
    assert dict(out.levels) == {"imu": RedundancyLevel.TRIPLEX, "mag": RedundancyLevel.SIMPLEX,
                                "baro": RedundancyLevel.SIMPLEX, "gps": RedundancyLevel.SIMPLEX}
    assert out.nav_health == 1.0
    with pytest.raises(ValueError):
        suite.step(1.0, imu, (mag,), (baro, baro, baro), (gps,))


def test_the_redundancy_plot_is_written_only_for_runs_with_redundancy(tmp_path) -> None:
    from sims.redundancy_plot import plot_redundancy

    p = plot_redundancy(_lane_run(), tmp_path)
    assert p is not None and p.stat().st_size > 10_000
    plain = run_scenario(_scenario(duration_s=0.5), MerlinConfig())
    assert plot_redundancy(plain, tmp_path / "none") is None


def test_a_sim_report_of_a_redundancy_run_includes_the_redundancy_page(tmp_path) -> None:
    """What ``merlin sim`` writes (sims.report.write_all): redundancy.png beside the other plots."""
    from sims.report import write_all

    files = write_all(_lane_run(), [], tmp_path / "lanes")
    assert files["redundancy"] == tmp_path / "lanes" / "redundancy.png"
    assert files["redundancy"].stat().st_size > 10_000
    plain = write_all(run_scenario(_scenario(duration_s=0.5), MerlinConfig()), [], tmp_path / "plain")
    assert "redundancy" not in plain and not (tmp_path / "plain" / "redundancy.png").exists()
