"""Stop one process of a live MAVSDK offboard flight for a while, and see whom the core blames.

A fresh ``merlin serve`` flies the native MAVSDK ``offboard_velocity_body`` flow
(:mod:`tests.serve.px4_examples_native`). Once the example prints "Fly a circle", either serve's process or
the example's is stopped with SIGSTOP for ``--stall`` seconds, ``--times`` times, 1.5 s apart. Printed: the
revocations serve recorded (time, reason, detail) and its closing timing (``late_max_ms``, ``resyncs``,
``controller_gap_in_authority_max_ms``). A stopped serve must revoke nothing (the controller streamed
throughout); a stopped example must be revoked for ``controller_heartbeat`` (docs/benchmarks/serve.md, "A
stalled serve took its own delay for the controller's silence").

    .venv/bin/python benchmarks/stall_serve.py serve --stall 0.6
    .venv/bin/python benchmarks/stall_serve.py example --stall 0.6
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.serve.conftest import start_serve, stop  # noqa: E402

TIMING = ("late_max_ms", "resyncs", "controller_gap_in_authority_max_ms", "controller_gap_end_s")


def _events(out: Path) -> list[dict[str, object]]:
    p = out / "events.jsonl"
    return [json.loads(line) for line in p.read_text().splitlines() if line.strip()] if p.exists() else []


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("which", choices=("serve", "example"))
    ap.add_argument("--stall", type=float, default=0.6)
    ap.add_argument("--times", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        sp = start_serve(Path(tmp))
        try:
            p = sp.spawn("-m", "tests.serve.px4_examples_native", "offboard_velocity_body",
                         f"udpin://0.0.0.0:{sp.ctl_port}")
            assert p.stdout is not None
            stalled = False
            for line in iter(p.stdout.readline, ""):
                if "Fly a circle" in line and not stalled:
                    stalled = True
                    time.sleep(1.0)
                    pid = sp.proc.pid if args.which == "serve" else p.pid
                    for _ in range(args.times):
                        os.kill(pid, signal.SIGSTOP)
                        time.sleep(args.stall)
                        os.kill(pid, signal.SIGCONT)
                        time.sleep(1.5)
                if "EXAMPLE FINISHED" in line:
                    break
        finally:
            stop(sp)
        events = _events(sp.out)
        print("revoked:", [(e["t"], e["reason"], e.get("reason_detail")) for e in events if e["type"] == "revoked"])
        stops = [e for e in events if e["type"] == "serve_stop"]
        timing = stops[-1]["timing"] if stops else {}
        assert isinstance(timing, dict)
        print("timing:", {k: timing.get(k) for k in TIMING})


if __name__ == "__main__":
    main()
