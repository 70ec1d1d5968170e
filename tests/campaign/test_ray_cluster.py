"""The Ray backend on a cluster address, not only on the local instance it starts itself.

A Ray head node is started as its own process (``ray start --head --block``, what a cluster operator
runs), and ``merlin campaign --backend ray --address HOST:PORT`` is run unchanged against it. The runs it
flies must be the same runs, bit for bit, as the local backend's with the same campaign seed.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
TINY = str(HERE / "tiny.yaml")

pytestmark = [pytest.mark.integration, pytest.mark.slow]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _digests(out: Path) -> dict[str, str]:
    rows = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines() if line.strip()]
    assert all(r["status"] == "ok" for r in rows), rows
    return {r["run_id"]: r["log_digest_sha256"] for r in rows}


def test_campaign_runs_unchanged_on_a_ray_cluster_address(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    ray_exe = Path(sys.executable).with_name("ray")
    if not ray_exe.exists():
        pytest.skip("the ray command-line tool is not installed beside this Python")
    port = _free_port()
    # One authentication mode on both sides (Ray >= 2.5x may find a token file in ~/.ray otherwise).
    env = {**os.environ, "RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}
    temp = Path("/tmp") / f"merlin-ray-{port}"  # Ray's socket paths must stay short: not under tmp_path
    head = subprocess.Popen(
        [str(ray_exe), "start", "--head", "--block", f"--port={port}", "--num-cpus=1",
         "--include-dashboard=false", "--disable-usage-stats", f"--temp-dir={temp}"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while True:  # the head is up when its GCS port accepts connections
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert head.poll() is None, "ray start --head exited"
                assert time.monotonic() < deadline, "the Ray head did not come up in 120 s"
                time.sleep(0.5)
        cmd = [sys.executable, "-m", "merlin.cli", "campaign", TINY, "--runs", "2", "--seed", "11"]
        on_cluster = subprocess.run(
            [*cmd, "--backend", "ray", "--address", f"127.0.0.1:{port}", "--out", str(tmp_path / "cluster")],
            cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
        assert on_cluster.returncode == 0, on_cluster.stderr[-3000:]
        local = subprocess.run([*cmd, "--workers", "1", "--out", str(tmp_path / "local")],
                               cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
        assert local.returncode == 0, local.stderr[-3000:]
        got, want = _digests(tmp_path / "cluster"), _digests(tmp_path / "local")
        assert len(got) == 2
        assert got == want
    finally:
        try:
            os.killpg(head.pid, signal.SIGTERM)  # --block: the head stops the processes it started
            head.wait(timeout=60)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            os.killpg(head.pid, signal.SIGKILL)
        shutil.rmtree(temp, ignore_errors=True)
