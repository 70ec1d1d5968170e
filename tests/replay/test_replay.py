"""``merlin replay``: the seed's real PX4 ULogs and a generated MAVLink .tlog through the trusted core."""

from __future__ import annotations

import json
import math
import os
import struct
from pathlib import Path

import pytest

from merlin.cli import main
from merlin.config.loader import load_config
from merlin.replay.core_replay import replay
from merlin.replay.flightlog import read_log

ROOT = Path(__file__).resolve().parents[2]
SHARED = Path(os.environ.get("MERLIN_SHARED", ROOT / ".." / "shared"))
ULOG = SHARED / "data" / "seed-triplex-logs" / "instance_0_Communication_fail.ulg"
DEFAULT = ROOT / "examples" / "configs" / "default.yaml"


@pytest.fixture(scope="module")
def ulog_replay():  # type: ignore[no-untyped-def]
    if not ULOG.exists():
        pytest.skip(f"seed logs not found at {ULOG} (set MERLIN_SHARED)")
    log = read_log(ULOG)
    return log, replay(log, load_config(DEFAULT))


def test_ulog_is_read_with_the_topics_the_core_needs(ulog_replay) -> None:  # type: ignore[no-untyped-def]
    log, _ = ulog_replay
    assert log.kind == "ulog" and log.t_end_s > 30.0
    assert log.armed is not None and log.landed is not None and log.accel_frd_mps2 is not None
    # hover in SITL: specific force about -g on the body z axis
    az = log.accel_frd_mps2[1][:, 2]
    assert -11.0 < float(sorted(az)[len(az) // 2]) < -8.5


def test_ulog_replay_grants_once_airborne_and_reports_each_revocation(ulog_replay) -> None:  # type: ignore[no-untyped-def]
    _, r = ulog_replay
    assert r.first_airborne_s is not None
    grants = [e for e in r.events if e["type"] == "granted"]
    assert grants and grants[0]["t"] >= r.first_airborne_s
    # every denial before the grant says why (here: below the envelope's minimum altitude of 3 m)
    denials = [e for e in r.events if e["type"] == "denied"]
    assert denials and all(e.get("reason") for e in denials)
    assert r.revocations, "this log's flight leaves the default configuration's field: a revocation is due"
    for e in r.revocations:
        assert e["t"] > grants[0]["t"] and e.get("reason") and e["reason_detail"]["text"]
    # authority is EXPERIMENTAL only between a grant and the next revocation
    k_grant = int(grants[0]["t"] * r.rate_hz) + 2
    assert r.authority[k_grant] == 2
    k_rev = math.ceil(r.revocations[0]["t"] * r.rate_hz) + 1
    assert r.authority[k_rev] == 0


@pytest.mark.parametrize("instance", [0, 1, 2])
def test_ulog_replay_matches_the_documented_account(instance: int) -> None:
    """docs/campaigns.md: on the seed's triplex SITL logs with the default configuration, requests are
    denied while the vehicle is below the envelope's 3 m minimum altitude, granted at 19.7 s and revoked
    at 43.1 s by the geofence (the projected path reaches the north field's boundary, with the default's
    8 m margin; 44.2 s with a 5 m margin, checked below). The three
    instances flew the same mission: each must tell the same story."""
    path = ULOG.with_name(f"instance_{instance}_Communication_fail.ulg")
    if not path.exists():
        pytest.skip(f"seed logs not found at {path} (set MERLIN_SHARED)")
    r = replay(read_log(path), load_config(DEFAULT))
    assert r.first_airborne_s is not None
    decisions = [e for e in r.events if e["type"] in ("denied", "granted", "revoked")]
    kinds = [e["type"] for e in decisions]
    n_denied = kinds.index("granted")
    assert kinds == ["denied"] * n_denied + ["granted", "revoked"], kinds
    assert n_denied >= 1
    for e in decisions[:n_denied]:  # one REQUEST a second from the first airborne moment
        assert e["reason"] == "envelope" and e["reason_detail"]["parameter"] == "altitude_m"
        assert e["reason_detail"]["value"] < 3.0 <= e["reason_detail"]["limit"] + 1e-9
    assert decisions[0]["t"] == pytest.approx(r.first_airborne_s, abs=0.03)
    grant, rev = decisions[n_denied], decisions[n_denied + 1]
    assert grant["t"] == pytest.approx(19.7, abs=0.05)
    assert rev["t"] == pytest.approx(43.1, abs=0.05)
    assert rev["reason"] == "geofence" and rev["reason_detail"]["parameter"] == "inclusion"
    assert rev["reason_detail"]["value"] >= rev["reason_detail"]["limit"]
    assert "inclusion boundary" in rev["reason_detail"]["text"]
    t = [k / r.rate_hz for k in range(len(r.authority))]
    experimental = [tk for tk, a in zip(t, r.authority, strict=True) if a == 2]
    assert experimental and grant["t"] <= experimental[0] <= grant["t"] + 0.1
    assert rev["t"] - 0.03 <= experimental[-1] < rev["t"]


def test_ulog_replay_revokes_later_with_a_smaller_fence_margin() -> None:
    """The revocation's time follows the fence's margin: with 5 m instead of the default's 8 m the projected
    path reaches the margin's edge 1.1 s later (44.2 s)."""
    if not ULOG.exists():
        pytest.skip(f"seed logs not found at {ULOG} (set MERLIN_SHARED)")
    cfg = load_config(DEFAULT)
    cfg = cfg.model_copy(update={"geofence": cfg.geofence.model_copy(update={"margin_m": 5.0})})
    r = replay(read_log(ULOG), cfg)
    [rev] = [e for e in r.events if e["type"] == "revoked"]
    assert rev["reason"] == "geofence" and rev["t"] == pytest.approx(44.2, abs=0.05)


def test_replay_cli_writes_json_and_plots(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    if not ULOG.exists():
        pytest.skip("seed logs not found")
    assert main(["replay", str(ULOG), "--config", str(DEFAULT), "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "GRANTED" in out and "revocation(s)" in out
    d = json.loads((tmp_path / "replay.json").read_text())
    assert d["kind"] == "ulog" and len(d["config_sha256"]) == 64
    assert (tmp_path / "replay_envelope.png").stat().st_size > 10_000


def _write_tlog(path: Path, north_speed_mps: float) -> None:
    """A flight as a vehicle would send it: armed HEARTBEAT, take-off to 10 m, then north at the speed."""
    from pymavlink.dialects.v20 import common as mavlink

    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    t0_us = 1_700_000_000_000_000
    n = e = 0.0
    with path.open("wb") as f:
        def put(msg: object, t_s: float) -> None:
            f.write(struct.pack(">Q", t0_us + int(t_s * 1e6)) + msg.pack(mav))  # type: ignore[attr-defined]

        for k in range(0, 40 * 20):
            t = k / 20.0
            armed = t >= 1.0
            h = min(10.0, max(0.0, (t - 2.0) * 2.0)) if armed else 0.0
            vn = north_speed_mps if t >= 12.0 else 0.0
            n += vn / 20.0
            if k % 20 == 0:
                put(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4,
                                                      mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0, 0,
                                                      mavlink.MAV_STATE_ACTIVE, 3), t)
                put(mavlink.MAVLink_gps_raw_int_message(int(t * 1e6), 3, 0, 0, 0, 80, 100, 0, 0, 0, 12), t)
            put(mavlink.MAVLink_attitude_message(int(t * 1e3), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), t)
            put(mavlink.MAVLink_local_position_ned_message(int(t * 1e3), n, e, -h, vn, 0.0, 0.0), t)


@pytest.mark.parametrize("speed, revoked", [(12.0, True), (4.0, False)])
def test_tlog_replay_revokes_an_overspeed_for_the_vel_n_limit(tmp_path: Path, speed: float, revoked: bool) -> None:
    p = tmp_path / "flight.tlog"
    _write_tlog(p, speed)
    log = read_log(p)
    assert log.kind == "tlog" and 39.0 < log.t_end_s < 40.0
    r = replay(log, load_config(DEFAULT))
    assert any(e["type"] == "granted" for e in r.events)
    revs = r.revocations
    if revoked:
        # default conservative stage: vel_n within +-8 m/s for at most 0.5 s; the overspeed starts at 12 s
        assert revs and revs[0]["reason"] == "envelope"
        assert revs[0]["reason_detail"]["parameter"] == "vel_n_mps"
        assert 12.5 - 0.03 <= revs[0]["t"] <= 12.5 + 0.05
    else:
        assert not [e for e in revs if e["reason"] == "envelope"]


def test_unknown_log_type_is_an_input_error(tmp_path: Path) -> None:
    p = tmp_path / "x.csv"
    p.write_text("t\n")
    assert main(["replay", str(p), "--config", str(DEFAULT)]) == 2
