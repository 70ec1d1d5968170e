"""Real-time figures of ``merlin serve`` under load: tick-period jitter, missed ticks, setpoint latency.

Starts ``merlin serve`` at 250 Hz as a subprocess on loopback, a controller that floods
SET_POSITION_TARGET_LOCAL_NED at 2 kHz (with HEARTBEAT at 10 Hz), and a ground station that asks for every
stream at 100 Hz (MAV_CMD_SET_MESSAGE_INTERVAL) and heartbeats at 1 Hz. serve measures itself (absolute
deadlines from ``time.monotonic_ns``): the start-to-start tick period, how late each tick starts, missed
ticks (a tick starting a whole period late), and for every setpoint a tick used, the time from its arrival
in serve to the end of the core tick that actuated it. Figures are printed as JSON and per window of the
run (median and spread across windows).

    .venv/bin/python benchmarks/bench_serve.py --duration 300
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STREAM_IDS = (0, 1, 24, 30, 32, 33, 74, 242, 245, 53105, 53106)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def controller(port: int, stop: threading.Event, rate_hz: float, sent: list[int]) -> None:
    from pymavlink import mavutil

    m = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=42, source_component=191)
    m.wait_heartbeat(timeout=30)
    period = 1.0 / rate_hz
    n = 0
    t_next = time.monotonic()
    mask = 0b0000_1101_1111_1000  # velocity only, yaw ignored
    while not stop.is_set():
        m.mav.set_position_target_local_ned_send(0, 1, 1, 1, mask, 0, 0, 0, 0.0, 0.0, 0.0, 0, 0, 0, 0, 0)
        n += 1
        if n % int(rate_hz / 10) == 0:
            m.mav.heartbeat_send(18, 8, 0, 0, 0)
            while m.recv_match(blocking=False) is not None:
                pass
        t_next += period
        delay = t_next - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    sent.append(n)


def ground_station(port: int, stop: threading.Event) -> None:
    from pymavlink import mavutil

    m = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=190)
    m.wait_heartbeat(timeout=30)
    for mid in STREAM_IDS:
        m.mav.command_long_send(1, 1, 511, 0, mid, 10_000, 0, 0, 0, 0, 0)  # 100 Hz
    while not stop.is_set():
        m.mav.heartbeat_send(6, 8, 0, 0, 0)
        t_end = time.monotonic() + 1.0
        while time.monotonic() < t_end and not stop.is_set():
            m.recv_match(blocking=True, timeout=0.2)


def run_once(duration_s: float, out: Path, flood_hz: float, rt_priority: int) -> dict[str, object]:
    gcs_port, ctl_port = free_port(), free_port()
    cmd = [sys.executable, "-m", "merlin.cli", "serve", "--rate-hz", "250", "--duration", str(duration_s),
           "--gcs-port", str(gcs_port), "--gcs-bind-port", "0", "--offboard-port", str(ctl_port),
           "--offboard-bind-port", "0", "--out", str(out), "--quiet", "--realtime-priority", str(rt_priority)]
    stop = threading.Event()
    sent: list[int] = []
    threads = [threading.Thread(target=controller, args=(ctl_port, stop, flood_hz, sent), daemon=True),
               threading.Thread(target=ground_station, args=(gcs_port, stop), daemon=True)]
    for th in threads:
        th.start()
    steal0 = _steal_s()
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=duration_s * 3 + 60,
                          env={**os.environ, "PYTHONUNBUFFERED": "1"})
    steal = _steal_s() - steal0 if steal0 is not None else None
    stop.set()
    for th in threads:
        th.join(timeout=5)
    stop_rec = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines() if '"serve_stop"' in x][-1]
    return {"returncode": proc.returncode, "timing": stop_rec["timing"], "links": stop_rec["links"],
            "setpoints_sent": sent[0] if sent else None, "stderr_tail": proc.stderr[-400:],
            # the machine while measuring: 1-minute load average at the end, CPU time the hypervisor took
            # from this virtual machine's CPUs during the run (the "steal" column of /proc/stat)
            "loadavg_1min_end": os.getloadavg()[0], "steal_s": steal}


def _steal_s() -> float | None:
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=300.0, help="seconds per run (default 300)")
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--flood-hz", type=float, default=2000.0)
    ap.add_argument("--realtime-priority", type=int, default=0, help="passed to merlin serve (SCHED_FIFO)")
    a = ap.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(a.runs):
            r = run_once(a.duration, Path(tmp) / f"run{k}", a.flood_hz, a.realtime_priority)
            results.append(r)
            print(json.dumps(r, indent=1), flush=True)
    keys = ("jitter_p99_ms", "missed_ticks", "late_p99_ms", "late_max_ms", "work_p50_ms", "work_p99_ms",
            "work_max_ms", "gc_max_ms", "setpoint_latency_p50_ms", "setpoint_latency_p99_ms",
            "setpoint_latency_max_ms")
    summary = {k: {"median": statistics.median(float(r["timing"][k]) for r in results),  # type: ignore[index]
                   "min": min(float(r["timing"][k]) for r in results),  # type: ignore[index]
                   "max": max(float(r["timing"][k]) for r in results)} for k in keys}  # type: ignore[index]
    print(json.dumps({"runs": len(results), "duration_s": a.duration, "summary": summary}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
