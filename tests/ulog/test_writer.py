"""The ULog writer on its own: formats are checked, a flight written in batches reads as the same flight
written at once, logged-message levels are PX4's, and pyulog reads a file cut short up to its end."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pyulog import ULog

from merlin.ulog.flight import FlightMeta, FlightULog, write_flight_ulog
from merlin.ulog.format import Field, Format, ULogFormatError, ULogWriter

META = FlightMeta(home_lat_deg=29.6516, home_lon_deg=-82.3248, home_alt_amsl_m=30.0)


def _cols(n: int) -> dict[str, np.ndarray]:
    t = np.arange(n) * 0.02
    rng = np.random.default_rng(3)
    cols = {"t": t}
    for k in ("est_n", "est_e", "est_d", "est_vn", "est_ve", "est_vd", "est_roll", "est_pitch", "est_yaw",
              "est_p", "est_q", "est_r", "est_ax", "est_ay", "est_az", "sigma_h", "sigma_v", "nav_inertial_s",
              "cmd_vn", "cmd_ve", "cmd_vd", "cmd_roll", "cmd_pitch", "cmd_yaw", "cmd_thrust", "cmd_blend",
              "m0", "m1", "m2", "m3", "battery_frac", "env_roll_deg", "fence_margin"):
        cols[k] = rng.normal(size=n)
    cols.update(nav_mode=np.zeros(n), authority=(t > 0.5) * 2.0, behavior=np.full(n, 2.0), armed=np.ones(n),
                landed=np.zeros(n), cmd_kind=np.ones(n), sp_kind=np.where(t > 0.3, 1.0, np.nan),
                mon_envelope=(t > 0.8) * 1.0)
    for k in ("sp_n", "sp_e", "sp_d", "sp_vn", "sp_ve", "sp_vd", "sp_roll", "sp_pitch", "sp_yaw", "sp_thrust"):
        cols[k] = np.where(t > 0.3, 1.5, np.nan)
    return cols


def test_formats_are_checked() -> None:
    with pytest.raises(ULogFormatError, match="first field must be 'uint64_t timestamp'"):
        Format("x", (Field("float", "a"),))
    with pytest.raises(ULogFormatError, match="type 'float32'"):
        Format("x", (Field("uint64_t", "timestamp"), Field("float32", "a")))
    with pytest.raises(ULogFormatError, match="not a unique identifier"):
        Format("x", (Field("uint64_t", "timestamp"), Field("float", "a"), Field("float", "a")))


def test_definitions_come_before_data(tmp_path: Path) -> None:
    w = ULogWriter(tmp_path / "x.ulg")
    w.add_format(Format("topic_a", (Field("uint64_t", "timestamp"), Field("float", "v", unit="m"))))
    w.subscribe("topic_a")
    with pytest.raises(ULogFormatError, match="definitions section"):
        w.info("late", "x")
    with pytest.raises(ULogFormatError, match="log level"):
        w.log("loud", 0, "x")
    w.log("warning", 5, "careful")
    w.close()
    u = ULog(str(tmp_path / "x.ulg"))
    assert [(m.log_level_str(), m.timestamp, m.message) for m in u.logged_messages] == [("WARNING", 5, "careful")]
    assert u.msg_info_dict["unit:topic_a.v"] == "m"


def test_batches_read_as_one_write(tmp_path: Path) -> None:
    cols = _cols(120)
    events = [{"t": 0.5, "type": "granted", "reason": "granted"}, {"t": 0.9, "type": "revoked", "reason": "envelope"}]
    write_flight_ulog(tmp_path / "once.ulg", cols, events, META)
    f = FlightULog(tmp_path / "batches.ulg", META)
    for lo in range(0, 120, 50):
        part = {k: v[lo:lo + 50] for k, v in cols.items()}
        f.append(part, [e for e in events if lo * 0.02 <= e["t"] < (lo + 50) * 0.02], interleave=lo % 100 == 0)
    f.close()
    a, b = ULog(str(tmp_path / "once.ulg")), ULog(str(tmp_path / "batches.ulg"))
    assert sorted(d.name for d in a.data_list) == sorted(d.name for d in b.data_list)
    for d in a.data_list:
        other = b.get_dataset(d.name).data
        for k, v in d.data.items():
            assert np.array_equal(v, other[k], equal_nan=v.dtype.kind == "f"), (d.name, k)
    assert [m.message for m in a.logged_messages] == [m.message for m in b.logged_messages]
    # the timers of the envelope are 0 where no detail column was given; setpoints only once there is one
    env = a.get_dataset("merlin_envelope").data
    assert np.all(env["roll_deg_outside_s"] == 0.0)
    assert len(a.get_dataset("trajectory_setpoint").data["timestamp"]) == int(np.sum(cols["t"] > 0.3))


def test_a_file_cut_short_reads_to_its_end(tmp_path: Path) -> None:
    path = tmp_path / "cut.ulg"
    write_flight_ulog(path, _cols(200), [], META)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 37])  # a process killed in the middle of a write
    u = ULog(str(path))
    n = len(u.get_dataset("vehicle_local_position").data["timestamp"])
    assert 195 <= n <= 200
