"""The Ray backend on a cluster address, not only on the local instance it starts itself.

A Ray head node is started as its own process (``ray start --head --block``, what a cluster operator
runs), and ``merlin campaign --backend ray --address HOST:PORT`` is run unchanged against it. The runs it
flies must be the same runs, bit for bit, as the local backend's with the same campaign seed.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from tests.ports import reserve_port

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
TINY = str(HERE / "tiny.yaml")

pytestmark = [pytest.mark.integration, pytest.mark.slow]


def _digests(out: Path) -> dict[str, str]:
    rows = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines() if line.strip()]
    assert all(r["status"] == "ok" for r in rows), rows
    return {r["run_id"]: r["log_digest_sha256"] for r in rows}


NODE_ID = re.compile(r"node_id=([0-9a-f]{40,})")


class _Node:
    """One ``ray start --block`` node in its own session: its process group holds its raylet and agents, and
    everything it started is ended by pid (never ``ray stop``, which would stop every Ray on the machine)."""

    def __init__(self, ray_exe: Path, args: list[str], temp: Path, env: dict[str, str]) -> None:
        self.temp = temp
        self.log = temp.with_suffix(".log")
        self._cmd = [str(ray_exe), "start", "--block", "--num-cpus=1", "--node-ip-address=127.0.0.1",
                     "--disable-usage-stats", f"--temp-dir={temp}", *args]
        self._env = env
        self._launch()

    def _launch(self) -> None:
        with self.log.open("wb") as log:
            self.proc = subprocess.Popen(self._cmd, env=self._env, stdout=log, stderr=subprocess.STDOUT,
                                         start_new_session=True)

    def wait_started(self, timeout_s: float = 180.0) -> str:
        """Block until the node is up; its Ray node id (from its raylet's log)."""
        deadline = time.monotonic() + timeout_s
        while True:
            ids = [m.group(1) for f in self.temp.glob("session_*/logs/raylet.out")
                   for m in [NODE_ID.search(f.read_text(errors="replace"))] if m]
            if ids and "Ray runtime started" in self.log.read_text(errors="replace"):
                return ids[0]
            assert self.proc.poll() is None, f"ray start exited:\n{self.log.read_text()[-3000:]}"
            assert time.monotonic() < deadline, f"the Ray node did not come up in {timeout_s:.0f} s"
            time.sleep(0.5)

    def start_waiting(self, attempts: int = 5, pause_s: float = 15.0) -> str:
        """:meth:`wait_started`, starting the node again (up to ``attempts`` times in all) when ``ray start``
        itself gives up: on a loaded machine Ray's own start-up may time out ("The current node timed out
        during startup", GCS deadline exceeded) before anything of Merlin's runs; an operator restarts it.
        Ray waits a fixed 30 s for its raylet to register; beside the rest of the suite on two cores three
        starts in a row once took longer, so each new attempt first waits out the burst (``pause_s`` times
        the attempt's number)."""
        for attempt in range(attempts):
            try:
                return self.wait_started()
            except AssertionError as exc:
                if self.proc.poll() is None or attempt == attempts - 1:
                    raise AssertionError(f"{exc}\n(start attempt {attempt + 1} of {attempts})") from exc
            self.kill()
            shutil.rmtree(self.temp, ignore_errors=True)
            time.sleep(pause_s * (attempt + 1))
            self._launch()
        raise AssertionError("unreachable")

    def pids(self) -> set[int]:
        """This node's processes: its process group, and any child that left it (by parent pid)."""
        procs = {}
        for d in Path("/proc").iterdir():
            if d.name.isdigit():
                with contextlib.suppress(OSError, IndexError, ValueError):
                    fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
                    procs[int(d.name)] = (int(fields[1]), int(fields[2]))  # ppid, pgid
        mine = {p for p, (_, pgid) in procs.items() if pgid == self.proc.pid} | {self.proc.pid}
        grew = True
        while grew:
            more = {p for p, (ppid, _) in procs.items() if ppid in mine} - mine
            mine |= more
            grew = bool(more)
        return mine

    def kill(self) -> None:
        """SIGKILL to every process of this node, as a machine that is lost: nothing shuts down cleanly."""
        for pid in self.pids():
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, signal.SIGKILL)
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(timeout=30)

    def close(self) -> None:
        self.kill()
        shutil.rmtree(self.temp, ignore_errors=True)
        self.log.unlink(missing_ok=True)


def test_campaign_runs_unchanged_on_a_ray_cluster_address(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    ray_exe = Path(sys.executable).with_name("ray")
    if not ray_exe.exists():
        pytest.skip("the ray command-line tool is not installed beside this Python")
    port = reserve_port()
    # One authentication mode on both sides (Ray >= 2.5x may find a token file in ~/.ray otherwise).
    env = {**os.environ, "RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}
    # Ray's socket paths must stay short: not under tmp_path
    head = _Node(ray_exe, ["--head", f"--port={port}", "--include-dashboard=false"],
                 Path("/tmp") / f"merlin-ray-{port}", env)
    try:
        # Up means its raylet registered, not only its GCS port open: a driver that connects in between
        # finds no node ("No node info found") when the machine is loaded.
        head.start_waiting()
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
        head.close()


# --------------------------------------------------------------------------- two nodes, one killed

def _records(out: Path) -> list[dict]:
    path = out / "results.jsonl"
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        with contextlib.suppress(ValueError):
            rows.append(json.loads(line))
    return rows


def test_campaign_on_two_nodes_survives_losing_one(tmp_path: Path) -> None:
    """A two-node cluster (a head and a second node, one CPU each, on this machine) flies a 12-run campaign
    with ``--address``; runs are flown on both nodes; the second node is killed (SIGKILL to all its
    processes) while runs are still to fly; the campaign completes on the head (Ray flies the lost
    tasks again), and every run's verdict and decision digest equals a local run's with the same seed."""
    pytest.importorskip("ray")
    ray_exe = Path(sys.executable).with_name("ray")
    if not ray_exe.exists():
        pytest.skip("the ray command-line tool is not installed beside this Python")
    port = reserve_port()
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
    env |= {"RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}
    runs = 12
    # tiny.yaml flown for 30 s instead of 5: a run must last long enough (about a second here) that the
    # second node, whose first worker takes seconds to start, flies some while runs remain to be flown
    scenario = tmp_path / "two_node.yaml"
    doc = yaml.safe_load(Path(TINY).read_text())
    scenario.write_text(yaml.safe_dump({**doc, "name": "two_node", "duration_s": 30}, sort_keys=False))
    head = second = None
    try:
        head = _Node(ray_exe, ["--head", f"--port={port}", "--include-dashboard=false"],
                     Path("/tmp") / f"merlin-ray-{port}-h", env)
        head_id = head.start_waiting()
        second = _Node(ray_exe, [f"--address=127.0.0.1:{port}"], Path("/tmp") / f"merlin-ray-{port}-w", env)
        second_id = second.start_waiting()
        assert head_id != second_id

        cmd = [sys.executable, "-m", "merlin.cli", "campaign", str(scenario), "--runs", str(runs), "--seed", "11",
               "--quiet"]
        out = tmp_path / "cluster"
        err = tmp_path / "cluster.err"  # a file, not a pipe: nobody reads a pipe while the campaign runs
        with err.open("wb") as err_f:
            campaign = subprocess.Popen(
                [*cmd, "--backend", "ray", "--address", f"127.0.0.1:{port}", "--out", str(out)],
                cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=err_f)
        try:
            # the second node is lost once it has flown a run, while runs remain to be flown
            deadline = time.monotonic() + 600
            while not any(r["worker"].get("ray_node_id") == second_id for r in _records(out)):
                assert campaign.poll() is None, err.read_text(errors="replace")[-3000:]
                assert time.monotonic() < deadline, "no run reached the second node in 600 s"
                time.sleep(0.2)
            second.kill()
            done_at_kill = len(_records(out))
            campaign.wait(timeout=900)
        finally:
            if campaign.poll() is None:
                campaign.kill()
        assert campaign.returncode == 0, err.read_text(errors="replace")[-3000:]
        # one run the second node finished just before it was killed may be stored just after
        assert done_at_kill + 1 < runs, "the campaign ended before the node was lost: nothing was shown"

        rows = _records(out)
        assert sorted(r["run_id"] for r in rows) == sorted({r["run_id"] for r in rows}), "a run stored twice"
        got = {r["run_id"]: r for r in rows}
        assert len(got) == runs and all(r["status"] == "ok" for r in rows), rows
        # the nodes were started without thread limits: the driver gives its tasks the local workers' limits
        # (Ray itself sets OMP_NUM_THREADS to a task's CPUs; OpenBLAS's limit is Merlin's to give)
        assert all(r["threads"] == {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "opencv": 1}
                   for r in rows), [r["threads"] for r in rows]
        nodes = [r["worker"]["ray_node_id"] for r in rows]
        assert set(nodes) == {head_id, second_id}
        # after the loss, every run still to fly (and any lost in flight) is flown by the head
        assert set(nodes[done_at_kill + 1:]) == {head_id}

        local = subprocess.run([*cmd, "--workers", "1", "--out", str(tmp_path / "local")],
                               cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
        assert local.returncode == 0, local.stderr[-3000:]
        want = {r["run_id"]: r for r in _records(tmp_path / "local")}
        for recs in (got, want):
            for r in recs.values():
                assert r["log_digest_sha256"], r
        verdict = lambda r: (r["passed"], r["log_digest_sha256"], r["expectations"], r["metrics"])  # noqa: E731
        assert {k: verdict(r) for k, r in got.items()} == {k: verdict(r) for k, r in want.items()}
    finally:
        for node in (second, head):
            if node is not None:
                node.close()
