"""Seed 000 lane voter: the testable behaviours of notes §7, the presets and the fixed flaws."""

from __future__ import annotations

from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.redundancy.events import FaultKind
from merlin.redundancy.lane_sim import LaneFault, run_lane_bus
from merlin.redundancy.lane_voter import (
    FAST,
    THESIS,
    THESIS_SITL,
    BumplessSwitch,
    LaneMessage,
    LaneVoter,
    Received,
    Selector,
    priorities_from_counters,
    vote_from_priorities,
)

N_FLAGS = len(THESIS.flags)
OK = (True,) * N_FLAGS


def _peer(sender, t, flags=OK, vote=0, hears=(True, True, True)):
    return Received(t, LaneMessage(sender, t, flags, vote, hears))


def _bad(flag_index):
    f = list(OK)
    f[flag_index] = False
    return tuple(f)


def test_counters_4_0_0_give_priorities_3_1_1_and_vote_for_lane_1():
    """Notes §7 item 8 (seed 000 §5.3.2)."""
    p = priorities_from_counters((4, 0, 0), (False, False, False))
    assert p == (3, 1, 1) and vote_from_priorities(p) == 1


def test_ties_go_to_the_lowest_index():
    assert vote_from_priorities((1, 1, 1)) == 0
    assert vote_from_priorities((2, 1, 1)) == 1


@given(st.tuples(*[st.integers(0, 12)] * 3), st.tuples(*[st.booleans()] * 3))
def test_priorities_stay_in_range_and_the_winner_has_the_minimum(counters, silent):
    """Notes §7 item 17."""
    p = priorities_from_counters(counters, silent)
    assert all(1 <= x <= 3 for x in p)
    w = vote_from_priorities(p)
    assert p[w] == min(p) and all(p[k] > p[w] for k in range(w))


@pytest.mark.parametrize(("votes", "expected"), [((0, 0, 0), 0), ((1, 1, 0), 1), ((2, 0, 2), 2), ((0, 1, 2), 0),
                                                 ((2, 1, 0), 0)])
def test_selector_plurality_and_1_1_1_to_lane_0(votes, expected):
    """Notes §7 item 3."""
    s = Selector(vote_timeout_s=3.0)
    for i, v in enumerate(votes):
        s.receive(0.0, i, v)
    assert s.step(0.0).lane == expected


def _run_voter(cfg, lane, ticks, flags_of):
    """Drive one lane's voter with peers that report flags_of(t, peer)."""
    v = LaneVoter(cfg, lane)
    outs = []
    for k in range(ticks):
        t = 100.0 + k * cfg.period_s
        peers = tuple(None if j == lane else _peer(j, t - 0.01, flags_of(t, j)) for j in range(3))
        outs.append(v.step(t, flags_of(t, lane), peers, takeoff_t_s=0.0))
    return outs


def test_unanimous_bad_flag_is_not_a_fault():
    """Notes §7 item 4: battery unhealthy on all three is external to the autopilots."""
    outs = _run_voter(THESIS, 1, 5, lambda t, j: _bad(6))
    assert all(o.counters == (0, 0, 0) and o.vote == 0 for o in outs)


def test_only_the_dissenting_lane_is_charged_after_persistence_and_latched():
    """Notes §7 items 5, 6, 7: > 1 s of disagreement counts; it stays counted for 600 s."""
    def flags(t, j):
        return _bad(0) if (j == 0 and t < 103.0) else OK

    outs = _run_voter(THESIS, 2, 20, flags)
    assert outs[0].counters == (0, 0, 0)  # seen once: not yet persistent
    assert outs[1].counters == (1, 0, 0)  # seen again 1 s later
    assert outs[1].vote == 1
    assert all(o.counters == (1, 0, 0) for o in outs[1:])  # latched after it cleared at 103 s
    latched = [e for o in outs for e in o.events if e.kind is FaultKind.FLAG_FAULT]
    assert len(latched) == 1 and latched[0].lane == 0


def test_single_tick_glitch_is_ignored():
    outs = _run_voter(THESIS, 2, 5, lambda t, j: _bad(0) if (j == 0 and abs(t - 101.0) < 0.1) else OK)
    assert all(o.counters == (0, 0, 0) for o in outs)


def test_latch_expires_after_600_s():
    cfg = replace(THESIS, latch_s=3.0)
    outs = _run_voter(cfg, 2, 10, lambda t, j: _bad(0) if (j == 0 and t < 102.0) else OK)
    assert outs[1].counters == (1, 0, 0)
    assert outs[-1].counters == (0, 0, 0)  # latched until 104 s only


def test_bad_value_charge_variant_charges_every_bad_lane():
    cfg = replace(THESIS, charge="bad_value")
    outs = _run_voter(cfg, 2, 3, lambda t, j: _bad(0) if j in (0, 1) else OK)
    assert outs[-1].counters == (1, 1, 0)
    outs = _run_voter(THESIS, 2, 3, lambda t, j: _bad(0) if j in (0, 1) else OK)
    assert outs[-1].counters == (0, 0, 1)  # thesis text: the lone dissenter is charged


def test_take_off_gate_holds_lane_0():
    """Notes §7 item 11."""
    v = LaneVoter(THESIS, 1)
    for k in range(5):
        t = 10.0 + k
        out = v.step(t, OK, (_peer(0, t - 0.01, _bad(0)), None, _peer(2, t - 0.01)), takeoff_t_s=0.0)
    assert out.gated and out.vote == 0 and out.counters == (0, 0, 0)


def test_thesis_preset_silent_lane_last_choice_after_3_s():
    """Notes §7 items 9-10 on the bus: lane 0 stops sending to its peers (still votes for itself)."""
    res = run_lane_bus(THESIS_SITL, 40.0, (LaneFault(0, 20.0, "mute"),), takeoff_t_s=0.0)
    last = res.last_sent_to_peers[0]
    switch = [e for e in res.events if e.kind is FaultKind.LANE_SWITCH]
    assert [e.lane for e in switch] == [1]
    assert 3.0 < switch[0].t_s - last <= 4.0 + 1e-9  # > 3 s of silence, read at the next 1 Hz tick
    # the peers' messages say they no longer hear lane 0, so lane 0 learns it is isolated (fixed flaw)
    assert any(e.kind is FaultKind.SELF_ISOLATED and e.lane == 0 for e in res.events)


def test_without_the_fix_the_isolated_lane_keeps_voting_for_itself():
    cfg = replace(THESIS_SITL, self_isolation=False)
    res = run_lane_bus(cfg, 40.0, (LaneFault(0, 20.0, "mute"),), takeoff_t_s=0.0)
    assert res.votes[-1][0].vote == 0 and res.votes[-1][1].vote == 1 and res.selected[-1] == 1
    fixed = run_lane_bus(THESIS_SITL, 40.0, (LaneFault(0, 20.0, "mute"),), takeoff_t_s=0.0)
    assert fixed.votes[-1][0].vote == 1 and fixed.votes[-1][0].self_isolated


def test_fast_preset_votes_out_a_silent_lane_within_three_periods():
    """Issue target: out within 3 exchange periods (60 ms) of its last message; the replacement lane
    holds the selection from that tick, so it commands on the runner's next tick."""
    res = run_lane_bus(FAST, 8.0, (LaneFault(0, 6.0, "mute_selector"),), takeoff_t_s=0.0)
    last = res.last_sent_to_peers[0]
    switch = [e for e in res.events if e.kind is FaultKind.LANE_SWITCH]
    assert len(switch) == 1 and switch[0].lane == 1
    assert switch[0].t_s - last <= 3 * FAST.period_s + 1e-9
    k = res.t_s.index(switch[0].t_s)
    assert res.selected[k] == 1 and res.selected[k - 1] == 0


def test_flag_fault_switches_lanes_on_the_bus():
    res = run_lane_bus(FAST, 8.0, (LaneFault(0, 6.0, "flag", "local_position_valid"),), takeoff_t_s=0.0)
    switch = [e for e in res.events if e.kind is FaultKind.LANE_SWITCH]
    assert [e.lane for e in switch] == [1]
    assert FAST.persistence_s <= switch[0].t_s - 6.0 <= FAST.persistence_s + 2 * FAST.period_s + 1e-9


def test_all_voters_fed_the_same_data_agree():
    """Notes §7 item 17."""
    res = run_lane_bus(FAST, 8.0, (LaneFault(2, 6.0, "flag", "battery_healthy"),), takeoff_t_s=0.0)
    for votes in res.votes:
        assert len({v.vote for v in votes}) == 1


def test_bumpless_switch_bounds_the_actuator_step_and_feeds_tracking():
    sw = BumplessSwitch(max_step=0.01)
    a = (0.5, 0.5, 0.5, 0.5)
    b = (0.7, 0.3, 0.5, 0.9)
    out = sw.step(0, (a, b, b))
    assert out == a
    outs = [sw.step(1, (a, b, b)) for _ in range(60)]
    prev = a
    for o in outs:
        assert max(abs(x - y) for x, y in zip(o, prev, strict=True)) <= 0.01 + 1e-12
        prev = o
    assert outs[-1] == pytest.approx(b)
    assert sw.tracking_reference() == outs[-1]


def test_standby_lanes_tracking_the_actuated_command_make_the_switch_seamless():
    """Three PI lanes on one first-order plant. Standby lanes back-calculate their integrator from the
    tracking reference (seed 000 §5.3.1's "fight" fixed): at the switch their command already equals
    the actuated one, so the bumpless limiter never has to act."""
    dt, ki, kp = 0.01, 2.0, 1.5
    sensor_offset = (0.0, 0.05, -0.05)  # each lane sees the plant through its own sensor lane
    integ = [0.0, 0.0, 0.0]
    sw = BumplessSwitch(max_step=0.02)
    x, setpoint = 0.0, 1.0
    selected = 0
    jumps = []
    for k in range(1000):
        if k == 600:
            selected = 1
        cmds = []
        ref = sw.tracking_reference()
        for i in range(3):
            e = setpoint - (x + sensor_offset[i])
            if i != selected and ref is not None:
                integ[i] = ref[0] - kp * e  # track: the lane's own command equals the actuated one
            else:
                integ[i] += ki * e * dt
            cmds.append((kp * e + integ[i],))
        before = sw.last
        u = sw.step(selected, tuple(cmds))
        if k == 600:
            jumps.append(abs(cmds[1][0] - before[0]))
        x += dt * (-x + u[0])
    assert jumps[0] < 0.05  # the incoming lane's own command is already at the actuated value
    assert abs(x - (setpoint - sensor_offset[1])) < 0.05


@settings(max_examples=12, deadline=None)
@given(lane=st.integers(0, 2), flag=st.sampled_from(FAST.flags), onset=st.floats(5.5, 7.0),
       kind=st.sampled_from(["flag", "mute", "mute_selector"]))
def test_a_single_faulty_lane_is_never_selected_after_the_fault_is_counted(lane, flag, onset, kind):
    """Safety invariant on the bus: one lane failing (bad flag or silence) can only move the selection
    away from it; once its fault is counted, it is never the selected lane."""
    res = run_lane_bus(FAST, 8.5, (LaneFault(lane, onset, kind, flag),), takeoff_t_s=0.0)
    settle = onset + FAST.persistence_s + 3 * FAST.period_s
    for t, sel in zip(res.t_s, res.selected, strict=True):
        if t >= settle:
            assert sel != lane, (t, sel)
    switches = [e for e in res.events if e.kind is FaultKind.LANE_SWITCH]
    assert all(e.lane != lane for e in switches)
    assert len(switches) == (1 if lane == 0 else 0)
