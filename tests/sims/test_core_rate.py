"""The trusted core at a period of several ticks (a scenario's ``core_dt_s``): the physics, the sensors, the
filter and the inner loops keep the scenario's tick; the core runs on every ``core_every``-th tick, its
decision is flown on the ticks between, and what arrives between its ticks (the ground station's commands,
the controller's requests) waits for its next tick. Nothing may be lost, delivered twice or recorded twice,
the exceedance timers stay exact at the core's tick, and a period the fence's reaction time does not cover
is refused before the flight."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import sims.runner as runner
from merlin.commands.sim import preflight
from merlin.config.crosschecks import CrossCheckRefusal, run_checks
from merlin.config.loader import ConfigError
from merlin.config.models import MerlinConfig
from merlin.core.types import Decision, Inputs
from sims.expectations import evaluate_all
from sims.runner import RunResult, run_scenario, vehicle_capability
from sims.scenario import Scenario, load_scenario

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "examples" / "scenarios"


class CoreSpy:
    """The tick's core, recording each call: when it ran, what it was handed and what it decided."""

    def __init__(self, core: Any) -> None:
        self.core = core
        self.calls: list[tuple[float, Inputs, Decision]] = []

    def step(self, now: float, inputs: Inputs) -> Decision:
        d = self.core.step(now, inputs)
        self.calls.append((now, inputs, d))
        return d


def _fly(sc: Scenario, cfg: MerlinConfig | None = None) -> tuple[RunResult, CoreSpy]:
    cfg = cfg if cfg is not None else MerlinConfig()
    loop = runner.make_loop(sc, cfg)
    spy = CoreSpy(loop.tick.core)
    loop.tick.core = spy
    return run_scenario(sc, cfg, loop=loop), spy


def _scenario(**kw: Any) -> Scenario:
    base: dict[str, Any] = {
        "name": "core_rate", "duration_s": 6.0, "seed": 3, "camera": None,
        "gcs": [{"t": 0.5, "command": "arm"}, {"t": 1.0, "command": "takeoff", "param": 5}],
        "controller": {"type": "waypoint_tracker",
                       "params": {"request_at_s": 3.0, "waypoints_ned_m": [[5, 0, -5]], "release_at_end": False}},
    }
    base.update(kw)
    return Scenario.model_validate(base)


def _due_tick(t_s: float, dt: float, every: int) -> int:
    """The core's first tick at or after a command scripted at ``t_s`` (the script delivers it on the first
    simulation tick at or after ``t_s``; the core takes it on its first tick from there)."""
    k = math.ceil((t_s - 1e-9) / dt)
    return -(-k // every) * every


def test_the_core_runs_on_every_kth_tick_and_nowhere_else() -> None:
    sc = _scenario(core_dt_s=0.01)
    assert sc.core_every == 4
    result, spy = _fly(sc)
    n = round(sc.duration_s / sc.dt_s)
    assert [now for now, _, _ in spy.calls] == [k * sc.dt_s for k in range(0, n, 4)]
    # every tick is logged, the held ones with the held decision
    assert len(result.log["t"]) == round(sc.duration_s * sc.log_rate_hz)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(every=st.integers(1, 8), arm_t=st.floats(0.0, 0.6), takeoff_t=st.floats(0.0, 0.9),
       hold_t=st.floats(0.0, 1.5))
def test_each_ground_station_command_reaches_the_core_once_at_its_first_tick(
        every: int, arm_t: float, takeoff_t: float, hold_t: float) -> None:
    """Commands falling due between the core's ticks, several on one tick, some on the same tick as the core:
    each is in the inputs of exactly one core tick, the first at or after its time, in the script's order."""
    gcs = sorted([{"t": arm_t, "command": "arm"}, {"t": arm_t + takeoff_t, "command": "takeoff", "param": 4},
                  {"t": arm_t + takeoff_t + hold_t, "command": "hold"}], key=lambda g: g["t"])
    sc = _scenario(duration_s=3.0, core_dt_s=every * 0.0025, gcs=gcs, controller=None,
                   estimator="truth_plus_noise")
    _, spy = _fly(sc)
    delivered = [(round(now / sc.dt_s), c.seq) for now, inputs, _ in spy.calls for c in inputs.gcs_commands]
    assert [seq for _, seq in delivered] == [1, 2, 3]
    assert [k for k, _ in delivered] == [_due_tick(g["t"], sc.dt_s, every) for g in gcs]


def test_the_controllers_requests_and_the_core_events_are_neither_lost_nor_recorded_twice() -> None:
    every_tick, spy1 = _fly(_scenario(core_dt_s=None))
    quarter, spy4 = _fly(_scenario(core_dt_s=0.01))
    requests1 = [(r.kind, r.seq) for _, inputs, _ in spy1.calls for r in inputs.experimental.requests]
    requests4 = [(r.kind, r.seq) for _, inputs, _ in spy4.calls for r in inputs.experimental.requests]
    assert requests1 and requests4 == requests1
    for result, spy in ((every_tick, spy1), (quarter, spy4)):
        decided = [e.to_dict() for _, _, d in spy.calls for e in d.events]
        recorded = [e for e in result.events if e in decided]
        assert recorded == decided  # each of the core's events once, in order
    kinds4 = [e["type"] for _, _, d in spy4.calls for e in (x.to_dict() for x in d.events)]
    kinds1 = [e["type"] for _, _, d in spy1.calls for e in (x.to_dict() for x in d.events)]
    assert "granted" in " ".join(kinds4) and kinds4 == kinds1  # the same decisions, in kind and order


@pytest.mark.parametrize("name", ["figure5_delayed", "figure5_instant", "controller_crash", "fw_controller_crash",
                                  "fw_fence_0deg_22mps"])
def test_a_shipped_scenario_meets_its_expectations_with_the_core_at_100_hz(name: str) -> None:
    """Figure 5's exceedance timers (revoked after exactly the duration, to the core's tick), the heartbeat
    watchdog (revoked within its timeout plus one tick) and the fixed wing's fence, with the core at 100 Hz:
    a quarter of the multirotor's tick rate, half the fixed wing's."""
    sc, cfg = load_scenario(SCENARIOS / f"{name}.yaml")
    sc = sc.model_copy(update={"core_dt_s": 0.01})
    result, spy = _fly(sc, cfg)
    failed = [v for v in evaluate_all(sc.expectations, result.events, result.log, result.metrics) if not v.passed]
    assert not failed, failed
    core_times = {now for now, _, _ in spy.calls}
    revoked = [e for e in result.events if e["type"] == "revoked"]
    assert revoked and all(e["t"] in core_times for e in revoked)


def test_a_core_period_that_is_not_a_whole_number_of_ticks_is_refused_naming_file_field_and_value(
        tmp_path: Path) -> None:
    path = tmp_path / "odd_core.yaml"
    path.write_text("name: odd_core\nduration_s: 2\ndt_s: 0.0025\ncore_dt_s: 0.006\n", encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        load_scenario(path)
    text = str(err.value)
    assert "odd_core.yaml" in text and "core_dt_s" in text and "0.006" in text and "whole number" in text
    path.write_text("name: slow_core\nduration_s: 2\ncore_dt_s: 0.05\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="core_dt_s"):
        load_scenario(path)
    assert _scenario(core_dt_s=0.0025).core_every == 1 and _scenario(core_dt_s=None).core_every == 1


@pytest.mark.parametrize(("dt_s", "estimator", "core", "nav"), [
    (0.0025, "ekf", 0.01, 0.01),  # the multirotor's 400 Hz tick: four ticks, PX4's EKF2_PREDICT_US
    (0.005, "ekf", 0.01, 0.01),  # the fixed wing's 200 Hz: two
    (0.003, "ekf", 0.009, 0.009),  # rounded down to whole ticks, never up past 10 ms
    (0.01, "ekf", 0.01, 0.01),  # one tick
    (0.0025, "truth_plus_noise", 0.01, None),  # the stand-in has no filter to slow
])
def test_the_default_periods_are_10_ms_rounded_down_to_whole_ticks(
        dt_s: float, estimator: str, core: float, nav: float | None) -> None:
    for stated in ({}, {"core_dt_s": "auto", "nav_dt_s": "auto"}):
        sc = _scenario(dt_s=dt_s, estimator=estimator, **stated)
        assert sc.core_dt_s == pytest.approx(core) and (sc.nav_dt_s is None) == (nav is None)
        assert sc.core_every == round(core / dt_s)
        assert sc.nav_every == (1 if nav is None else round(nav / dt_s))
    # null is every tick, as before the default; a period given is kept as given
    sc = _scenario(dt_s=dt_s, estimator=estimator, core_dt_s=None, nav_dt_s=None)
    assert (sc.core_every, sc.nav_every) == (1, 1)
    assert _scenario(core_dt_s=0.02, nav_dt_s=0.005).core_dt_s == 0.02


def test_with_fields_keeps_out_what_the_scenario_left_out() -> None:
    """A scenario's ``redundancy`` section turns the core's ``nav_redundancy`` monitor on by being there
    (sims.vehicle_loop.core_source): a copy with another period must not add it."""
    sc = _scenario()
    assert "redundancy" not in sc.model_fields_set
    copy = sc.with_fields(core_dt_s=None)
    assert "redundancy" not in copy.model_fields_set and copy.core_every == 1 and copy.nav_every == 4
    assert not runner.make_loop(copy, MerlinConfig()).reports_redundancy
    red = _scenario(redundancy={"sensor_voter": True}).with_fields(nav_dt_s=None)
    assert "redundancy" in red.model_fields_set and red.nav_every == 1


def test_a_field_left_to_auto_is_resolved_again_for_a_copy() -> None:
    """``camera``, ``core_dt_s`` and ``nav_dt_s`` left to auto are resolved, not given: a copy that changes
    what they resolve from resolves them again, instead of carrying a period or a camera into a scenario
    that refuses it (an EKF scenario's filter period on the stand-in, a 10 ms period on a 3 ms tick)."""
    sc = _scenario(estimator="ekf", camera="auto")
    assert not {"camera", "core_dt_s", "nav_dt_s"} & sc.model_fields_set
    assert sc.nav_dt_s == 0.01 and sc.camera is not None
    stand_in = sc.with_fields(estimator="truth_plus_noise")
    assert (stand_in.nav_dt_s, stand_in.camera, stand_in.core_dt_s) == (None, None, 0.01)
    assert math.isclose(sc.with_fields(dt_s=0.003).core_dt_s or 0.0, 0.009)
    # what was given stays given, "auto" included as not given
    given = _scenario(estimator="ekf", core_dt_s=0.005, nav_dt_s="auto")
    assert "core_dt_s" in given.model_fields_set and "nav_dt_s" not in given.model_fields_set
    assert given.with_fields(estimator="truth_plus_noise").core_dt_s == 0.005


def test_the_fence_reaction_time_must_cover_the_cores_period() -> None:
    """XC005 with the driver's tick: a reaction time the vehicle's loops alone fit in, but not with a
    crossing seen one core tick late, is refused."""
    cap = vehicle_capability("quadrotor_default")
    assert cap is not None
    loops = cap.min_reaction_s(4.0)
    cfg = MerlinConfig.model_validate({"vehicle": {"reaction_time_s": round(loops + 0.006, 4)}})
    assert not [f for f in run_checks(cfg, vehicle=cap, core_period_s=0.0025) if f.check_id == "XC005"]
    found = [f for f in run_checks(cfg, vehicle=cap, core_period_s=0.01) if f.check_id == "XC005"]
    assert found and "10 ms tick" in found[0].text


def test_merlin_sim_refuses_a_core_period_the_default_reaction_time_does_not_cover() -> None:
    slow = _scenario(core_dt_s=0.02)
    with pytest.raises(CrossCheckRefusal, match="XC005"):
        preflight(slow, MerlinConfig(), "slow_core.yaml")
    preflight(_scenario(core_dt_s=0.01), MerlinConfig(), "core_100hz.yaml")  # 0.284 + 0.010 <= 0.3 s
