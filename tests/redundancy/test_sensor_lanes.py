"""Triplex magnetometer, barometer and GPS (``redundancy.sensor_lanes: 3``): three units of each, lane i
beside IMU i, per-lane faults, voted samples fed to the EKF, the redundancy level reported to the core,
and each autopilot lane on its own sensor lane with its own estimator (``lane_navigation: own``)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from pydantic import ValidationError

from merlin.config.models import MerlinConfig
from merlin.measurements import BaroSample, GpsSample, MagSample
from merlin.redundancy.lanes import LaneContext, LaneNavigation, channel_specs, lane_config
from merlin.redundancy.sensor_suite import VOTED_LANE, SensorSuiteVoter
from sims.runner import ClosedLoop, gps_loss_spans, run_scenario
from sims.scenario import Scenario
from sims.sensor_faults import BaroBias, BaroStuck, GpsStuck, MagBias, SensorDropout, SensorFaultInjector
from sims.sensors import SensorParams, SensorSuite

TAKEOFF = [{"t": 0.5, "command": "arm"}, {"t": 1.0, "command": "takeoff", "param": 6}]


class _Truth:
    t_s = 0.0
    pos_ned_m = (0.0, 0.0, -5.0)
    vel_ned_mps = (1.0, 0.0, 0.0)
    quat_wxyz = (1.0, 0.0, 0.0, 0.0)
    omega_frd_radps = (0.0, 0.0, 0.0)
    specific_force_frd_mps2 = (0.0, 0.0, -9.81)


def _frames(params: SensorParams, seconds: float, faults: list[Any] | None = None) -> list[Any]:
    suite = SensorSuite(params, np.random.default_rng(3))
    inj = SensorFaultInjector(faults or [], np.random.default_rng(4))
    out = []
    truth = _Truth()
    for k in range(round(seconds / 0.0025)):
        truth.t_s = k * 0.0025
        out.append(inj.apply(suite.step(truth)))
    return out


def test_three_units_keep_lane_0_and_the_imus_bit_identical_to_one_unit() -> None:
    one = _frames(SensorParams(), 2.0)
    three = _frames(SensorParams(aux_lanes=3), 2.0)
    for a, b in zip(one, three, strict=True):
        assert a.imu == b.imu and a.gps == b.gps and a.baro == b.baro and a.mag == b.mag
        assert not a.gps_lanes
        if b.baro is not None:
            assert [s.lane for s in b.baro_lanes] == [0, 1, 2]
            assert b.baro_lanes[0] is b.baro
            assert len({s.alt_m for s in b.baro_lanes}) == 3  # independent noise per unit
    assert sum(1 for f in three if f.gps_lanes and f.gps_lanes[2] is not None) > 10


def test_per_lane_faults_act_on_their_unit_only() -> None:
    faults = [
        GpsStuck(0.5, lane=1),
        BaroBias(0.5, 7.0, lane=2),
        MagBias(0.5, (0.3, 0.0, 0.0), lane=0),
        SensorDropout(0.5, "baro", lane=0),
        BaroStuck(1.0, lane=1),
    ]
    clean = _frames(SensorParams(aux_lanes=3), 2.0)
    bad = _frames(SensorParams(aux_lanes=3), 2.0, faults)
    gps1 = [
        f.gps_lanes[1].pos_ned_m for f in bad if f.t_s > 0.8 and f.gps_lanes and f.gps_lanes[1] is not None
    ]
    assert len(gps1) > 5 and len(set(gps1)) == 1  # frozen fix
    for c, b in zip(clean, bad, strict=True):
        if not b.gps_lanes or b.t_s < 0.5:
            continue
        if c.gps_lanes[0] is not None:
            assert b.gps_lanes[0] == c.gps_lanes[0] and b.gps_lanes[2] == c.gps_lanes[2]
        if c.baro_lanes[2] is not None:
            assert b.baro_lanes[0] is None  # dropout
            assert b.baro_lanes[2].alt_m == pytest.approx(c.baro_lanes[2].alt_m + 7.0)
        if c.mag_lanes[0] is not None:
            assert b.mag_lanes[0].field_frd_gauss[0] == pytest.approx(c.mag_lanes[0].field_frd_gauss[0] + 0.3)
            assert b.mag_lanes[1] == c.mag_lanes[1]
    baro1 = {
        f.baro_lanes[1].alt_m for f in bad if f.t_s > 1.05 and f.baro_lanes and f.baro_lanes[1] is not None
    }
    assert len(baro1) == 1


def test_voted_samples_carry_the_newest_time_of_validity() -> None:
    v = SensorSuiteVoter(np.random.default_rng(0))
    gps = tuple(
        GpsSample(0.89 + 0.001 * i, (1.0 + i * 0.1, 0.0, 0.0), (0.0, 0.0, 0.0), 3, 12, lane=i)
        for i in range(3)
    )
    baro = tuple(BaroSample(0.99, 5.0 + 0.01 * i, i) for i in range(3))
    mag = tuple(MagSample(0.99, (0.2, 0.0, 0.4), i) for i in range(3))
    out = v.step(1.0, (None, None, None), mag, baro, gps)
    assert out.gps is not None and out.gps.t_s == pytest.approx(0.892) and out.gps.lane == VOTED_LANE
    assert out.gps.pos_ned_m[0] == pytest.approx(1.1) and out.baro is not None and out.baro.t_s == 0.99


def test_a_fault_on_a_unit_the_airframe_lacks_is_refused() -> None:
    with pytest.raises(ValidationError, match="lane 2 does not exist"):
        Scenario.model_validate(
            {"name": "x", "duration_s": 1, "faults": [{"type": "gps_stuck", "start_s": 0.5, "lane": 2}]}
        )
    with pytest.raises(ValidationError, match="needs autopilot_lanes: 3"):
        Scenario.model_validate({"name": "x", "duration_s": 1, "redundancy": {"lane_navigation": "own"}})
    with pytest.raises(ValidationError, match="offset_m"):
        Scenario.model_validate(
            {"name": "x", "duration_s": 1, "faults": [{"type": "baro_bias", "start_s": 0.5}]}
        )


def test_gps_outage_spans_of_the_stand_in_need_every_unit_lost() -> None:
    sc = Scenario.model_validate(
        {
            "name": "x",
            "duration_s": 30,
            "redundancy": {"sensor_lanes": 3},
            "faults": [
                {"type": "gps_loss", "start_s": 1.0, "end_s": 10.0, "lane": 0},
                {"type": "gps_loss", "start_s": 5.0, "end_s": 20.0, "lane": 1},
                {"type": "gps_loss", "start_s": 8.0, "end_s": 9.0, "lane": 2},
                {"type": "gps_loss", "start_s": 9.5, "end_s": 12.0, "lane": 2},
            ],
        }
    )
    assert gps_loss_spans(sc) == [(8.0, 9.0), (9.5, 10.0)]
    assert gps_loss_spans(sc, (1,)) == [(5.0, 20.0)]


def test_the_configuration_sets_the_voter_limits_and_presets() -> None:
    cfg = MerlinConfig.model_validate(
        {
            "redundancy": {
                "baro_miscompare_m": 2.0,
                "imu_persistence_s": 0.1,
                "gps_pos_miscompare_m": 8.0,
                "reintegration_s": 5.0,
                "lane_preset": "thesis",
                "lane_persistence_s": 2.0,
            }
        }
    )
    specs = channel_specs(cfg.redundancy)
    assert specs["baro"].miscompare == (2.0,) and specs["imu"].persistence_s == 0.1
    assert specs["gps"].miscompare[:3] == (8.0, 8.0, 12.0) and specs["mag"].reintegration_s == 5.0
    lc = lane_config(cfg.redundancy)
    assert lc.exchange_hz == 1.0 and lc.persistence_s == 2.0 and lc.latch_s == 600.0
    assert lane_config(cfg.redundancy, "fast").exchange_hz == 50.0  # the scenario's choice wins
    with pytest.raises(ValidationError, match="warn_at"):
        MerlinConfig.model_validate({"redundancy": {"warn_at": "triplex"}})


def test_a_lane_whose_own_barometer_fails_flags_its_altitude_and_only_it() -> None:
    sc = Scenario.model_validate(
        {
            "name": "own",
            "duration_s": 6.0,
            "seed": 3,
            "gcs": TAKEOFF,
            "estimator": "ekf",
            "redundancy": {"autopilot_lanes": 3, "sensor_lanes": 3, "lane_navigation": "own"},
            "faults": [{"type": "baro_bias", "start_s": 4.0, "lane": 2, "offset_m": 20.0}],
        }
    )
    loop = ClosedLoop(sc, MerlinConfig())
    assert loop.ekf is None and loop.redundancy.lane_nav is not None
    nav: LaneNavigation = loop.redundancy.lane_nav
    from merlin.core.types import Inputs

    flags_at: dict[float, list[tuple[bool, ...]]] = {}
    for k in range(round(5.0 / sc.dt_s)):
        st = loop.sense()
        loop.act(Inputs(st, gcs_link_t_s=loop.t))
        t = loop.t
        if k % 40 == 0:
            flags_at[round(t, 2)] = [
                nav.flags(i, t, loop.frame.imu[i], False, LaneContext(), 5.0) for i in range(3)
            ]
    before = flags_at[3.9]
    assert all(all(f) for f in before), before
    after = flags_at[4.5]
    from merlin.redundancy.lane_voter import THESIS_FLAGS

    alt = THESIS_FLAGS.index("local_altitude_valid")
    assert after[0][alt] and after[1][alt] and not after[2][alt]
    assert all(after[0]) and all(after[1])


@pytest.mark.parametrize("path", ["sensor_lanes_isolated", "autopilot_lane_own_sensors"])
def test_the_report_to_the_core_names_the_degraded_channel(path: str) -> None:
    from sims.scenario import load_scenario

    sc, cfg = load_scenario(f"examples/scenarios/{path}.yaml")
    sc = sc.model_copy(update={"duration_s": 24.0 if path == "sensor_lanes_isolated" else 21.0})
    r = run_scenario(sc, cfg)
    tripped = [
        e
        for e in r.events
        if e["type"] in ("warning", "monitor_tripped") and e.get("reason") == "redundancy_degraded"
    ]
    assert not tripped, "duplex is not a warning at the default warn_at: simplex"
    cfg2 = cfg.model_copy(update={"redundancy": cfg.redundancy.model_copy(update={"warn_at": "duplex"})})
    r2 = run_scenario(sc, cfg2)
    w = [e for e in r2.events if e["type"] == "warning" and e.get("reason") == "redundancy_degraded"]
    assert w, "warn_at: duplex warns at the first isolation"
    text = w[0]["reason_detail"]["text"]
    assert "DUPLEX" in text and ("baro" in text or "autopilot" in text)
    assert r2.metrics["revocations"] == 0 and math.isfinite(w[0]["t"])
