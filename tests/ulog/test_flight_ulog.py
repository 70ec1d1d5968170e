"""A `merlin sim` run's ULog: it opens in pyulog and its command-line tools with PX4's topic and field
names, Merlin's own topics, units and enum labels; `merlin replay` of it reproduces the run's revocation."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pyulog import ULog

from merlin.config.models import MerlinConfig
from merlin.core.types import Authority
from merlin.replay.core_replay import home_frame, replay
from merlin.replay.flightlog import read_log
from sims.report import write_ulog
from sims.runner import run_scenario
from sims.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "examples" / "scenarios" / "figure5_instant.yaml"

PX4_TOPICS = {
    "vehicle_local_position": ["x", "y", "z", "vx", "vy", "vz", "ref_lat", "ref_lon", "ref_alt", "eph", "epv"],
    "vehicle_global_position": ["lat", "lon", "alt", "eph"],
    "vehicle_attitude": ["q[0]", "q[1]", "q[2]", "q[3]"],
    "vehicle_angular_velocity": ["xyz[0]", "xyz[1]", "xyz[2]"],
    "vehicle_status": ["arming_state", "nav_state", "vehicle_type"],
    "sensor_combined": ["gyro_rad[0]", "accelerometer_m_s2[2]"],
    "battery_status": ["remaining"],
    "actuator_outputs": ["noutputs", "output[0]", "output[3]"],
    "vehicle_land_detected": ["landed"],
    "vehicle_attitude_setpoint": ["q_d[0]", "thrust_body[2]"],
}
MERLIN_TOPICS = {
    "merlin_authority": ["authority", "behavior", "armed", "landed"],
    "merlin_envelope": ["roll_deg", "pitch_deg", "roll_deg_outside_s", "altitude_m_outside_s"],
    "merlin_monitors": ["envelope"],
    "merlin_fence": ["margin_m"],
    "merlin_nav": ["nav_mode", "sigma_h_m", "sigma_v_m", "inertial_s"],
    "merlin_command": ["kind", "velocity[0]", "thrust", "blend"],
}


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[object, Path]:
    sc, cfg = load_scenario(SCENARIO)
    r = run_scenario(sc, cfg, source=str(SCENARIO))
    out = tmp_path_factory.mktemp("fig5")
    return r, write_ulog(r, out)


def _topic(u: ULog, name: str) -> dict[str, np.ndarray]:
    return u.get_dataset(name).data


def test_px4_and_merlin_topics_with_units_and_labels(run: tuple[object, Path]) -> None:
    r, path = run
    u = ULog(str(path))
    for topic, fields in {**PX4_TOPICS, **MERLIN_TOPICS}.items():
        data = _topic(u, topic)
        missing = [f for f in fields if f not in data]
        assert not missing, f"{topic} lacks {missing}"
    lp = _topic(u, "vehicle_local_position")
    assert len(lp["timestamp"]) == len(r.log["t"])  # one sample per log row
    assert np.allclose(lp["ref_lat"], r.config.home.lat_deg) and np.allclose(lp["ref_lon"], r.config.home.lon_deg)
    assert np.allclose(lp["x"], r.log["est_n"], atol=1e-3) and np.allclose(lp["vz"], r.log["est_vd"], atol=1e-4)
    # the quaternion is the attitude the core read (roll of the figure 5 ramp past 30 deg)
    q = np.stack([_topic(u, "vehicle_attitude")[f"q[{i}]"] for i in range(4)], axis=1)
    roll = np.arctan2(2 * (q[:, 0] * q[:, 1] + q[:, 2] * q[:, 3]), 1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2))
    assert np.allclose(roll, r.aux["est_roll"], atol=1e-5)
    info = u.msg_info_dict
    assert info["unit:vehicle_local_position.x"] == "m"
    assert info["unit:merlin_envelope.roll_deg"] == "deg"
    assert info["unit:vehicle_angular_velocity.xyz"] == "rad/s"
    assert "2=EXPERIMENTAL" in info["labels:merlin_authority.authority"]
    assert info["sys_name"] == "Merlin" and info["merlin_scenario"] == "figure5_instant"
    # authority as logged, and PX4's OFFBOARD navigation state exactly while EXPERIMENTAL holds authority
    auth = _topic(u, "merlin_authority")["authority"]
    assert np.array_equal(auth, r.log["authority"].astype(np.uint8))
    offboard = _topic(u, "vehicle_status")["nav_state"] == 14
    assert np.array_equal(offboard, auth == int(Authority.EXPERIMENTAL))
    # every event is a logged message, the revocation a warning
    texts = [(m.log_level_str(), m.message) for m in u.logged_messages]
    assert len(texts) == len(r.events)
    assert any(level == "WARNING" and text.startswith("REVOKED envelope") for level, text in texts)
    params = u.initial_parameters
    assert params["ENV_ROLL_MAX"] == pytest.approx(30.0) and params["ENV_ROLL_DUR"] == pytest.approx(0.0)


def test_pyulog_command_line_tools(run: tuple[object, Path]) -> None:
    _, path = run
    bindir = Path(sys.executable).parent

    def tool(name: str) -> str:
        exe = bindir / name
        if not exe.exists():
            pytest.skip(f"pyulog's {name} is not installed beside {sys.executable}")
        res = subprocess.run([str(exe), str(path)], capture_output=True, text=True, timeout=120, check=False)
        assert res.returncode == 0, res.stderr
        return res.stdout

    info = tool("ulog_info")
    assert "vehicle_local_position" in info and "merlin_authority" in info and "sys_name: Merlin" in info
    assert "REVOKED envelope" in tool("ulog_messages")
    assert "ENV_ROLL_MAX,30" in tool("ulog_params").replace(" ", "")


def test_pyulog_rewrites_it_unchanged(run: tuple[object, Path], tmp_path: Path) -> None:
    """pyulog's own serialiser, fed what it parsed from our file, writes a log that parses to the same
    contents: the two implementations of the format agree."""
    _, path = run
    u = ULog(str(path))
    copy = tmp_path / "copy.ulg"
    u.write_ulog(str(copy))
    v = ULog(str(copy))
    assert u == v
    assert not u.file_corruption


def test_replay_of_the_runs_ulog_reproduces_its_revocation(run: tuple[object, Path]) -> None:
    r, path = run
    log = read_log(path)
    assert log.config_json is not None and log.local_frame == "merlin"
    cfg = MerlinConfig.model_validate_json(log.config_json)
    log, frame = home_frame(log, cfg)
    assert frame.frame == "home" and frame.max_shift_m == 0.0
    res = replay(log, cfg, rate_hz=50.0)
    run_revoked = [e for e in r.events if e["type"] == "revoked"]
    assert len(run_revoked) == 1 and len(res.revocations) == 1
    a, b = run_revoked[0], res.revocations[0]
    assert b["reason"] == a["reason"] == "envelope"
    assert b["reason_detail"]["parameter"] == a["reason_detail"]["parameter"] == "roll_deg"
    # the log holds 50 Hz rows of a 400 Hz run: the replay sees the exceedance at the next logged row
    assert a["t"] <= b["t"] <= a["t"] + 2.0 / 50.0 + 1e-9
    # and the replayed authority holds EXPERIMENTAL until then, TRUSTED after, as the run's does
    t_rev = b["t"]
    after = res.t_s > t_rev + 0.05
    assert np.all(res.authority[after] == int(Authority.TRUSTED))
    assert math.isclose(r.log["authority"][r.log["t"] > t_rev + 0.05].max(), 0.0)


def test_replay_reproduces_a_fence_revocation(tmp_path: Path) -> None:
    """Figure 4(a): the velocity-projected fence revokes an experimental controller flying at the
    boundary; the run's ULog, replayed, revokes for the same boundary at the next logged rows."""
    scenario = ROOT / "examples" / "scenarios" / "figure4_projection_9mps.yaml"
    sc, cfg = load_scenario(scenario)
    r = run_scenario(sc, cfg, source=str(scenario))
    log, _ = home_frame(read_log(write_ulog(r, tmp_path)), cfg)
    res = replay(log, MerlinConfig.model_validate_json(log.config_json or ""), rate_hz=50.0)
    a = next(e for e in r.events if e["type"] == "revoked")
    b = res.revocations[0]
    assert a["reason"] == b["reason"] == "geofence"
    assert a["reason_detail"]["parameter"] == b["reason_detail"]["parameter"] == "inclusion"
    assert a["t"] <= b["t"] <= a["t"] + 2.0 / 50.0 + 1e-9


def test_gps_fixes_are_vehicle_gps_position(tmp_path: Path) -> None:
    """With the EKF the simulated receiver's fixes are logged as PX4's vehicle_gps_position, stamped on
    arrival, none while the GPS is lost."""
    scenario = ROOT / "examples" / "scenarios" / "gps_loss_vo.yaml"
    sc, cfg = load_scenario(scenario)
    sc = sc.model_copy(update={"duration_s": 12.0})
    r = run_scenario(sc, cfg, source=str(scenario))
    assert r.gps_fixes
    u = ULog(str(write_ulog(r, tmp_path)))
    gps = _topic(u, "vehicle_gps_position")
    assert len(gps["timestamp"]) == len(r.gps_fixes)
    assert np.all(gps["timestamp"] >= gps["timestamp_sample"]) and np.all(gps["fix_type"] == 3)
    lp = _topic(u, "vehicle_global_position")
    assert abs(float(np.median(gps["latitude_deg"])) - float(np.median(lp["lat"]))) < 1e-4
    assert u.msg_info_dict["unit:vehicle_gps_position.altitude_msl_m"] == "m"
