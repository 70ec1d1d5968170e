"""Campaign throughput: runs per minute on 1 and 2 local workers and on a local Ray instance, and the
scheduling overhead per run (workers' capacity not spent inside ``run_scenario``).

    .venv/bin/python benchmarks/bench_campaign.py                 # small: 8 runs per configuration
    .venv/bin/python benchmarks/bench_campaign.py --runs 1000     # the 1,000-run mixed campaign

    .venv/bin/python benchmarks/bench_campaign.py --runs 100 --configs ray2 --repeats 3
    .venv/bin/python benchmarks/bench_campaign.py --runs 100 --configs cluster2   # a two-node Ray cluster

``cluster2`` starts a real two-node Ray cluster on loopback (``ray start --head`` and a second
``ray start --address``, one CPU each, each in its own process group) and flies the campaign with
``--address`` against it, as an operator would on two machines; both nodes are ended by process group
afterwards (never ``ray stop``, which would end every Ray on the machine).

The mixed campaign is every file in ``examples/campaigns/`` (docs/campaigns.md lists them: nominal flight,
every controller fault, every sensor / link / battery / wind fault on the fusion EKF, GPS faults with the
camera and visual odometry, autopilot-lane and IMU-lane redundancy, fence approaches, the JSBSim fixed
wing). Adding a file changes the mix and so the mean run time: compare runs per minute only between
measurements of the same set of files (the JSON names them). Each configuration flies a fresh directory
with the same seed, so all fly the same runs. The machine is shared: numbers vary with its load.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from merlin.campaign.aggregate import timing  # noqa: E402
from merlin.campaign.scheduler import CampaignOptions, run_campaign  # noqa: E402


@contextlib.contextmanager
def two_node_cluster() -> Iterator[str]:
    """A head and a second Ray node on loopback, one CPU each; yields the head's address."""
    with socket.socket() as sk:
        sk.bind(("127.0.0.1", 0))
        port = sk.getsockname()[1]
    ray_exe = Path(sys.executable).with_name("ray")
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
    env |= {"RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}
    nodes: list[subprocess.Popen] = []
    logs: list[Path] = []
    try:
        for i, extra in enumerate((["--head", f"--port={port}", "--include-dashboard=false"],
                                   [f"--address=127.0.0.1:{port}"])):
            log = Path(tempfile.gettempdir()) / f"merlin-bench-ray-{port}-{i}.log"
            logs.append(log)
            with log.open("wb") as f:
                nodes.append(subprocess.Popen(
                    [str(ray_exe), "start", "--block", "--num-cpus=1", "--node-ip-address=127.0.0.1",
                     "--disable-usage-stats", f"--temp-dir={tempfile.gettempdir()}/merlin-bench-ray-{port}-{i}",
                     *extra], env=env, stdout=f, stderr=subprocess.STDOUT, start_new_session=True))
            deadline = time.monotonic() + 300
            while "Ray runtime started" not in log.read_text(errors="replace"):
                if nodes[-1].poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"ray node {i} did not start:\n{log.read_text(errors='replace')[-2000:]}")
                time.sleep(0.5)
        yield f"127.0.0.1:{port}"
    finally:
        for proc in reversed(nodes):
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(proc.pid, signal.SIGKILL)
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=30)
        for log in logs:
            log.unlink(missing_ok=True)


@contextlib.contextmanager
def _campaign_dir(keep: Path | None, name: str) -> Iterator[Path]:
    if keep is None:
        with tempfile.TemporaryDirectory() as d:
            yield Path(d)
        return
    d = keep / name
    if d.exists() and any(d.iterdir()):
        raise SystemExit(f"{d} is not empty: a kept campaign directory would be resumed, not flown")
    d.mkdir(parents=True, exist_ok=True)
    yield d


def _compare(digests: dict[str, dict[str, str | None]]) -> dict[str, dict[str, int]]:
    """Each configuration's runs against the first configuration's, by the decision log's digest: the same
    seed must fly the same runs to the same decisions whatever the backend."""
    if not digests:
        return {}
    first_name, first = next(iter(digests.items()))
    out = {}
    for name, d in digests.items():
        if name == first_name:
            continue
        common = set(first) & set(d)
        out[name] = {"runs_compared": len(common), "same_digest": sum(1 for k in common if first[k] == d[k]),
                     "missing_runs": len(set(first) ^ set(d))}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--runs", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=1, help="repeat each configuration (median and spread)")
    ap.add_argument("--configs", default="local1,local2,ray2")
    ap.add_argument("--keep", type=Path, default=None,
                    help="keep each configuration's campaign directory under KEEP/<config> (KEEP/<config>-<n> with "
                         "--repeats; else a temporary one); one that is not empty is refused, not resumed")
    args = ap.parse_args()
    scenarios = tuple(str(p) for p in sorted((ROOT / "examples" / "campaigns").glob("*.yaml")))
    results: dict = {}
    digests: dict[str, dict[str, str | None]] = {}
    for name in args.configs.split(","):
        backend = "ray" if name.startswith(("ray", "cluster")) else "local"
        workers = int(name.removeprefix("ray").removeprefix("local").removeprefix("cluster"))
        if name.startswith("cluster") and workers != 2:
            raise SystemExit("cluster2 is the one cluster configuration (two nodes, one CPU each)")
        rates, overheads, fracs, after, startups, inside = [], [], [], [], [], []
        for rep in range(args.repeats):
            kept = name if args.repeats == 1 else f"{name}-{rep + 1}"
            with _campaign_dir(args.keep, kept) as d, (
                    two_node_cluster() if name.startswith("cluster") else contextlib.nullcontext(None)) as address:
                o = run_campaign(CampaignOptions(scenarios=scenarios, runs=args.runs, out=Path(d), seed=1,
                                                 backend=backend, address=address, workers=workers, quiet=False))
                t = timing(list(o.records.values()), o.wall_s, workers, o.flown_now, o.startup_s)
                passed = sum(1 for r in o.records.values() if r.get("passed"))
                errors = sum(1 for r in o.records.values() if r.get("status") == "error")
                digests[name] = {k: r.get("log_digest_sha256") for k, r in o.records.items()}
            rates.append(t["runs_per_min"])
            overheads.append(t["overhead_per_run_s"])
            fracs.append(t["overhead_fraction"])
            after.append(t["overhead_fraction_after_startup"])
            startups.append(t["startup_s"])
            inside.append(t["worker_overhead_per_run_s"])
            print(f"{name}: {t['runs_per_min']:.2f} runs/min, mean run {t['mean_run_wall_s']:.2f} s, overhead/run "
                  f"{t['overhead_per_run_s']:.2f} s ({100 * t['overhead_fraction']:.1f} %), after start-up "
                  f"{100 * t['overhead_fraction_after_startup']:.1f} %, start-up {t['startup_s']:.1f} s, in-worker "
                  f"{t['worker_overhead_per_run_s']:.3f} s/run, {passed} passed, {errors} errors", flush=True)
        results[name] = {"runs": args.runs, "files": [Path(p).name for p in scenarios],
                         "runs_per_min_median": statistics.median(rates),
                         "runs_per_min_spread": [min(rates), max(rates)],
                         "overhead_per_run_s_median": statistics.median(overheads),
                         "overhead_fraction_median": statistics.median(fracs),
                         "overhead_fraction_after_startup_median": statistics.median(after),
                         "startup_s_median": statistics.median(startups),
                         "worker_overhead_per_run_s_median": statistics.median(inside)}
    if "local1" in results and "local2" in results:
        results["speedup_2_over_1"] = results["local2"]["runs_per_min_median"] / results["local1"]["runs_per_min_median"]
    results["identical_to_first"] = _compare(digests)
    print(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
