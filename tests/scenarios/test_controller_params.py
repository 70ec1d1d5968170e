"""The plug-in controllers' parameters, the scenario's seed and the campaign's options: values a file or a
command line can hold that no run can fly are refused by name before anything flies."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from experimental_controllers.api import ParamError
from experimental_controllers.examples import RollExceeder, WaypointTracker
from merlin.campaign.scheduler import CampaignOptions, run_campaign
from merlin.cli import main
from merlin.config.loader import ConfigError
from sims.scenario import SEED_MAX, load_scenario

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "examples" / "scenarios"


@pytest.mark.parametrize(("value", "where", "shown"), [
    (math.nan, "waypoints_ned_m[1][2]", "value nan"),
    (-math.inf, "waypoints_ned_m[1][2]", "value -inf"),
    (10**400, "waypoints_ned_m[1][2]", "value 100000000000... (401 digits)"),
], ids=["nan", "-inf", "401 digits"])
def test_a_number_inside_a_list_parameter_is_held_to_the_same_rule(value: float, where: str, shown: str) -> None:
    """A waypoint no float holds crashed the tracker's constructor unnamed (an int) or flew NaN setpoints
    (a NaN)."""
    wps = [[1.0, 0.0, -10.0], [2.0, 0.0, value]]
    with pytest.raises(ParamError) as err:
        WaypointTracker(waypoints_ned_m=wps)
    assert f"parameter {where} of controller 'waypoint_tracker': {shown}; allowed: finite numbers" in str(err.value)


def test_finite_waypoints_are_accepted_ints_included() -> None:
    assert WaypointTracker(waypoints_ned_m=[[1, 2, -10], [0.5, 0.0, -12.0]]).wps == [(1.0, 2.0, -10.0),
                                                                                    (0.5, 0.0, -12.0)]


@pytest.mark.parametrize("profile", [[], [[0.0, 0.0], [1.0]], [[0.0, 0.0], [0.0, 40.0]], [[1.0, 0.0], [0.5, 40.0]],
                                     [[0.0, "forty"]], [[0.0, True]]])
def test_a_roll_profile_that_cannot_be_interpolated_is_refused(profile: list) -> None:
    """An empty profile failed in the controller's step (an IndexError, seen as a missed heartbeat), and two
    keyframes at one time divide by zero between them."""
    with pytest.raises(ParamError, match=r"profile must be a non-empty list of \[t_after_start_s, roll_deg\]"):
        RollExceeder(profile=profile)


def test_a_roll_profile_interpolates_between_its_keyframes() -> None:
    c = RollExceeder(start_at_s=1.0, profile=[[0, 0], [2.0, 40.0]])
    assert c.roll_at(2.0) == pytest.approx(math.radians(20.0))
    assert c.roll_at(10.0) == pytest.approx(math.radians(40.0))


@pytest.mark.parametrize(("seed", "message"), [
    (-1, "greater than or equal to 0"), (SEED_MAX + 1, f"less than or equal to {SEED_MAX}"),
    (True, "seed: value true is true/false where a number is expected")])  # it flew seed 1
def test_a_scenario_seed_no_run_can_take_is_refused_with_its_line(tmp_path: Path, seed: int, message: str) -> None:
    """A negative seed crashed numpy's generator after the scenario loaded; one beyond int64 flew the whole run
    and then crashed the ULog's writer, losing the run's log."""
    data = yaml.safe_load((SCENARIOS / "nominal.yaml").read_text())
    data["seed"] = seed
    p = tmp_path / "seeded.yaml"
    p.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as err:
        load_scenario(p)
    text = str(err.value)
    assert "seeded.yaml" in text and "seed" in text and message in text


def test_the_largest_seed_loads() -> None:
    sc, _ = load_scenario(SCENARIOS / "nominal.yaml", seed=SEED_MAX)
    assert sc.seed == SEED_MAX


@pytest.mark.parametrize("seed", ["-1", str(SEED_MAX + 1)])
def test_a_seed_override_no_run_can_take_exits_2_naming_it(tmp_path: Path, capsys, seed: str) -> None:
    rc = main(["sim", str(SCENARIOS / "nominal.yaml"), "--seed", seed, "--out", str(tmp_path / "o"), "--no-plots",
               "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "nominal.yaml (--seed)" in err and f"seed: value {seed}; allowed: a whole number from 0 to" in err


@pytest.mark.parametrize(("options", "message"), [
    ({"seed": -1}, "--seed: must be in [0, 2^32), got -1"),
    ({"seed": 2**32}, "--seed: must be in [0, 2^32), got 4294967296"),  # it flew seed 0's runs
    ({"workers": -1}, "--workers: must be >= 0 (0: every core), got -1"),
    ({"runs": 0, "seed": -2}, "--runs: must be at least 1, got 0"),
])
def test_campaign_options_no_campaign_can_fly_are_refused_before_anything_flies(
        tmp_path: Path, options: dict[str, int], message: str) -> None:
    opts = CampaignOptions(scenarios=(), **{"runs": 2, "out": tmp_path / "c", **options})  # type: ignore[arg-type]
    with pytest.raises(ConfigError) as err:
        run_campaign(opts, [])
    assert message in str(err.value)
    assert not (tmp_path / "c").exists()


def test_campaign_keep_runs_below_zero_exits_2(tmp_path: Path, capsys) -> None:
    rc = main(["campaign", str(ROOT / "examples" / "campaigns" / "adversarial_crash.yaml"), "--runs", "1",
               "--keep-runs", "-1", "--out", str(tmp_path / "c"), "--quiet"])
    assert rc == 2
    assert "--keep-runs: must be >= 0, got -1" in capsys.readouterr().err
