"""The .tlog reader: what Merlin's own writer logged reads back as plain records, a corrupted frame is
skipped rather than fatal, and the MAVLink constants it names agree with pymavlink's common dialect."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from merlin.link.tlog import TlogWriter
from merlin.link.tlog_reader import MAV_MODE_FLAG_SAFETY_ARMED, MAV_TYPE_GCS, TlogError, read_records


def _frames() -> list[bytes]:
    from pymavlink.dialects.v20 import common as mavlink

    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    return [
        mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4,
                                          mavlink.MAV_MODE_FLAG_SAFETY_ARMED, 0, mavlink.MAV_STATE_ACTIVE,
                                          3).pack(mav),
        mavlink.MAVLink_attitude_message(1000, 0.1, -0.2, 0.3, 0.0, 0.0, 0.0).pack(mav),
        mavlink.MAVLink_local_position_ned_message(1000, 1.5, -2.5, -10.0, 0.5, 0.0, 0.0).pack(mav),
    ]


def test_constants_match_the_common_dialect() -> None:
    from pymavlink.dialects.v20 import common as mavlink

    assert mavlink.MAV_TYPE_GCS == MAV_TYPE_GCS
    assert mavlink.MAV_MODE_FLAG_SAFETY_ARMED == MAV_MODE_FLAG_SAFETY_ARMED


def test_records_written_by_merlins_writer_read_back(tmp_path: Path) -> None:
    p = tmp_path / "x.tlog"
    t0 = time.time()
    with TlogWriter(p, fsync_interval_s=None) as w:
        for i, f in enumerate(_frames()):
            w.write(f, t0 + i)
    recs = list(read_records(p))
    assert [r.name for r in recs] == ["HEARTBEAT", "ATTITUDE", "LOCAL_POSITION_NED"]
    assert recs[1].fields["pitch"] == pytest.approx(-0.2)
    assert recs[2].fields["y"] == pytest.approx(-2.5)
    assert recs[2].t_unix_s == pytest.approx(t0 + 2, abs=1e-5)
    assert recs[0].fields["base_mode"] & MAV_MODE_FLAG_SAFETY_ARMED
    assert [r.name for r in read_records(p, ["ATTITUDE"])] == ["ATTITUDE"]


def test_a_corrupted_frame_is_skipped(tmp_path: Path) -> None:
    p = tmp_path / "bad.tlog"
    frames = _frames()
    bad = bytearray(frames[1])
    bad[-1] ^= 0xFF  # break the CRC
    with TlogWriter(p, fsync_interval_s=None) as w:
        w.write(frames[0], 1.7e9)
        w.write(bytes(bad), 1.7e9 + 1)
        w.write(frames[2], 1.7e9 + 2)
    names = [r.name for r in read_records(p)]
    assert "ATTITUDE" not in names
    assert names[0] == "HEARTBEAT" and names[-1] == "LOCAL_POSITION_NED"


def test_an_unreadable_path_is_a_tlog_error(tmp_path: Path) -> None:
    with pytest.raises(TlogError, match="cannot open"):
        list(read_records(tmp_path / "missing" / "x.tlog"))
