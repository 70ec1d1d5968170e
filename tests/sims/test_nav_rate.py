"""The IMU voter and the fusion EKF at a period of several ticks (a scenario's ``nav_dt_s``): they run on every
``nav_every``-th tick on the IMU lanes down-sampled since their last tick and the other sensors' newest
samples; the output predictor gives the state on every tick, and the inner loops keep reading each tick's
raw IMU lanes. Faults are still caught, in the same time; a setting that cannot be flown is refused naming
the field."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import sims.runner as runner
from merlin.config.loader import ConfigError
from merlin.config.models import MerlinConfig
from sims.expectations import evaluate_all
from sims.runner import RunResult, run_scenario
from sims.scenario import Scenario, load_scenario

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "examples" / "scenarios"


class FilterSpy:
    """The fusion stage's filter ticks and the voter's votes, with the time of each (stand-ins around the
    real stages: a compiled stage's methods cannot be replaced)."""

    def __init__(self, loop: Any) -> None:
        self.filter_t: list[float] = []
        self.vote_t: list[float] = []
        loop.tick.estimator = _Stage(loop.tick.estimator, self.filter_t)
        if loop.tick.voter is not None:
            loop.tick.voter = _Voter(loop.tick.voter, self.vote_t)


class _Stage:
    def __init__(self, stage: Any, times: list[float]) -> None:
        self.stage, self.times = stage, times

    def estimate(self, t: float, frame: Any, voted: Any) -> Any:
        raise AssertionError("with nav_dt_s the tick calls filter_tick and propagate, not estimate")

    def filter_tick(self, t: float, frame: Any, voted: Any, clips: tuple[Any, ...] = ()) -> None:
        self.times.append(t)
        self.stage.filter_tick(t, frame, voted, clips)

    def propagate(self, t: float, frame: Any, isolated: tuple[bool, ...]) -> Any:
        return self.stage.propagate(t, frame, isolated)


class _Voter:
    def __init__(self, voter: Any, times: list[float]) -> None:
        self.voter, self.times = voter, times

    def vote(self, t: float, frame: Any) -> Any:
        self.times.append(t)
        return self.voter.vote(t, frame)


def _fly(sc: Scenario, cfg: MerlinConfig | None = None, spy: bool = False) -> tuple[RunResult, FilterSpy | None]:
    cfg = cfg if cfg is not None else MerlinConfig()
    loop = runner.make_loop(sc, cfg)
    s = FilterSpy(loop) if spy else None
    return run_scenario(sc, cfg, loop=loop), s


def _shipped(name: str, **update: Any) -> tuple[Scenario, MerlinConfig]:
    sc, cfg = load_scenario(SCENARIOS / f"{name}.yaml")
    return sc.with_fields(**update), cfg


def _failed(sc: Scenario, result: RunResult) -> list[Any]:
    return [v for v in evaluate_all(sc.expectations, result.events, result.log, result.metrics) if not v.passed]


def _horizontal_error(result: RunResult) -> np.ndarray:
    log = result.log
    return np.hypot(log["est_n"] - log["truth_n"], log["est_e"] - log["truth_e"])


def test_the_voter_and_the_filter_run_on_every_kth_tick_and_the_state_moves_on_every_tick() -> None:
    sc = Scenario.model_validate({
        "name": "nav_rate", "duration_s": 4.0, "seed": 3, "camera": None, "estimator": "ekf", "nav_dt_s": 0.01,
        "gcs": [{"t": 0.5, "command": "arm"}, {"t": 1.0, "command": "takeoff", "param": 5}]})
    assert sc.nav_every == 4
    result, spy = _fly(sc, spy=True)
    assert spy is not None
    n = round(sc.duration_s / sc.dt_s)
    ticks = [k * sc.dt_s for k in range(0, n, 4)]
    assert spy.filter_t == ticks and spy.vote_t == ticks
    # between the filter's ticks the estimate is the predictor's, moving with the vehicle: in the climb no two
    # logged heights in a row are equal
    climb = (result.log["t"] > 2.0) & (result.log["t"] < 3.0)
    assert np.all(np.diff(result.log["est_d"][climb]) != 0.0)


@pytest.mark.parametrize("name", ["nominal", "gps_jump_20m", "gps_spoof_1mps", "imu_stuck_isolated",
                                  "imu_second_fault_duplex", "fw_gps_jump_ekf", "fw_imu_stuck_ekf"])
def test_a_shipped_scenario_meets_its_expectations_with_the_filter_at_100_hz(name: str) -> None:
    """The failsafes that read the navigation stack (GPS jump rejection, spoof detection with VO, an IMU lane
    stuck and isolated, a second IMU fault in duplex, and the fixed wing's) with the voter and the filter at
    100 Hz, the trusted core too: a quarter of the multirotor's tick rate, half the fixed wing's."""
    sc, cfg = _shipped(name, nav_dt_s=0.01, core_dt_s=0.01)
    result, _ = _fly(sc, cfg)
    failed = _failed(sc, result)
    assert not failed, failed


def test_the_estimate_at_100_hz_stays_within_a_tenth_of_the_every_tick_error() -> None:
    """Nominal flight: the position estimate's error against the truth with the filter at 100 Hz is within
    10 % of the filter at every tick (RMS and largest over the flight)."""
    sc, cfg = _shipped("nominal", camera=None)
    every, _ = _fly(sc, cfg)
    quarter, _ = _fly(sc.with_fields(nav_dt_s=0.01), cfg)
    e1, e4 = _horizontal_error(every), _horizontal_error(quarter)
    assert np.sqrt(np.mean(e4 ** 2)) <= 1.1 * np.sqrt(np.mean(e1 ** 2))
    assert e4.max() <= 1.1 * e1.max()


def test_a_stuck_imu_lane_is_isolated_as_soon_as_at_every_tick() -> None:
    """The voter's stuck-sample count is scaled to its period (merlin.redundancy.lanes.voter_specs): a lane
    stuck at 100 Hz is isolated within one filter period of when it is at every tick, not four times later."""
    def isolated_at(sc: Scenario, cfg: MerlinConfig) -> float:
        result, _ = _fly(sc, cfg)
        times = [e["t"] for e in result.events if e["type"] == "imu_isolated"]
        assert times, [e["type"] for e in result.events][:40]
        return float(times[0])

    sc, cfg = _shipped("imu_stuck_isolated")
    t1 = isolated_at(sc, cfg)
    t4 = isolated_at(sc.with_fields(nav_dt_s=0.01), cfg)
    assert abs(t4 - t1) <= 0.01 + 1e-9


def _own_lanes(nav_dt_s: float | None, duration_s: float = 1.0, faults: list[Any] | None = None) -> Scenario:
    """Three autopilot lanes, each on its own IMU, magnetometer, barometer and GPS with its own filter."""
    return Scenario.model_validate({
        "name": "own_lanes_rate", "duration_s": duration_s, "seed": 7, "camera": None, "estimator": "ekf",
        "nav_dt_s": nav_dt_s, "faults": faults or [],
        "redundancy": {"autopilot_lanes": 3, "sensor_lanes": 3, "lane_navigation": "own"},
        "gcs": [{"t": 0.5, "command": "arm"}, {"t": 1.0, "command": "takeoff", "param": 8}]})


@pytest.mark.parametrize(("nav_dt_s", "every"), [(0.01, 4), (None, 1)])
def test_with_a_filter_per_lane_the_voter_votes_at_their_period_on_the_frame_they_ran_on(
        nav_dt_s: float | None, every: int) -> None:
    """With ``lane_navigation: own`` the voter votes after the core; at a filter period of several ticks it
    votes once per period, on the frame the lanes' filters took (its clock, the IMU samples' time of
    validity, is that frame's), and between its votes the autopilot lanes read each tick's raw IMU lanes.
    At every tick it votes every tick on the raw frame."""
    from merlin.pipeline import InputBuilder

    sc = _own_lanes(nav_dt_s)
    assert sc.nav_every == every
    loop = runner.make_loop(sc, MerlinConfig())
    red = loop.redundancy
    voter = red.voter.suite.imu.voter
    votes = 0
    last = voter.state.t_s
    for k in range(160):
        state = loop.sense()
        taken = red.lane_nav.taken
        assert (taken is not None) == (every > 1 and k % every == 0)
        inputs = InputBuilder().build(state, (), loop.redundancy_report(loop.t)) if loop.core_due else None
        frame = loop.frame
        loop.act(inputs)
        if voter.state.t_s != last:
            votes += 1
            last = voter.state.t_s
            assert k % every == 0
            assert voter.state.t_s == (taken if every > 1 else frame).imu[0].t_s
    assert votes == 160 // every


def test_with_a_filter_per_lane_a_stuck_imu_lane_is_isolated_as_soon_as_at_every_tick() -> None:
    """The voter after the lanes' own filters votes their down-sampled lanes at their period, with its
    stuck-sample count scaled to it: a stuck lane is isolated within one period of when it is at every tick."""
    def isolated_at(nav_dt_s: float | None) -> float:
        sc = _own_lanes(nav_dt_s, 4.0, [{"type": "imu_stuck", "start_s": 2.5, "lane": 2}])
        result, _ = _fly(sc)
        times = [e["t"] for e in result.events if e["type"] == "imu_isolated" and e.get("lane") == 2]
        assert times, [e["type"] for e in result.events][:40]
        return float(times[0])

    t1, t4 = isolated_at(None), isolated_at(0.01)
    assert 2.5 < t1 < 2.7
    assert abs(t4 - t1) <= 0.01 + 1e-9


@pytest.mark.parametrize(("text", "needle"), [
    ("nav_dt_s: 0.006\n", "whole number"),
    ("nav_dt_s: 0.05\n", "nav_dt_s"),
    ("nav_dt_s: 0.01\nestimator: truth_plus_noise\ncamera: null\n", "estimator"),
])
def test_a_filter_period_that_cannot_be_flown_is_refused_naming_file_field_and_value(
        tmp_path: Path, text: str, needle: str) -> None:
    path = tmp_path / "odd_nav.yaml"
    path.write_text("name: odd_nav\nduration_s: 2\ndt_s: 0.0025\n" + text, encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        load_scenario(path)
    msg = str(err.value)
    assert "odd_nav.yaml" in msg and "nav_dt_s" in msg and needle in msg
