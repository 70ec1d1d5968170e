"""The shipped mixed campaign (``examples/campaigns/``): every file loads and plans, and together the files
inject every fault kind the scenario loader knows, so the mix cannot silently fall behind a new one."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, get_args

import pytest
import yaml

from merlin.campaign.scheduler import load_scenarios, plan
from sims.scenario import FaultType

ROOT = Path(__file__).resolve().parents[2]
FILES = sorted((ROOT / "examples" / "campaigns").glob("*.yaml"))
FAULT_TYPE_KEY = re.compile(r"^faults\.(\d+)\.type$")


def fault_types_of(data: dict[str, Any]) -> set[str]:
    """The fault kinds a campaign file can inject: those written in ``faults:`` and those a ``vary:``
    entry can draw for a fault's ``type`` (a fault whose type is varied counts only by its draws)."""
    varied = {
        int(m.group(1)): spec
        for k, spec in (data.get("vary") or {}).items()
        if (m := FAULT_TYPE_KEY.match(str(k)))
    }
    out: set[str] = set()
    for i, f in enumerate(data.get("faults") or []):
        if i not in varied:
            out.add(f["type"])
    for spec in varied.values():
        ((kind, args),) = spec.items()
        assert kind == "choice", f"a fault type can only be drawn by choice, got {kind}"
        out.update(args)
    return out


def test_the_campaign_files_are_there() -> None:
    assert len(FILES) >= 8, [f.name for f in FILES]


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_every_shipped_campaign_file_loads_and_plans(path: Path) -> None:
    scs = load_scenarios([str(path)])
    specs = plan(scs, 6, seed=1)  # every sample validated through the scenario and configuration models
    assert len({s.seed for s in specs}) == 6


def test_every_fault_kind_is_in_the_mixed_campaign() -> None:
    known = set(get_args(FaultType))
    assert known, "sims.scenario.FaultType lists no fault kinds"
    covered: dict[str, list[str]] = {}
    for p in FILES:
        for t in fault_types_of(yaml.safe_load(p.read_text())):
            covered.setdefault(t, []).append(p.name)
    missing = sorted(known - set(covered))
    assert not missing, f"fault kinds no file in examples/campaigns/ injects: {missing}"
    assert set(covered) <= known, f"unknown fault kinds in campaign files: {sorted(set(covered) - known)}"


def test_the_fault_census_reads_both_written_and_drawn_kinds() -> None:
    data = {
        "faults": [{"type": "gps_loss"}, {"type": "imu_stuck"}],
        "vary": {"faults.1.type": {"choice": ["imu_bias", "imu_drift"]}},
    }
    assert fault_types_of(data) == {"gps_loss", "imu_bias", "imu_drift"}


def test_sensor_noise_scales_reach_the_simulated_sensor_units() -> None:
    """``sensors:`` scales the baseline noise of the sensor units a campaign varies; all at 1 it hands the
    very same parameters on (shipped scenarios stay bit-identical)."""
    from merlin.config.models import MerlinConfig
    from sims.runner import ClosedLoop
    from sims.scenario import Scenario, SensorNoise
    from sims.sensors import SensorParams

    base = SensorParams()
    assert SensorNoise().apply(base) is base
    s = SensorNoise(
        imu_noise_scale=2.0, gps_noise_scale=3.0, baro_noise_scale=0.5, mag_noise_scale=4.0
    ).apply(base)
    assert s.imu.gyro_noise_density_radps_per_rthz == 2.0 * base.imu.gyro_noise_density_radps_per_rthz
    assert s.imu.accel_noise_density_mps2_per_rthz == 2.0 * base.imu.accel_noise_density_mps2_per_rthz
    assert s.imu.gyro_bias_rw_radps2_per_rthz == base.imu.gyro_bias_rw_radps2_per_rthz  # noise only
    assert (s.gps.pos_h_markov_sigma_m, s.gps.pos_v_white_sigma_m, s.gps.vel_h_sigma_mps) == (
        3.0 * base.gps.pos_h_markov_sigma_m,
        3.0 * base.gps.pos_v_white_sigma_m,
        3.0 * base.gps.vel_h_sigma_mps,
    )
    assert s.baro.noise_sigma_m == 0.5 * base.baro.noise_sigma_m
    assert s.mag.noise_sigma_gauss == 4.0 * base.mag.noise_sigma_gauss
    sc = Scenario.model_validate(
        {"name": "n", "duration_s": 1.0, "estimator": "ekf", "sensors": {"gps_noise_scale": 3.0}}
    )
    assert (
        ClosedLoop(sc, MerlinConfig()).sensors.params.gps.pos_h_markov_sigma_m
        == 3.0 * base.gps.pos_h_markov_sigma_m
    )
    with pytest.raises(ValueError, match="gps_noise_scale"):
        Scenario.model_validate({"name": "n", "duration_s": 1.0, "sensors": {"gps_noise_scale": -1.0}})
