"""Safety invariants of the trusted core, stated as properties and checked with hypothesis."""

from __future__ import annotations

import math
from dataclasses import replace

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core.envelope import TIME_EPS_S, envelope_values, outside
from merlin.core.step import TrustedCore
from merlin.core.types import (
    Authority,
    AuthorityRequest,
    CommandKind,
    EventKind,
    ExperimentalInput,
    GcsCommand,
    GcsCommandKind,
    Inputs,
    NavMode,
    OperatorInput,
    RequestKind,
    Setpoint,
    SetpointKind,
    VehicleState,
)
from tests.core.harness import DT, HOVER_10M, Harness

CORE_CFG = build_core_config(MerlinConfig())
ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True)
SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


_TEMPLATE: list[Harness] = []


def _granted_harness() -> Harness:
    """A harness in EXPERIMENTAL authority. The core's state is immutable, so one flown template is
    cloned for every example instead of flying the take-off again."""
    if not _TEMPLATE:
        t = Harness()
        t.airborne()
        t.grant()
        _TEMPLATE.append(t)
    t = _TEMPLATE[0]
    h = Harness(cfg=t.cfg)
    h.core.state = t.core.state
    for name in ("k", "state", "last_hb_t", "last_sp_t", "last_gcs_t"):
        setattr(h, name, getattr(t, name))
    return h


# ----------------------------------------------------------------------------------------- envelope


STATE_FIELDS = st.fixed_dictionaries(
    {
        "roll": st.floats(-0.8, 0.8),
        "pitch": st.floats(-0.8, 0.8),
        "vn": st.floats(-12.0, 12.0),
        "vd": st.floats(-4.0, 3.0),
        "alt": st.floats(1.0, 110.0),
        "p": st.floats(-3.5, 3.5),
    }
)


def _state(f: dict[str, float]) -> VehicleState:
    return replace(
        HOVER_10M,
        pos_ned_m=(0.0, 0.0, -f["alt"]),
        vel_ned_mps=(f["vn"], 0.0, f["vd"]),
        att_rpy_rad=(f["roll"], f["pitch"], 0.0),
        rates_frd_radps=(f["p"], 0.0, 0.0),
    )


@given(st.lists(STATE_FIELDS, min_size=1, max_size=120))
@SETTINGS
def test_experimental_never_holds_authority_past_an_exceedance_and_is_revoked_exactly_then(seq) -> None:
    """EXPERIMENTAL never holds authority on a tick where some parameter has been out of bounds for at
    least its duration; and while it held authority, it was not revoked for the envelope before that tick."""
    h = _granted_harness()
    limits = h.core.cfg.envelope
    since = [None] * len(limits)
    for f in seq:
        s = _state(f)
        t = h.t
        values = envelope_values(s)
        due = False
        for i, lim in enumerate(limits):
            if outside(lim, values[lim.index]):
                since[i] = t if since[i] is None else since[i]
                if t - since[i] + TIME_EPS_S >= lim.duration_s:
                    due = True
            else:
                since[i] = None
        was = h.core.state.arbiter.authority
        d = h.tick(state=s)
        if due:
            assert d.authority is not Authority.EXPERIMENTAL
        elif was is Authority.EXPERIMENTAL and d.authority is not Authority.EXPERIMENTAL:
            # revoked for another reason (e.g. the fence), never early for the envelope
            assert all(e.reason.monitor != "envelope" for e in d.events if e.kind is EventKind.REVOKED)
        if d.authority is not Authority.EXPERIMENTAL:
            break


@given(gap_ticks=st.integers(1, 400), alive_ticks=st.integers(0, 50))
@settings(max_examples=40, deadline=None)
def test_a_heartbeat_gap_longer_than_the_timeout_always_revokes(gap_ticks: int, alive_ticks: int) -> None:
    h = _granted_harness()
    h.run(max(alive_ticks, 1) * DT)
    h.heartbeat = False
    last = h.last_hb_t
    assert last is not None
    for _ in range(gap_ticks + 1):
        d = h.tick()
        gap = d.t_s - last
        if gap > CORE_CFG.watchdogs.controller_heartbeat_s:
            assert d.authority is Authority.TRUSTED
            return
        assert d.authority is Authority.EXPERIMENTAL


REQUESTS = st.lists(
    st.one_of(
        st.just(()),
        st.tuples(st.builds(AuthorityRequest, st.sampled_from(list(RequestKind)), st.integers(0, 5))),
    ),
    min_size=1,
    max_size=200,
)


@given(REQUESTS, st.lists(st.booleans(), min_size=200, max_size=200))
@SETTINGS
def test_experimental_gains_authority_only_through_a_completed_exchange(reqs, heartbeat_pattern) -> None:
    h = _granted_harness()
    h.tick(requests=(AuthorityRequest(RequestKind.RELEASE),))
    granted: dict[int, float] = {}
    acked: dict[int, float] = {}
    for i, r in enumerate(reqs):
        h.heartbeat = heartbeat_pattern[i % len(heartbeat_pattern)] or i % 3 == 0
        before = h.core.state.arbiter.authority
        d = h.tick(requests=r)
        for e in d.events:
            if e.kind is EventKind.GRANTED:
                granted[e.seq] = d.t_s
            if e.kind is EventKind.ACKNOWLEDGED:
                assert e.seq in granted
                acked[e.seq] = d.t_s
        if d.authority is Authority.EXPERIMENTAL and before is not Authority.EXPERIMENTAL:
            ev = [e for e in d.events if e.kind is EventKind.AUTHORITY and e.to is Authority.EXPERIMENTAL]
            assert ev, "authority changed without an authority event"
            seq = ev[0].seq
            assert seq in granted and seq in acked
            assert acked[seq] < d.t_s  # switched on a later tick than the ACK
            assert granted[seq] <= acked[seq]


# ------------------------------------------------------------------------------------------- robustness

VEC = st.tuples(ANY_FLOAT, ANY_FLOAT, ANY_FLOAT)
STATES = st.builds(
    VehicleState,
    pos_ned_m=VEC,
    vel_ned_mps=VEC,
    att_rpy_rad=VEC,
    rates_frd_radps=VEC,
    accel_frd_mps2=VEC,
    airspeed_mps=ANY_FLOAT,
    pos_sigma_h_m=ANY_FLOAT,
    pos_sigma_v_m=ANY_FLOAT,
    nav_mode=st.sampled_from(list(NavMode)),
    nav_inertial_s=ANY_FLOAT,
    armed=st.booleans(),
    landed=st.booleans(),
    battery_frac=ANY_FLOAT,
)
SETPOINTS = st.one_of(
    st.none(),
    st.builds(
        Setpoint,
        kind=st.sampled_from(list(SetpointKind)),
        pos_ned_m=VEC,
        vel_ned_mps=VEC,
        yaw_rad=ANY_FLOAT,
        yaw_rate_radps=ANY_FLOAT,
        att_rpy_rad=VEC,
        thrust=ANY_FLOAT,
    ),
)
OPT_T = st.one_of(st.none(), ANY_FLOAT)
INPUTS = st.builds(
    Inputs,
    state=STATES,
    experimental=st.builds(
        ExperimentalInput,
        heartbeat_t_s=OPT_T,
        setpoint=SETPOINTS,
        setpoint_t_s=OPT_T,
        requests=st.lists(st.builds(AuthorityRequest, st.sampled_from(list(RequestKind)), st.integers(-3, 5)),
                          max_size=3).map(tuple),
    ),
    operator=st.builds(OperatorInput, link_t_s=OPT_T, takeover=st.booleans(), roll=ANY_FLOAT, pitch=ANY_FLOAT,
                       yaw=ANY_FLOAT, throttle=ANY_FLOAT),
    gcs_link_t_s=OPT_T,
    gcs_commands=st.lists(st.builds(GcsCommand, st.sampled_from(list(GcsCommandKind)), ANY_FLOAT,
                                    st.integers(0, 3), st.booleans()), max_size=2).map(tuple),
)


def _finite_command(d) -> bool:
    c = d.command
    vals = (*c.vel_ned_mps, c.yaw_rad, c.yaw_rate_radps, *c.att_rpy_rad, c.thrust)
    return all(math.isfinite(v) for v in vals)


@given(st.lists(st.tuples(ANY_FLOAT, INPUTS), min_size=1, max_size=25))
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_no_input_finite_or_not_makes_step_raise_or_emit_a_non_finite_command(ticks) -> None:
    core = TrustedCore(CORE_CFG)
    for now, inputs in ticks:
        d = core.step(now, inputs)
        assert _finite_command(d)
        assert d.command.kind in CommandKind


@given(st.lists(INPUTS, min_size=1, max_size=15))
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_garbage_after_a_grant_never_grants_and_never_raises(inputs_seq) -> None:
    h = _granted_harness()
    core = h.core
    t = h.t
    for inputs in inputs_seq:
        before = core.state.arbiter.authority
        d = core.step(t, inputs)
        t += DT
        assert _finite_command(d)
        if before is not Authority.EXPERIMENTAL:
            assert d.authority is not Authority.EXPERIMENTAL or any(
                e.kind is EventKind.AUTHORITY and e.to is Authority.EXPERIMENTAL for e in d.events
            )


def test_replay_reproduces_decisions_exactly() -> None:
    h = Harness(rc_alive=True)
    h.airborne()
    h.grant()
    h.run(0.5, state=replace(HOVER_10M, att_rpy_rad=(0.7, 0.0, 0.0)))
    h.operator = OperatorInput(takeover=True, pitch=0.3)
    h.run(0.5)
    # replay the same inputs through a fresh core
    recorded = []
    h2 = Harness(rc_alive=True)
    class Recording:  # wraps the core (a compiled TrustedCore's methods cannot be reassigned)
        def __init__(self, core: TrustedCore) -> None:
            self.core = core

        def step(self, now, inputs):
            recorded.append((now, inputs))
            return self.core.step(now, inputs)

    h2.core = Recording(h2.core)  # type: ignore[assignment]
    h2.airborne()
    h2.grant()
    h2.run(0.5, state=replace(HOVER_10M, att_rpy_rad=(0.7, 0.0, 0.0)))
    h2.operator = OperatorInput(takeover=True, pitch=0.3)
    h2.run(0.5)
    fresh = TrustedCore(CORE_CFG)
    replayed = [fresh.step(now, inputs) for now, inputs in recorded]
    assert replayed == h2.history
    assert [d.authority for d in replayed] == [d.authority for d in h.history]
