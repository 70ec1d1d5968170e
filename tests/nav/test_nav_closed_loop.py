"""Visual odometry in the closed loop (sims/vision_loop.py), the navigation expectations and the nav page
of the run report."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from merlin.config.loader import ConfigError
from merlin.config.models import MerlinConfig
from merlin.core.types import NavMode
from merlin.measurements import ImuSample
from merlin.nav.estimator import NavEstimator, NavInit
from sims.expectations import evaluate
from sims.nav_report import distance_flown_m, plot_nav
from sims.runner import run_scenario
from sims.scenario import Camera, Expectation, Scenario, load_scenario, resolve_config
from sims.sensors import dipole_field_ned_gauss
from sims.vision_loop import MIN_RENDER_HEIGHT_M, VisionLoop, nav_filter_config, nominal_mission

DT = 0.0025


@dataclass(frozen=True)
class Truth:
    pos_ned_m: tuple[float, float, float]
    vel_ned_mps: tuple[float, float, float]
    rpy_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)


def hover_estimator(pos, vel) -> NavEstimator:
    return NavEstimator(init=NavInit(pos_ned_m=pos, vel_ned_mps=vel))


def fly_level(texture: str, height_m: float, vel=(3.0, 1.0, 0.0), seconds: float = 1.0, rate_hz: float = 15.0):
    """Constant velocity, level; the filter is fed a level IMU so its attitude and velocity stay put."""
    loop = VisionLoop(Camera(texture=texture, rate_hz=rate_hz), seed=5)
    p0 = (0.0, 0.0, -height_m)
    est = hover_estimator(p0, vel)
    samples = []
    for k in range(round(seconds / DT)):
        t = k * DT
        est.predict(ImuSample(t, (0.0, 0.0, 0.0), (0.0, 0.0, -9.80665)))
        truth = Truth((vel[0] * t, vel[1] * t, -height_m), vel)
        s = loop.step(t, truth, est)
        if s is not None:
            samples.append(s)
    return loop, samples


def test_frames_come_at_the_camera_rate_and_measure_the_ground_velocity():
    loop, samples = fly_level("grass", 20.0)
    assert len(samples) == 15  # 15 frames/s for 1 s
    valid = [s for s in samples if s.quality.valid]
    assert len(valid) >= 13  # the first frame only starts the tracker
    v = np.array([s.vel_ned_mps for s in valid])
    assert np.abs(v[:, :2] - (3.0, 1.0)).max() < 0.3
    assert loop.trace.frames == 15 and len(loop.trace.vo["t"]) == 15
    assert all(0.0 <= r < 0.5 for r in loop.trace.vo["repetition"] if not math.isnan(r))


def test_over_water_no_frame_is_valid_and_nothing_is_fused():
    loop, samples = fly_level("water", 20.0)
    assert samples and not any(s.quality.valid for s in samples)
    assert not any(loop.trace.vo["fused"])


def test_no_frames_on_the_ground():
    loop, samples = fly_level("grass", MIN_RENDER_HEIGHT_M * 0.5)
    assert samples == [] and loop.trace.frames == 0


def test_without_a_camera_only_the_gps_trace_is_kept():
    loop = VisionLoop(None, seed=1)
    est = hover_estimator((0.0, 0.0, -10.0), (0.0, 0.0, 0.0))
    assert loop.step(0.0, Truth((0.0, 0.0, -10.0), (0.0, 0.0, 0.0)), est) is None
    assert loop.trace.frames == 0


def test_filter_config_follows_the_core_limit_and_the_declination_at_home():
    cfg = MerlinConfig.model_validate({"name": "x", "nav": {"inertial_time_limit_s": 12.0}})
    nc = nav_filter_config(cfg)
    n, e, _ = dipole_field_ned_gauss(cfg.home.lat_deg, cfg.home.lon_deg)
    assert nc.inertial_time_limit_s == 12.0
    assert nc.mag_declination_rad == pytest.approx(math.atan2(e, n))


def test_a_camera_needs_the_ekf(tmp_path: Path):
    p = tmp_path / "cam.yaml"
    # the stand-in, by name (the EKF is the default, with which the camera is accepted)
    p.write_text("name: cam\nduration_s: 5\nestimator: truth_plus_noise\ncamera: {texture: grass}\n")
    with pytest.raises(ConfigError) as exc:
        load_scenario(p)
    assert "camera" in str(exc.value) and "cam.yaml" in str(exc.value)
    p.write_text("name: cam\nduration_s: 5\ncamera: {texture: grass}\n")
    assert load_scenario(p)[0].estimator == "ekf"
    p.write_text("name: cam\nduration_s: 5\nestimator: ekf\ncamera: {texture: marble}\n")
    with pytest.raises(ConfigError) as exc:
        load_scenario(p)
    assert "marble" in str(exc.value)


def _log(modes, err_m):
    n = len(modes)
    t = np.arange(n) * 0.1
    return {
        "t": t,
        "nav_mode": np.array([float(m) for m in modes]),
        "truth_n": np.zeros(n),
        "truth_e": np.zeros(n),
        "est_n": np.array(err_m, dtype=float),
        "est_e": np.zeros(n),
    }


def test_nav_expectations():
    log = _log([NavMode.GPS] * 5 + [NavMode.VO] * 5, [0.1] * 5 + [0.5, 1.0, 4.0, 1.0, 0.5])
    ok = evaluate(Expectation(type="nav_mode_at", t=0.7, nav_mode="vo"), [], log, {})
    assert ok.passed and "VO" in ok.detail
    assert not evaluate(Expectation(type="nav_mode_at", t=0.2, nav_mode="VO"), [], log, {}).passed
    bad = evaluate(Expectation(type="max_nav_error", m=3.0), [], log, {})
    assert not bad.passed and "4.00 m at t=0.70" in bad.detail
    assert evaluate(Expectation(type="max_nav_error", m=3.0, after_s=0.75), [], log, {}).passed
    assert evaluate(Expectation(type="max_nav_error", m=0.2, within_s=0.45), [], log, {}).passed


def test_distance_flown_is_the_path_length():
    log = {"truth_n": np.array([0.0, 3.0, 3.0, 0.0]), "truth_e": np.array([0.0, 0.0, 4.0, 4.0])}
    assert distance_flown_m(log).tolist() == [0.0, 3.0, 7.0, 10.0]


@pytest.mark.slow
def test_camera_in_the_closed_loop_feeds_the_filter(tmp_path: Path):
    """A short hover with the camera: VO is fused on nearly every frame, GPS stays admitted, the run
    report draws its navigation page."""
    sc = Scenario.model_validate({
        "name": "hover_cam", "duration_s": 9.0, "seed": 3, "estimator": "ekf",
        "camera": {"texture": "gravel", "rate_hz": 10},
        "gcs": [{"t": 0.5, "command": "arm"}, {"t": 1.0, "command": "takeoff", "param": 6}],
        "expectations": [{"type": "nav_mode_at", "t": 8.0, "nav_mode": "GPS"}],
    })
    r = run_scenario(sc, resolve_config(sc, tmp_path, "<test>"))
    vo = r.nav["vo"]
    assert r.nav["frames"] >= 60
    airborne = vo["t"] > 4.0
    assert vo["fused"][airborne].mean() > 0.9
    assert not [e for e in r.events if e["type"] == "nav_excluded"]
    assert evaluate(sc.expectations[0], r.events, r.log, r.metrics).passed
    png = plot_nav(r, tmp_path)
    assert png is not None and png.stat().st_size > 10_000


@pytest.mark.slow
def test_nominal_flight_over_brick_keeps_a_healthy_gps(tmp_path: Path):
    """The benchmark flight that falsely excluded GPS at 143.5 s (seed 3, brick; docs/benchmarks/nav.md,
    "Nominal flight"): its barometer drifts 0.7 m in two minutes, which scaled the VO velocity by 4 %
    while the filter published a height sigma of 0.05 m. With the baro bias state the height follows,
    the VO-aided velocity is not dragged and the window test stays far from its limit. ~25 s of CPU."""
    sc = nominal_mission(3, 2.5, "brick")
    r = run_scenario(sc, resolve_config(sc, tmp_path, "<test>"))
    assert r.log["t"][-1] > 149.0
    assert not [e for e in r.events if e["type"] == "nav_excluded"]
    g = r.nav["gps"]
    assert np.nanmax(g["window_cusum"]) < 6.0
    assert np.nanmax(g["vo_cusum"]) < 6.0
    air = r.log["landed"] < 0.5
    assert np.max(np.abs(r.log["est_d"] - r.log["truth_d"])[air]) < 0.4
