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
