"""PX4 drop-in timings of ``merlin serve``, measured end to end on loopback in real time:

* ``offboard``: a pymavlink client as PX4's docs write one (``tests.serve.px4_offboard_client``, MAVSDK's
  default ground-station HEARTBEAT type) asks for OFFBOARD right after its first setpoint: the time from that
  setpoint to the COMMAND_ACK ACCEPTED, and how many IN_PROGRESS came before it; then the client is killed
  (SIGKILL): the silence the watchdog saw at the revocation (core clock, from ``events.jsonl``) and the wall
  time from the kill to the ground station's HEARTBEAT leaving OFFBOARD.
* ``takeoff``: PX4's offboard tutorial on the ground (5 m position setpoint, OFFBOARD, arm): the height at
  which the request went to the core and the time from the arming to the grant.

    .venv/bin/python benchmarks/bench_px4_dropin.py --runs 3

Prints one JSON object per run and a summary; a few minutes for three runs of each.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.serve.conftest import (  # noqa: E402  (the serve test harness: ports, process handling)
    arm_and_takeoff,
    gcs_connection,
    lines_until,
    start_serve,
    stop,
    wait_for,
)


def _t(line: str) -> float:
    found = re.search(r"t=([0-9.]+)$", line)
    return float(found.group(1)) if found else float("nan")


def run_offboard(tmp: Path) -> dict[str, Any]:
    sp = start_serve(tmp)
    try:
        m = gcs_connection(sp.gcs_port)
        arm_and_takeoff(m)
        ctl = sp.spawn("-m", "tests.serve.px4_offboard_client", "--url", f"udpin:127.0.0.1:{sp.ctl_port}",
                       "--flow", "velocity", "--fly-s", "600")
        out = lines_until(ctl, "mode OFFBOARD", timeout_s=60)
        acks = [(int(mm.group(1)), _t(x)) for x in out if (mm := re.search(r"ack command=176 result=(\d+) ", x))]
        assert wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1
                        and (x.custom_mode >> 16) & 0xFF == 6) is not None
        t_kill = time.monotonic()
        os.kill(ctl.pid, signal.SIGKILL)
        hb = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1
                      and (x.custom_mode >> 16) & 0xFF != 6)
        wall_s = time.monotonic() - t_kill if hb is not None else float("nan")
    finally:
        stop(sp)
    rv = next(e for e in sp.events() if e["type"] == "revoked")
    accepted = [t for r, t in acks if r == 0]
    return {"flow": "offboard", "first_setpoint_to_accepted_s": accepted[0] if accepted else None,
            "in_progress": sum(1 for r, _ in acks if r == 5), "revoked_reason": rv["reason"],
            "silence_at_revocation_s": rv["reason_detail"]["value"], "watchdog_s": rv["reason_detail"]["limit"],
            "kill_to_mode_change_wall_s": round(wall_s, 3)}


def run_takeoff(tmp: Path) -> dict[str, Any]:
    sp = start_serve(tmp)
    try:
        m = gcs_connection(sp.gcs_port)
        sp.spawn("-m", "tests.serve.px4_offboard_client", "--url", f"udpin:127.0.0.1:{sp.ctl_port}",
                 "--flow", "takeoff", "--height", "5", "--prestream-s", "3", "--fly-s", "120")
        off = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1
                       and (x.custom_mode >> 16) & 0xFF == 6, timeout_s=90)
        assert off is not None, "never handed over"
    finally:
        stop(sp)
    ev = sp.events()
    arm_t = next(e["t"] for e in ev if e["type"] == "command_ack" and e.get("command") == "ARM")
    req = next(e for e in ev if e.get("phase") == "requested")
    grant_t = next(e["t"] for e in ev if e["type"] == "authority" and e.get("to") == "EXPERIMENTAL")
    return {"flow": "takeoff", "request_alt_m": req["alt_m"], "arm_to_grant_s": round(grant_t - arm_t, 3)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args(argv)
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as d:
        for k in range(args.runs):
            for fn in (run_offboard, run_takeoff):
                row = fn(Path(d) / f"{fn.__name__}{k}")
                print(json.dumps(row), flush=True)
                rows.append(row)
    off = [r for r in rows if r["flow"] == "offboard"]
    tk = [r for r in rows if r["flow"] == "takeoff"]

    def span(vals: list[float]) -> str:
        return f"median {statistics.median(vals):.3f}, min {min(vals):.3f}, max {max(vals):.3f}"

    print(json.dumps({
        "runs": args.runs,
        "first_setpoint_to_accepted_s": span([r["first_setpoint_to_accepted_s"] for r in off]),
        "in_progress": sorted({r["in_progress"] for r in off}),
        "silence_at_revocation_s": span([r["silence_at_revocation_s"] for r in off]),
        "kill_to_mode_change_wall_s": span([r["kill_to_mode_change_wall_s"] for r in off]),
        "takeoff_request_alt_m": span([r["request_alt_m"] for r in tk]),
        "takeoff_arm_to_grant_s": span([r["arm_to_grant_s"] for r in tk]),
    }), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
