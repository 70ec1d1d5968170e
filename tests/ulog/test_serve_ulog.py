"""`merlin serve` writes flight.ulg beside flight.tlog: PX4's topics at 50 Hz, Merlin's own, the events."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pyulog import ULog

pytestmark = pytest.mark.integration


def test_serve_writes_a_ulog(tmp_path: Path) -> None:
    from tests.serve.conftest import start_serve, stop

    sp = start_serve(tmp_path, duration_s=4.0)
    try:
        assert sp.proc.wait(timeout=120) == 0
    finally:
        stop(sp)
    u = ULog(str(sp.out / "flight.ulg"))
    assert not u.file_corruption
    lp = u.get_dataset("vehicle_local_position").data
    t = (lp["timestamp"] - u.start_timestamp) / 1e6
    assert 190 <= len(t) <= 200 and np.allclose(np.diff(t), 0.02, atol=1e-6)  # 4 s at 50 Hz
    assert u.msg_info_dict["ver_hw"] == "MERLIN_SERVE"
    for topic in ("vehicle_attitude", "vehicle_status", "merlin_authority", "merlin_envelope", "merlin_fence"):
        assert len(u.get_dataset(topic).data["timestamp"]) == len(t)
    assert "ENV_ROLL_MAX" in u.initial_parameters
    assert np.all(u.get_dataset("vehicle_status").data["arming_state"] == 1)  # never armed: nobody asked


def test_a_parameter_change_is_in_the_ulog(tmp_path: Path) -> None:
    """PARAM_SET on the ground changes the configuration: the ULog has the parameter's change, as PX4
    logs one (Flight Review's "changed parameters"), and the config_changed record as a logged message."""
    import time

    from tests.serve.conftest import gcs_connection, start_serve, stop, wait_for

    sp = start_serve(tmp_path)
    try:
        m = gcs_connection(sp.gcs_port)
        m.mav.param_set_send(1, 1, b"ENV_ROLL_MAX", 25.0, 9)  # MAV_PARAM_TYPE_REAL32
        pv = wait_for(m, lambda x: x.get_type() == "PARAM_VALUE" and x.param_id == "ENV_ROLL_MAX")
        assert pv is not None and pv.param_value == 25.0
        time.sleep(2.0)  # a batch or two written after the change
    finally:
        stop(sp)
    u = ULog(str(sp.out / "flight.ulg"))
    assert u.initial_parameters["ENV_ROLL_MAX"] != 25.0
    assert [(name, value) for _, name, value in u.changed_parameters] == [("ENV_ROLL_MAX", 25.0)]
    assert any(msg.message.startswith("CONFIG_CHANGED") for msg in u.logged_messages)
