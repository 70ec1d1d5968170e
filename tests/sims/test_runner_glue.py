"""The runner's per-tick shortcuts decide nothing differently: the sensor frame is skipped only when nothing
reads it, and the column log gives exactly what a dict of lists would."""

from __future__ import annotations

import hashlib
import math
from typing import Any

import numpy as np
import pytest

import sims.runner as runner
from merlin.config.models import MerlinConfig
from sims.run_log import _Log
from sims.runner import ClosedLoop, RunResult, run_scenario
from sims.scenario import Scenario

TAKEOFF = [{"t": 0.5, "command": "arm"}, {"t": 1.0, "command": "takeoff", "param": 8}]


def _scenario(**kw: Any) -> Scenario:
    # the stand-in, by name (the EKF is the default): the estimator that reads no sensor, whose loop is the
    # one that can skip the sensor frame
    base: dict[str, Any] = {"name": "runner_glue", "duration_s": 6.0, "seed": 11, "gcs": TAKEOFF,
                            "estimator": "truth_plus_noise"}
    base.update(kw)
    return Scenario.model_validate(base)


def _digest(r: RunResult) -> str:
    h = hashlib.sha256(r.decisions_digest.encode())
    h.update(repr([{k: v for k, v in e.items() if k != "traceback"} for e in r.events]).encode())
    h.update(repr({k: v for k, v in r.metrics.items() if k not in ("wall_time_s", "realtime_factor")}).encode())
    return h.hexdigest()


def test_the_sensor_frame_is_sampled_only_for_its_readers() -> None:
    assert not ClosedLoop(_scenario(), MerlinConfig()).sensor_frame_wanted
    assert ClosedLoop(_scenario(estimator="ekf"), MerlinConfig()).sensor_frame_wanted
    assert ClosedLoop(_scenario(redundancy={"autopilot_lanes": 3}), MerlinConfig()).sensor_frame_wanted
    loop = ClosedLoop(_scenario(), MerlinConfig())
    loop.sense()
    assert loop.frame is None
    loop.sensor_frame_wanted = True  # a driver that wants the samples anyway
    loop.sense()
    assert loop.frame is not None and len(loop.frame.imu) == 3


def test_skipping_the_unread_sensor_frame_changes_no_decision() -> None:
    """The same run with the sensors sampled every tick (and their samples thrown away) is bit-identical:
    the sensors and the fault injector draw from their own random streams. Sensor faults included."""
    sc = _scenario(faults=[{"type": "gps_loss", "start_s": 3.0, "end_s": 4.0},
                           {"type": "imu_noise", "start_s": 2.0, "lane": 1},
                           {"type": "gcs_link_loss", "start_s": 4.5, "end_s": 5.0}])
    plain = runner.make_loop(sc, MerlinConfig())
    skipped = run_scenario(sc, MerlinConfig(), loop=plain)
    assert plain.frame is None  # nothing read the sensors: they were not sampled
    wanting = runner.make_loop(sc, MerlinConfig())
    wanting.sensor_frame_wanted = True  # a driver that wants the samples anyway
    sampled = run_scenario(sc, MerlinConfig(), loop=wanting)
    assert wanting.frame is not None
    assert _digest(sampled) == _digest(skipped)
    assert _digest(run_scenario(sc, MerlinConfig())) == _digest(skipped)  # the runner's own vehicle side
    assert [e["type"] for e in skipped.events if e["type"].startswith("fault_")] == [
        "fault_start", "fault_start", "fault_end", "fault_start", "fault_end"]


def _dict_log(rows: list[dict[str, float]]) -> dict[str, np.ndarray]:
    """The reference: every row's items appended to a dict of lists."""
    cols: dict[str, list[float]] = {}
    for row in rows:
        for k, v in row.items():
            cols.setdefault(k, []).append(v)
    return {k: np.asarray(v) for k, v in cols.items()}


def test_the_column_log_is_a_dict_of_lists() -> None:
    fixed_keys = ("t", "a", "b", "a")  # a repeated key keeps the later value, at the first place
    log = _Log(fixed_keys)
    assert log.arrays() == {} and len(log) == 0
    rows: list[dict[str, float]] = []
    rng = np.random.default_rng(3)
    for k in range(40):
        fixed = (k * 0.1, *rng.standard_normal(3).tolist())
        extra: dict[str, float] = {"mon_x": float(k % 2)}
        if k % 7 == 3:
            extra["mon_shadow"] = 1.0  # a column only some rows have
        if k % 5 == 0:
            extra["b"] = -1.0  # an extra value for a fixed column replaces it, as a dict update would
        log.add(fixed, extra)
        row = dict(zip(fixed_keys, fixed, strict=True))
        row.update(extra)
        rows.append(row)
    got, want = log.arrays(), _dict_log(rows)
    assert len(log) == 40
    assert list(got) == list(want)
    for key in want:
        assert got[key].dtype == want[key].dtype
        np.testing.assert_array_equal(got[key], want[key])


def test_the_column_log_keeps_every_bit_and_grows_after_it_is_read() -> None:
    log = _Log(("t", "v"))
    special = [-0.0, math.nan, math.inf, 5e-324, -1.7976931348623157e308]
    for k, v in enumerate(special):
        log.add((float(k), v), {})
    first = log.arrays()
    log.add((9.0, 1.5), {})  # reading the table leaves the buffer free to grow
    second = log.arrays()
    assert first["v"].tobytes() == np.asarray(special).tobytes()
    assert second["v"].tobytes() == np.asarray([*special, 1.5]).tobytes() and len(log) == 6
    assert first["t"].flags.c_contiguous and first["t"].dtype == np.float64
    with pytest.raises(ValueError, match="a log row has 3 fixed values; its columns are 2"):
        log.add((1.0, 2.0, 3.0), {})


def test_a_vehicle_side_already_flown_is_refused() -> None:
    """run_scenario flies a vehicle side from its first tick: one that has been ticked would start the run's
    clock, log and script at the wrong time."""
    sc = _scenario()
    loop = runner.make_loop(sc, MerlinConfig())
    run_scenario(sc, MerlinConfig(), loop=loop)
    with pytest.raises(ValueError, match="already been ticked"):
        run_scenario(sc, MerlinConfig(), loop=loop)
