"""MAVSDK-Python's offboard example program, unchanged, through ``merlin guard`` in front of ``merlin serve``
standing in for PX4 SITL (``merlin serve --autopilot-only``, at PX4 SITL's home where the example's
coordinates are). The program is tests/serve/px4_examples.py's ``offboard_velocity_ned`` (the calls, order
and waits of MAVSDK-Python's example). It starts OFFBOARD right after its first setpoint, on the ground,
as PX4 accepts: the guard holds the request (COMMAND_ACK IN_PROGRESS) until the controller's liveness rule
is met, then the core grants it; the example flies to its end and releases with AUTO.LOITER.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from tests.guard.test_guard_flight import ROOT, free_port
from tests.serve.px4_examples import PX4_HOME

pytest.importorskip("mavsdk_grpc", reason="the gRPC MAVSDK-Python (pip install mavsdk-grpc) runs the example")
pytestmark = pytest.mark.integration

HOME = f"home: {{lat_deg: {PX4_HOME[0]}, lon_deg: {PX4_HOME[1]}, alt_amsl_m: {PX4_HOME[2]}}}\n"


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_mavsdk_offboard_velocity_ned_runs_unchanged_through_the_guard(tmp_path: Path) -> None:
    serve_cfg = tmp_path / "serve.yaml"
    serve_cfg.write_text(HOME)
    guard_cfg = tmp_path / "guard.yaml"
    guard_cfg.write_text(HOME + "geofence:\n  inclusion_circles:\n    - {name: t, center_ne_m: [0.0, 0.0], radius_m: 60.0}\n")
    ap, ctl, gcs = free_port(), free_port(), free_port()
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    procs = [
        subprocess.Popen([sys.executable, "-m", "merlin.cli", "serve", "--autopilot-only", "--config", str(serve_cfg),
                          "--gcs-port", str(gcs), "--gcs-bind-port", "0", "--offboard-port", str(ap), "--offboard-bind-port", "0",
                          "--out", str(tmp_path / "serve"), "--duration", "200", "--quiet"],
                         cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env),
        subprocess.Popen([sys.executable, "-m", "merlin.cli", "guard", "--autopilot", f"udpin:127.0.0.1:{ap}",
                          "--controller", f"udpout:127.0.0.1:{ctl}", "--config", str(guard_cfg),
                          "--out", str(tmp_path / "guard"), "--duration", "200"],
                         cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env),
    ]
    try:
        ex = subprocess.run([sys.executable, "-m", "tests.serve.px4_examples", "offboard_velocity_ned",
                             f"udpin://0.0.0.0:{ctl}", str(_free_tcp_port())],
                            cwd=ROOT, capture_output=True, text=True, env=env, timeout=180)
        out = ex.stdout + ex.stderr
        assert "EXAMPLE FINISHED" in out and "failed with error code" not in out, out[-3000:]
        assert "-- Go down 1 m/s" in out and "-- Stopping offboard" in out, out[-3000:]
        events = (tmp_path / "guard" / "events.jsonl").read_text()
        assert '"guard_request_held"' in events and '"type": "granted"' in events
        assert '"type": "revoked"' not in events and '"type": "denied"' not in events
    finally:
        for p in procs:
            p.terminate()
            p.wait(timeout=20)
