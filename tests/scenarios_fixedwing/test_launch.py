"""The catapult: a fixed-wing scenario that starts on the ground rests on its launcher until the trusted core
flies TAKEOFF, then climbs out at cruise speed to the takeoff height and holds (``sims/fixedwing_loop.py``),
with the built-in configuration ``merlin serve --vehicle aerosonde`` uses; and that command's options."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest

from merlin.config.loader import ConfigError
from sims.fixedwing_loop import LAUNCH_RELEASE_HEIGHT_M, default_config
from sims.runner import RunResult, run_scenario
from sims.scenario import Scenario

LAUNCH_T_S = 3.0
ROOT = Path(__file__).resolve().parents[2]


@cache
def _launch_run() -> RunResult:
    sc = Scenario.model_validate({
        "name": "fw_launch", "duration_s": 40.0, "dt_s": 0.01, "vehicle": "aerosonde", "log_rate_hz": 10.0,
        "initial": {"pos_ned_m": [0.0, 0.0, 0.0], "yaw_deg": 30.0},
        "gcs": [{"t": 1.0, "command": "arm"}, {"t": LAUNCH_T_S, "command": "takeoff"}],
    })
    return run_scenario(sc, default_config())


def _at(r: RunResult, col: str, t: float) -> float:
    k = min(int(np.searchsorted(r.log["t"], t - 1e-9)), len(r.log["t"]) - 1)
    return float(r.log[col][k])


def test_the_fixed_wing_rests_on_the_catapult_until_takeoff_then_climbs_out_and_holds() -> None:
    r = _launch_run()
    launch = [e for e in r.events if e["type"] == "fixed_wing_launch"]
    assert len(launch) == 1 and launch[0]["t"] == pytest.approx(LAUNCH_T_S)
    assert launch[0]["height_m"] == pytest.approx(LAUNCH_RELEASE_HEIGHT_M, abs=0.01)
    assert launch[0]["airspeed_mps"] == pytest.approx(22.0, abs=0.01)
    # at rest on the launcher, armed, before the launch
    assert _at(r, "armed", 2.0) == 1.0 and _at(r, "landed", 2.0) == 1.0
    assert (_at(r, "truth_n", 2.0), _at(r, "truth_e", 2.0), _at(r, "truth_d", 2.0)) == (0.0, 0.0, 0.0)
    assert _at(r, "m3", 2.0) == 0.0  # motor off
    # climbing out along the launch heading at cruise speed, motor running
    assert -_at(r, "truth_d", 10.0) > 20.0
    assert _at(r, "env_airspeed_mps", 10.0) == pytest.approx(22.0, abs=2.0)
    assert _at(r, "m3", 10.0) > 0.5
    heading = np.degrees(np.arctan2(_at(r, "truth_e", 10.0), _at(r, "truth_n", 10.0)))
    assert heading == pytest.approx(30.0, abs=3.0)
    # the takeoff completes at the built-in 60 m and the core makes it HOLD; nothing trips on the way
    behaviours = [e["behavior"] for e in r.events if e["type"] == "behavior"]
    assert behaviours == ["IDLE", "TAKEOFF", "HOLD"] or behaviours == ["TAKEOFF", "HOLD"], behaviours
    assert -_at(r, "truth_d", 39.0) == pytest.approx(60.0, abs=3.0)
    assert not [e for e in r.events if e["type"] == "monitor_tripped" and e.get("monitor") == "geofence"]
    assert r.metrics["max_fence_breach_m"] == 0.0


def test_the_fusion_ekf_flies_the_launch_started_again_in_the_air_at_the_release() -> None:
    """The default estimator, the fusion EKF, aligned on the rail and started again GPS-aided at the release
    (the stroke is not simulated): it navigates on GPS through the launch, no fix is rejected (the rail's
    fixes that arrive after the release are not handed to it), and the estimate follows the climb-out."""
    r = _launch_run()
    assert r.scenario.estimator == "ekf"
    assert not [e for e in r.events if e["type"].startswith("nav_") and e["type"] != "nav_mode"], [
        e for e in r.events if e["type"].startswith("nav_")]
    t = np.asarray(r.log["t"])
    after = t >= LAUNCH_T_S
    assert (np.asarray(r.log["nav_mode"])[after] == 0).all()  # NavMode.GPS
    err = np.hypot(np.asarray(r.log["est_n"]) - r.log["truth_n"], np.asarray(r.log["est_e"]) - r.log["truth_e"])
    assert err[after].max() < 3.0  # the receiver's wander (1 m sigma) and the release's first seconds
    assert np.abs(np.asarray(r.log["est_d"]) - r.log["truth_d"])[after].max() < 2.0


def test_a_start_just_above_the_ground_is_refused_with_the_catapult_named() -> None:
    sc = Scenario.model_validate({"name": "low", "duration_s": 1.0, "dt_s": 0.01, "vehicle": "aerosonde",
                                  "initial": {"pos_ned_m": [0.0, 0.0, -5.0]}})
    with pytest.raises(ConfigError, match="catapult"):
        run_scenario(sc, default_config())


def _options(*argv: str) -> object:
    import argparse

    from merlin.commands import serve

    parser = argparse.ArgumentParser()
    serve.register(parser.add_subparsers())
    return serve.options_from_args(parser.parse_args(["serve", *argv]))


def test_serve_options_choose_the_fixed_wing_and_its_configuration() -> None:
    from merlin.config.loader import ConfigError

    opts = _options("--vehicle", "aerosonde")
    assert opts.vehicle == "aerosonde"  # type: ignore[attr-defined]
    cfg = opts.config  # type: ignore[attr-defined]
    assert cfg.vehicle.type.value == "fixed_wing" and cfg.geofence.altitude_floor_m is None
    assert _options().vehicle == "quadrotor_default"  # type: ignore[attr-defined]
    with pytest.raises(ConfigError, match="fixed_wing"):
        _options("--vehicle", "aerosonde", "--config", str(ROOT / "examples" / "configs" / "default.yaml"))
    with pytest.raises(ConfigError, match="no such vehicle"):
        _options("--vehicle", "bogus")
    fw = _options("--vehicle", "aerosonde", "--config", str(ROOT / "examples" / "configs" / "fixedwing_default.yaml"))
    assert fw.config.geofence.altitude_floor_m == 30.0  # type: ignore[attr-defined]


def test_a_takeoff_height_just_under_the_ceilings_margin_is_still_reached() -> None:
    """Merlin's behaviours fly the height first within two fence margins of the ceiling (no speed traded for
    height), but still climb to their own height: with the ceiling 8 m above the built-in 60 m take-off
    height (inside that band, and admitted by XC007: under the ceiling less its 5 m margin) the take-off
    completes and the core makes it HOLD, without tripping the ceiling."""
    cfg = default_config()
    assert cfg.geofence is not None
    fence = cfg.geofence.model_copy(update={"altitude_ceiling_m": cfg.trusted.takeoff_altitude_m + 8.0})
    cfg = cfg.model_copy(update={"geofence": fence})
    sc = Scenario.model_validate({
        "name": "fw_launch_low_ceiling", "duration_s": 45.0, "dt_s": 0.01, "vehicle": "aerosonde",
        "log_rate_hz": 10.0, "initial": {"pos_ned_m": [0.0, 0.0, 0.0], "yaw_deg": 30.0},
        "gcs": [{"t": 1.0, "command": "arm"}, {"t": LAUNCH_T_S, "command": "takeoff"}],
    })
    r = run_scenario(sc, cfg)
    behaviours = [e["behavior"] for e in r.events if e["type"] == "behavior"]
    assert behaviours[-2:] == ["TAKEOFF", "HOLD"], behaviours
    assert r.metrics["max_fence_breach_m"] == 0.0
