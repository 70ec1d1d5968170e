"""The JSBSim fixed wing in the whole closed loop (sensors, estimator, trusted core, fixed-wing actuator
stage): stall protection, the velocity-projected fence at several approach angles and speeds and next to
the range's notch, and the seed FCU thesis's lap. Checked numerically against the run's log, where the
scenario expectation types cannot say it (height lost after a revocation, height/airspeed errors).

The runs use the scenarios' own rates (200 Hz for the stall and the fence, 100 Hz for the 170 s lap:
the lap's errors agree with 200 Hz to 0.03 m RMS; docs/fixed-wing.md, "Closed loop").
"""

from __future__ import annotations

import math
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from merlin.config.loader import load_config
from merlin.config.runtime import build_core_config
from sims.expectations import evaluate_all, event_parameter
from sims.fixedwing_loop import FixedWingLoop
from sims.runner import RunResult, run_scenario
from sims.scenario import EVENT_PARAMETERS, EVENT_TYPES, Scenario, load_scenario, resolve_config
from tests.scenarios_fixedwing.fence_cases import (
    ANGLES_DEG,
    CEILING_M,
    CLIMB_RATES_MPS,
    COURSES_DEG,
    FLOOR_M,
    SPEEDS_MPS,
    altitude_case,
    approach_case,
    corner_case,
    course_case,
    notch_case,
)

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "examples" / "scenarios"
CONFIG = ROOT / "examples" / "configs" / "fixedwing_default.yaml"
STALL_SPEED_MPS = 15.5  # the model's 1 g stall speed (docs/fixed-wing.md; tests/fixedwing/test_vehicle.py)
ALPHA_STALL_DEG = 23.5
HEIGHT_LOSS_BOUND_M = 8.0  # the stated bound (docs/fixed-wing.md)
FENCE = build_core_config(load_config(CONFIG)).fence  # built once (its distance field takes a moment)
assert FENCE is not None
FENCE_PARAMS = FENCE.params


def _expectations_pass(r: RunResult) -> None:
    verdicts = evaluate_all(r.scenario.expectations, r.events, r.log, r.metrics)
    failed = [v.to_dict() for v in verdicts if not v.passed]
    assert not failed, failed
    # the list a scenario's event expectations are checked against holds every event the run logged
    assert {e["type"] for e in r.events} <= EVENT_TYPES, {e["type"] for e in r.events} - EVENT_TYPES
    # and every parameter an event named (the list an expectation's ``parameter`` is checked against)
    named = {event_parameter(e) for e in r.events} - {None, ""}
    assert named <= EVENT_PARAMETERS, named - EVENT_PARAMETERS


@cache
def _run_file(name: str, log_rate_hz: float | None = None) -> RunResult:
    sc, cfg = load_scenario(SCENARIOS / name)
    if log_rate_hz is not None:
        sc = sc.model_copy(update={"log_rate_hz": log_rate_hz})
    return run_scenario(sc, cfg, source=name)


@cache
def _run_case(kind: str, speed_mps: float) -> RunResult:
    sc = notch_case(FENCE_PARAMS, speed_mps) if kind == "notch" else approach_case(FENCE_PARAMS, float(kind), speed_mps)
    return run_scenario(sc, resolve_config(sc, SCENARIOS, "<generated>"), source=sc.name)


def _row(log: dict[str, np.ndarray], t: float) -> int:
    return int(np.searchsorted(log["t"], t - 1e-9))


def height_loss_after_revocation_m(r: RunResult) -> float:
    """Height at the first revocation minus the lowest height after it (what the stall recovery costs)."""
    rev = next(e for e in r.events if e["type"] == "revoked")
    k = _row(r.log, rev["t"])
    h = -r.log["truth_d"]
    return float(h[k] - h[k:].min())


def _surface_steps_at_changes(r: RunResult, columns: tuple[str, ...] = ("m0", "m1", "m2", "m3")) -> float:
    """Largest step of any surface across a change of authority or behaviour (log at the tick rate)."""
    log = r.log
    change = np.flatnonzero((np.diff(log["authority"]) != 0) | (np.diff(log["behavior"]) != 0)) + 1
    steps = [max(abs(float(log[c][k] - log[c][k - 1])) for c in columns) for k in change]
    return max(steps, default=0.0)


# ------------------------------------------------------------------------------------------------ stall


def test_stall_protection_revokes_before_the_stall_and_recovers_within_the_bound() -> None:
    r = _run_file("fw_stall_protection.yaml", log_rate_hz=200.0)
    _expectations_pass(r)
    rev = [e for e in r.events if e["type"] == "revoked"]
    assert len(rev) == 1 and rev[0]["reason"] == "envelope"
    assert rev[0]["reason_detail"]["parameter"] in ("airspeed_mps", "alpha_deg")
    k = _row(r.log, rev[0]["t"])
    airspeed, alpha = r.log["env_airspeed_mps"], r.log["env_alpha_deg"]
    # before the stall: the aircraft never got near the stall speed or the stall angle, before or after
    assert airspeed[k] > STALL_SPEED_MPS + 2.0, airspeed[k]
    assert alpha[k] < ALPHA_STALL_DEG - 5.0, alpha[k]
    assert airspeed.min() > STALL_SPEED_MPS + 2.0 and alpha.max() < ALPHA_STALL_DEG - 5.0
    # the experimental controller really pulled the speed down: it was revoked on the way to the stall
    assert airspeed[k] < 18.5
    loss = height_loss_after_revocation_m(r)
    assert 0.0 < loss < HEIGHT_LOSS_BOUND_M, loss
    # recovered: back at cruise and within 3 m of the revocation height by the end
    h = -r.log["truth_d"]
    assert airspeed[-1] == pytest.approx(22.0, abs=1.0)
    assert h[-1] > h[k] - 3.0
    # bumpless: no control surface steps by more than two autopilot ticks of setpoint slew at the switches;
    # the throttle does (the underspeed recovery goes to full power at once)
    assert _surface_steps_at_changes(r, ("m0", "m1", "m2")) < 0.05
    assert r.log["m3"][k + 1] == pytest.approx(1.0)


PUSH_HEIGHTS_M = (38, 45, 60)


@pytest.mark.parametrize("height_m", PUSH_HEIGHTS_M)
def test_a_push_at_full_throttle_before_the_stall_revocation_recovers_above_the_floor(height_m: int) -> None:
    """The adversary pulls up at idle, then pushes the nose down at full throttle 0.1 s before the airspeed
    revocation: Merlin takes over a slow aircraft pitching down hard at full power. The recovery (full power,
    wings level, pitch on the sink) loses far less than the bound and keeps the floor from 38 m up (it lost
    11.3-11.7 m and went 3.7 m through the floor from 38 m when TECS traded height for speed at the switch)."""
    r = _run_file(f"fw_adv_push_before_stall_{height_m}m.yaml")
    _expectations_pass(r)
    rev = [e for e in r.events if e["type"] == "revoked"]
    assert rev[0]["reason_detail"]["parameter"] == "airspeed_mps"
    k = _row(r.log, rev[0]["t"])
    assert r.log["env_pitch_rate_degps"][k] < -10.0  # handed over pitching down hard ...
    assert r.log["m3"][k - 1] > 0.3  # ... with the throttle going up
    loss = height_loss_after_revocation_m(r)
    assert loss < 4.0, loss
    h = -r.log["truth_d"]
    assert h[k:].min() > FENCE_PARAMS.altitude_floor_m + 2.0
    assert r.log["env_airspeed_mps"][k:].min() > STALL_SPEED_MPS + 2.0
    assert r.log["env_alpha_deg"][k:].max() < ALPHA_STALL_DEG - 5.0
    # the airspeed the revoked controller left below the envelope's minimum is noted, with its reason
    notes = [e for e in r.events if e["type"] == "fixed_wing_trusted_excursion"]
    assert notes and notes[0]["parameter"] == "airspeed_mps" and notes[0]["reason"].startswith("inherited")


def test_a_head_on_approach_in_a_tailwind_turns_back_inside() -> None:
    """22 m/s at the east boundary with a 10 m/s tailwind, revoked 0.6 s after the grant: the escape turn rolls
    in at once (the takeover does not carry the revoked command's integrators) and keeps the widening (it
    crossed the boundary by 9.2 m when it did)."""
    r = _run_file("fw_adv_tailwind_fence_22mps.yaml")
    _expectations_pass(r)
    assert r.metrics["min_fence_margin_m"] > FENCE_PARAMS.margin_m, r.metrics["min_fence_margin_m"]


# ------------------------------------------------------------------------------------------------ fence

CASES = [(str(a), v) for a in ANGLES_DEG for v in SPEEDS_MPS] + [("notch", v) for v in SPEEDS_MPS]


@pytest.mark.parametrize(("kind", "speed_mps"), CASES, ids=[f"{k}_{int(v)}mps" for k, v in CASES])
def test_fence_approach_holds_at_every_angle_and_speed(kind: str, speed_mps: float) -> None:
    """Velocity projection with a fixed wing's turn: zero breach at 0/30/60/90 deg to the boundary normal
    (90: parallel to the east boundary, into the north-east corner), at cruise and maximum speed, and next
    to the notch, where only the turn away from home is clear."""
    r = _run_case(kind, speed_mps)
    _expectations_pass(r)
    assert r.metrics["max_fence_breach_m"] == 0.0
    assert r.metrics["min_fence_margin_m"] > 0.0
    rev = next(e for e in r.events if e["type"] == "revoked")
    k = _row(r.log, rev["t"])
    turn_roll = float(np.mean(r.log["truth_roll"][k + 50 : k + 150]))  # 1-3 s after the trip
    if kind == "notch":
        assert turn_roll > math.radians(20.0)  # right: the left turn (towards home) is blocked by the notch
    elif kind != "0.0":
        assert turn_roll < -math.radians(20.0)  # left: away from the east boundary it is flying along
    assert _surface_steps_at_changes(r) < 0.1  # the log is at 50 Hz here: two to four autopilot ticks


ALTITUDE_CASES = [(lim, v, c) for lim in ("ceiling", "floor") for v in SPEEDS_MPS for c in CLIMB_RATES_MPS]


@pytest.mark.parametrize(("limit", "speed_mps", "climb_mps"), ALTITUDE_CASES,
                         ids=[f"{lim}_{int(v)}mps_climb{c:g}" for lim, v, c in ALTITUDE_CASES])
def test_fence_altitude_approach_levels_off_inside(limit: str, speed_mps: float, climb_mps: float) -> None:
    """The projection's vertical part: climbing to the ceiling (descending to the floor) at 2 and 4 m/s, at
    cruise and maximum speed, the fence revokes the flyaway on the projected climb (descent) and Merlin's
    RTL levels off (climbs back) inside: zero breach, the ceiling and floor never reached."""
    sc = altitude_case(FENCE_PARAMS, limit, speed_mps, climb_mps)
    r = run_scenario(sc, resolve_config(sc, SCENARIOS, "<generated>"), source=sc.name)
    _expectations_pass(r)
    rev = next(e for e in r.events if e["type"] == "revoked")
    assert f"the {limit} boundary" in rev["reason_detail"]["text"], rev["reason_detail"]["text"]
    assert r.metrics["max_fence_breach_m"] == 0.0 and r.metrics["min_fence_margin_m"] > 0.0
    h = -r.log["truth_d"]
    k = _row(r.log, rev["t"])
    if limit == "ceiling":
        assert h.max() < CEILING_M and h[k] - h[0] > 20.0  # it did climb towards the ceiling
    else:
        assert h.min() > FLOOR_M and h[0] - h[k] > 20.0
        assert h[-1] > h[k]  # climbing back to the RTL height


def test_guidance_alone_turns_into_the_notch() -> None:
    """Why the escape turn exists: without it the RTL guidance turns the short way home, into the notch.
    (Guidance alone: the keep-out-aware route, which would also avoid the notch, is off too; see below.)"""
    sc = notch_case(FENCE_PARAMS, 22.0)
    cfg = resolve_config(sc, SCENARIOS, "<generated>")
    loop = FixedWingLoop(sc, cfg, sc.name, escape_turns=False, rtl_routes=False)
    r = run_scenario(sc, cfg, source=sc.name, loop=loop)
    assert r.metrics["max_fence_breach_m"] > 20.0


def test_the_rtl_route_alone_keeps_out_of_the_notch() -> None:
    """The same case without the escape turn but with RTL's route (merlin.autopilot.fixedwing_route): the
    route starts with the turn the aircraft must fly (a Dubins start) and keeps out of the notch."""
    sc = notch_case(FENCE_PARAMS, 22.0)
    cfg = resolve_config(sc, SCENARIOS, "<generated>")
    loop = FixedWingLoop(sc, cfg, sc.name, escape_turns=False)
    r = run_scenario(sc, cfg, source=sc.name, loop=loop)
    assert any(e["type"] == "fixed_wing_rtl_route" for e in r.events)
    assert r.metrics["max_fence_breach_m"] == 0.0


#: All 40 runs of the sweep fly in the suite (about 90 s of one core; docs/fixed-wing.md, "The fence sweep").
SWEEP = [("course", c, v) for c in COURSES_DEG for v in SPEEDS_MPS] + [
    ("corner", c, v) for c in COURSES_DEG for v in SPEEDS_MPS if corner_case(FENCE, c, v) is not None]


@pytest.mark.slow
@pytest.mark.parametrize(("kind", "course_deg", "speed_mps"), SWEEP,
                         ids=[f"{k}_{int(c)}deg_{int(v)}mps" for k, c, v in SWEEP])
def test_fence_sweep_every_30_degrees_has_no_breach(kind: str, course_deg: float, speed_mps: float) -> None:
    """Courses 0-330 deg in 30 deg steps at cruise and maximum speed: from home to whichever side of the
    range the course meets (the notch's bottom at 0 deg), and across the notch's re-entrant corner from
    every direction the allowed area offers. Zero breach in every run (docs/fixed-wing.md)."""
    sc = course_case(FENCE, course_deg, speed_mps) if kind == "course" else corner_case(FENCE, course_deg, speed_mps)
    assert sc is not None
    r = run_scenario(sc, resolve_config(sc, SCENARIOS, "<generated>"), source=sc.name)
    _expectations_pass(r)
    assert r.metrics["max_fence_breach_m"] == 0.0


@pytest.mark.parametrize("name", ["fw_fence_ceiling_22mps", "fw_fence_ceiling_30mps", "fw_fence_floor_22mps",
                                  "fw_fence_floor_30mps"])
def test_shipped_altitude_files_are_the_generated_cases(name: str) -> None:
    """The altitude YAML files are exactly altitude_case's 4 m/s cases (the parametrised runs stand for them)."""
    sc, _cfg = load_scenario(SCENARIOS / f"{name}.yaml")
    limit, speed = name.removeprefix("fw_fence_").split("_")
    assert sc.model_dump() == altitude_case(FENCE_PARAMS, limit, float(speed.removesuffix("mps"))).model_dump()


@pytest.mark.parametrize("name", ["fw_fence_0deg_22mps", "fw_fence_60deg_30mps", "fw_fence_notch_22mps"])
def test_shipped_fence_files_are_the_generated_cases(name: str) -> None:
    """The representative YAML files are exactly the sweep's cases (so the sweep's runs stand for them)."""
    sc, _cfg = load_scenario(SCENARIOS / f"{name}.yaml")
    _, rest = name.removeprefix("fw_fence_").split("_")
    kind = name.removeprefix("fw_fence_").split("_")[0]
    speed = float(rest.removesuffix("mps"))
    gen: Scenario = (notch_case(FENCE_PARAMS, speed) if kind == "notch"
                     else approach_case(FENCE_PARAMS, float(kind.removesuffix("deg")), speed))
    assert sc.model_dump() == gen.model_dump()


# -------------------------------------------------------------------------------------------------- lap


def test_seed_004_lap_two_laps_clockwise_through_the_closed_loop() -> None:
    """Table 6.1 of the seed FCU thesis: 500 m square, 160 m, 22 m/s, clockwise, two laps, by Merlin's
    trusted MISSION behaviour; height within 10 m and airspeed within 2 m/s after capture."""
    r = _run_file("fw_lap.yaml")
    _expectations_pass(r)
    log = r.log
    t, h, v = log["t"], -log["truth_d"], log["env_airspeed_mps"]
    captured = np.flatnonzero((np.abs(h - 160.0) < 2.0) & (np.abs(v - 22.0) < 0.5))
    assert captured.size and t[captured[0]] < 30.0
    c = captured[0]
    assert np.abs(h[c:] - 160.0).max() <= 10.0
    assert np.abs(v[c:] - 22.0).max() <= 2.0
    # the corners, in order, twice (L1 cuts each corner by its turn anticipation: within 60 m)
    corners = [(500.0, 0.0), (500.0, 500.0), (0.0, 500.0), (0.0, 0.0)] * 2
    i = 0
    for n, e in zip(log["truth_n"], log["truth_e"], strict=True):
        if i < len(corners) and math.hypot(n - corners[i][0], e - corners[i][1]) < 60.0:
            i += 1
    assert i == len(corners)
    # clockwise: the heading turns right by 90 deg at each of the seven corners between the eight legs
    # (the last one still under way at the end of the run)
    turned = math.degrees(float(np.unwrap(log["truth_yaw"])[-1] - log["truth_yaw"][0]))
    assert turned > 560.0


def test_corner_approach_in_wind_escapes_on_the_side_that_stays_inside() -> None:
    """fw_fence_corner_wind.yaml, from the fixed-wing fence campaign: a 23.8 m/s approach
    to the south-west corner in a 2.9 m/s wind. It breached by 50 m when the escape side was chosen by
    free path first; now the left turn is flown and the range holds with a wide margin from the revocation
    on. (The whole run's least margin is the experimental controller's pass by the mast before it, 9.6 m
    since TECS reads the airspeed's rate in wind, 22.8 m before: its track there is the flyaway's, not
    Merlin's escape.)"""
    r = _run_file("fw_fence_corner_wind.yaml")
    _expectations_pass(r)
    turns = [e for e in r.events if e["type"] == "fixed_wing_escape_turn"]
    assert turns and turns[0]["side"] == "left"
    assert turns[0]["right_free_path_m"] > turns[0]["left_free_path_m"]
    t_rev = next(e["t"] for e in r.events if e["type"] == "revoked")
    after = np.asarray(r.log["t"]) >= t_rev
    assert r.metrics["max_fence_breach_m"] == 0.0 and np.asarray(r.log["fence_margin"])[after].min() > 10.0


# ------------------------------------------------------------------------------------ RTL around keep-outs

MAST_NE_M, MAST_R_M = (-350.0, -350.0), 60.0  # the campaign range's exclusion circle


@pytest.mark.parametrize("name", ["fw_rtl_keepout_climb.yaml", "fw_rtl_keepout_descend.yaml"])
def test_rtl_routes_around_the_keep_out_and_reaches_home(name: str) -> None:
    """Without routing, RTL after the revocation flies L1 straight home through the mast's exclusion circle
    (56.9 m and 6.85 m deep). The route now passes it with room and joins the loiter."""
    r = _run_file(name)
    _expectations_pass(r)
    assert r.metrics["max_fence_breach_m"] == 0.0
    routes = [e for e in r.events if e["type"] == "fixed_wing_rtl_route"]
    assert routes and routes[0]["status"] == "routed"
    rev = next(e for e in r.events if e["type"] == "revoked")
    k = _row(r.log, rev["t"])
    n, e = r.log["truth_n"][k:], r.log["truth_e"][k:]
    to_mast = np.hypot(n - MAST_NE_M[0], e - MAST_NE_M[1]) - MAST_R_M
    # planned for 120-126 m; a route planned from deep inside that clearance keeps only part of it, so the escape
    # hands over to the route while the aircraft is still a full clearance from every hazard (123 m measured;
    # docs/fixed-wing.md, "RTL around keep-out zones")
    assert to_mast.min() > 30.0
    # on the loiter circle over home at the end (radius 120 m)
    assert abs(r.metrics["final_distance_from_home_m"] - 120.0) < 10.0


def test_a_fence_trip_under_trusted_authority_starts_one_escape_turn_per_trip() -> None:
    """Nothing is left to revoke under trusted authority (the core's rule is RTL again), but the stage still
    turns away: a horizontal trip starts the escape turn, once, re-armed after 1 s of a clear monitor; a
    ceiling trip is left to the behaviour's height."""
    from merlin.autopilot.fixedwing_behaviours import TRIP_REARM_S
    from merlin.core.types import (
        Authority,
        Behavior,
        Command,
        CommandKind,
        Decision,
        MonitorStatus,
        Reason,
        ReasonCode,
        VehicleState,
    )

    sc, cfg = load_scenario(SCENARIOS / "fw_rtl_keepout_descend.yaml")
    loop = FixedWingLoop(sc, cfg, "<test>")
    # 120 m north of the south wall, heading south at 22 m/s
    s = VehicleState(pos_ned_m=(-580.0, 0.0, -100.0), vel_ned_mps=(-22.0, 0.0, 0.0),
                     att_rpy_rad=(0.0, 0.0, math.pi), airspeed_mps=22.0)

    def decision(kind: str | None) -> Decision:
        mon = (MonitorStatus("geofence", False) if kind is None else
               MonitorStatus("geofence", True, Reason(ReasonCode.GEOFENCE, "geofence", kind, 1.0, 0.0, 0.0, "test")))
        return Decision(0.0, Authority.TRUSTED, Behavior.RTL, Command(CommandKind.VELOCITY, Authority.TRUSTED),
                        (mon,), (), True)

    stage = loop.stage
    stage.escape_on_trusted_trip(10.0, decision("inclusion"), s)
    assert stage.escape_side != 0.0
    note = stage.notes[-1]
    assert note["type"] == "fixed_wing_escape_turn" and note["under"] == "trusted"
    stage.escape_side = 0.0  # the turn ended (the monitor still tripped): no second turn for the same trip
    stage.escape_on_trusted_trip(10.1, decision("inclusion"), s)
    assert stage.escape_side == 0.0
    stage.escape_on_trusted_trip(10.2, decision(None), s)  # clear, but not for long enough
    stage.escape_on_trusted_trip(10.2 + 0.5 * TRIP_REARM_S, decision("exclusion"), s)
    assert stage.escape_side == 0.0
    stage.escape_on_trusted_trip(11.0, decision(None), s)
    stage.escape_on_trusted_trip(11.0 + TRIP_REARM_S, decision(None), s)
    stage.escape_on_trusted_trip(11.1 + TRIP_REARM_S, decision("ceiling"), s)  # a ceiling trip: no turn
    assert stage.escape_side == 0.0
    stage.escape_on_trusted_trip(11.2 + TRIP_REARM_S, decision("exclusion"), s)  # a new horizontal trip
    assert stage.escape_side != 0.0
