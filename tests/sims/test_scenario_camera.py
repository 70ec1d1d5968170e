"""The camera by default: on where the terrain lets visual odometry work, off elsewhere, and said so."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from merlin.config.loader import ConfigError
from sims.scenario import CAMERA_TERRAINS, Camera, Scenario, camera_statement, load_scenario


def scenario(**fields: Any) -> Scenario:
    return Scenario.model_validate({"name": "cam", "duration_s": 5.0, **fields})


@pytest.mark.parametrize("terrain", CAMERA_TERRAINS)
def test_with_the_ekf_over_textured_terrain_the_camera_is_on(terrain):
    sc = scenario(estimator="ekf", terrain=terrain)
    assert sc.camera == Camera(texture=terrain)
    assert camera_statement(sc).startswith(f"on: downward camera over {terrain}, 160x120 at 15 frames/s")


def test_the_terrain_defaults_to_grass_and_auto_is_the_default():
    assert scenario(estimator="ekf").camera == Camera(texture="grass")
    assert scenario(estimator="ekf", camera="auto") == scenario(estimator="ekf")


@pytest.mark.parametrize(("fields", "reason"), [
    ({"estimator": "ekf", "terrain": "water"}, "off: terrain water"),
    ({"estimator": "ekf", "terrain": "tiles"}, "off: terrain tiles"),
    ({"estimator": "truth_plus_noise"}, "off: estimator truth_plus_noise"),
    ({"estimator": "ekf", "vehicle": "aerosonde"}, "off: no camera is modelled on the fixed wing"),
    ({"estimator": "ekf", "redundancy": {"autopilot_lanes": 3, "lane_navigation": "own"}},
     "off: the autopilot lanes' own filters"),
    ({"estimator": "ekf", "camera": None}, "off: the scenario has none (camera: null)"),
], ids=["water", "tiles", "stand_in", "fixed_wing", "own_lanes", "null"])
def test_the_camera_is_off_where_it_cannot_work_and_the_summary_says_why(fields, reason):
    sc = scenario(**fields)
    assert sc.camera is None
    assert camera_statement(sc).startswith(reason)


def test_a_scenario_may_still_fly_a_camera_over_water():
    """gps_loss_water_land: the camera is there on purpose, to show VO saying it cannot see."""
    sc = scenario(estimator="ekf", camera={"texture": "water"})
    assert sc.ground == "water" and sc.camera is not None and sc.camera.texture == "water"
    assert "VO cannot track water" in camera_statement(sc)


def test_a_camera_without_a_texture_sees_the_terrain():
    sc = scenario(estimator="ekf", terrain="brick", camera={"rate_hz": 10})
    assert sc.camera == Camera(texture="brick", rate_hz=10)


def test_a_camera_texture_that_contradicts_the_terrain_is_refused(tmp_path: Path):
    p = tmp_path / "cam.yaml"
    p.write_text("name: cam\nduration_s: 5\nestimator: ekf\nterrain: grass\ncamera: {texture: brick}\n")
    with pytest.raises(ConfigError) as exc:
        load_scenario(p)
    assert "cam.yaml" in str(exc.value) and "'brick'" in str(exc.value) and "'grass'" in str(exc.value)


def test_every_shipped_multirotor_ekf_scenario_over_texture_flies_the_camera():
    """The shipped files follow the default: an EKF multirotor scenario over grass, gravel or brick has the
    camera unless it says ``camera: null``; the fixed wing and the own-lane scenarios never do."""
    root = Path(__file__).resolve().parents[2] / "examples" / "scenarios"
    seen = 0
    for p in sorted(root.glob("*.yaml")):
        sc, _ = load_scenario(p)
        if sc.estimator != "ekf":
            continue
        seen += 1
        if sc.vehicle == "aerosonde" or sc.redundancy.lane_navigation == "own":
            assert sc.camera is None, p.name
        elif sc.camera is None:
            assert camera_statement(sc).startswith("off: the scenario has none") and "camera: null" in p.read_text(), p.name
    assert seen >= 10
