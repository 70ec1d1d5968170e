"""What a real-time tick costs after sleeping, against the same work run back to back.

``merlin serve`` sleeps between its 4 ms ticks; ``merlin sim`` runs its ticks back to back. On the 2-core
virtual machines of this workplace the same work costs about twice the CPU after a sleep. This
script measures that effect two ways:

- ``--part synthetic``: a fixed piece of pure-Python work (about 0.3 ms), timed with the thread's CPU clock,
  back to back and after sleeps of 0.5, 1 and 3 ms (median of 1,500 repetitions per run, several runs);
- ``--part serve``: ``merlin serve`` on the built-in defaults, disarmed on the ground, for ``--seconds`` of
  simulated time at ``--speedup 1`` (the real-time schedule: ~3 ms of sleep per tick) and at 3 (the same
  ticks, ~0.8 ms of sleep each). The process's CPU time less its start-up, per tick, and the median of
  serve's own per-tick work (``serve_stop``'s ``work_p50_ms``).

    .venv/bin/python benchmarks/bench_wakeup.py --part all --runs 3
"""

from __future__ import annotations

import argparse
import json
import resource
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GAPS_S = (0.0, 0.0005, 0.001, 0.003)


def _work() -> int:
    s = 0
    d: dict[int, int] = {}
    for i in range(3000):
        s += i * i
        d[i & 63] = s
    return s


def synthetic_once(gap_s: float, n: int = 1500) -> float:
    """Median thread CPU µs of one piece of work, each piece followed by a sleep of ``gap_s``."""
    ts = []
    for _ in range(n):
        t0 = time.thread_time_ns()
        _work()
        ts.append(time.thread_time_ns() - t0)
        if gap_s:
            time.sleep(gap_s)
    return statistics.median(ts) / 1e3


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def serve_once(speedup: float, seconds: float) -> dict[str, float]:
    """One ``merlin serve`` run; its CPU per tick (start-up subtracted) and its own median tick work."""
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "serve"
        gcs, ctl = _free_port(), _free_port()  # nobody listens there: serve streams to an empty port
        cmd = [sys.executable, "-m", "merlin.cli", "serve", "--gcs-port", str(gcs), "--gcs-bind-port", "0",
               "--offboard-port", str(ctl), "--offboard-bind-port", "0", "--out", str(out),
               "--duration", str(seconds), "--speedup", str(speedup), "--quiet"]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        events = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines() if x.strip()]
    timing = next(e for e in events if e["type"] == "serve_stop")["timing"]
    return {"cpu_s": cpu, "ticks": float(timing["ticks"]), "work_p50_ms": float(timing["work_p50_ms"])}


def _spread(xs: list[float]) -> str:
    return f"{statistics.median(xs):.3g} ({min(xs):.3g}-{max(xs):.3g})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part", choices=["synthetic", "serve", "all"], default="all")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=30.0, help="simulated seconds per serve run")
    args = ap.parse_args()
    if args.part in ("synthetic", "all"):
        res: dict[float, list[float]] = {g: [] for g in GAPS_S}
        for _ in range(args.runs):
            for g in GAPS_S:  # interleaved, so a change in the machine's load touches every gap alike
                res[g].append(synthetic_once(g))
        print("| sleep after each piece of work | CPU µs per piece, median (min-max) of runs |")
        print("|---|---|")
        for g in GAPS_S:
            print(f"| {g * 1e3:g} ms | {_spread(res[g])} |")
    if args.part in ("serve", "all"):
        # start-up, measured as a run of a tenth of a second, is subtracted from each run's CPU
        start = [serve_once(1.0, 0.1)["cpu_s"] for _ in range(args.runs)]
        startup = statistics.median(start)
        rows: dict[float, list[dict[str, float]]] = {1.0: [], 3.0: []}
        for _ in range(args.runs):
            for sp in rows:
                rows[sp].append(serve_once(sp, args.seconds))
        print(f"\nserve start-up (0.1 s runs): {_spread(start)} s CPU, subtracted below")
        print("| --speedup | ticks | CPU ms per tick | serve's own work_p50 ms |")
        print("|---|---|---|---|")
        for sp, rs in rows.items():
            per_tick = [(r["cpu_s"] - startup) / r["ticks"] * 1e3 for r in rs]
            print(f"| {sp:g} | {rs[0]['ticks']:.0f} | {_spread(per_tick)} | {_spread([r['work_p50_ms'] for r in rs])} |")


if __name__ == "__main__":
    main()
