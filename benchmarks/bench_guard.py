"""Latency the guard adds between a controller's setpoint and its arrival at the autopilot, and the guard's
CPU use, with setpoints at 50 Hz.

Setup on loopback: the simulated autopilot of tests/guard (PX4 dialect, telemetry at 50 Hz, i.e. the guard
also routes ~250 telemetry frames/s the other way), ``merlin guard`` as its own process, and a controller
socket sending SET_POSITION_TARGET_LOCAL_NED at 50 Hz whose ``x`` carries a sequence number. Latency is
the autopilot's receive time minus the controller's send time (same clock, monotonic), so it includes
two loopback hops; the direct path (controller -> autopilot, no guard) is measured in the same run and
reported beside it. CPU: the guard process's user+system time (/proc/PID/stat) over the measured window
divided by the wall time. The autopilot is on the ground in its hold mode: setpoints pass the gate as
PX4's proof of life, the same FORWARD path as under EXPERIMENTAL authority.

    PYTHONPATH=. MERLIN_USE_SOURCES=1 nice -n 10 python benchmarks/bench_guard.py --runs 3 --seconds 15

``--realtime-priority N`` runs the guard SCHED_FIFO (``merlin guard --realtime-priority``); a nice value given
to this script applies to the guard too unless it runs real-time. ``--sched-slice-us US`` passes the guard's own option
(a short EEVDF slice, merlin/guard/scheduling.py; 0, the default, the kernel's own slice).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mav

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from merlin.guard.dialects import Dialect  # noqa: E402
from tests.guard.sim_autopilot import SimAutopilot  # noqa: E402


class TimedSim(SimAutopilot):
    def __init__(self, *a: object, **k: object) -> None:
        super().__init__(*a, **k)  # type: ignore[arg-type]
        self.arrivals: dict[int, float] = {}

    def _handle(self, msg: object, now: float) -> None:
        if msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED":  # type: ignore[attr-defined]
            self.arrivals[int(msg.x)] = time.monotonic()  # type: ignore[attr-defined]
        super()._handle(msg, now)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def cpu_s(pid: int) -> float:
    f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")


def stream(sock: socket.socket, dest: tuple[int, int] | tuple[str, int], seconds: float, sim: TimedSim,
           base: int) -> list[float]:
    m = mav.MAVLink(None, 1, 191)
    sent: dict[int, float] = {}
    period = 0.02
    nxt = time.monotonic()
    n = 0
    end = nxt + seconds
    while time.monotonic() < end:
        seq = base + n
        raw = m.set_position_target_local_ned_encode(0, 1, 1, 1, 0b0000_1101_1100_0111, float(seq), 0, 0,
                                                     0, 0, 0, 0, 0, 0, 0, 0).pack(m)
        m.seq = (m.seq + 1) % 256
        sent[seq] = time.monotonic()
        sock.sendto(raw, dest)
        if n % 50 == 0:
            sock.sendto(m.heartbeat_encode(18, 8, 0, 0, 4).pack(m), dest)
        n += 1
        nxt += period
        time.sleep(max(0.0, nxt - time.monotonic()))
    time.sleep(0.2)
    return [(sim.arrivals[s] - t) * 1e3 for s, t in sent.items() if s in sim.arrivals]


def pct(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(q * len(xs)))]


def one_run(seconds: float, realtime_priority: int = 0, sched_slice_us: int = 0) -> dict[str, float]:
    ap_port, ctl_port = free_port(), free_port()
    sim = TimedSim(Dialect.PX4, ap_port).start()
    cfg = ROOT / "out" / "bench_guard.yaml"
    cfg.parent.mkdir(exist_ok=True)
    cfg.write_text("guard:\n  rate_hz: 50\n")
    proc = subprocess.Popen([sys.executable, "-m", "merlin.cli", "guard", "--autopilot", f"udpin:127.0.0.1:{ap_port}",
                             "--controller", f"udpin:127.0.0.1:{ctl_port}", "--config", str(cfg),
                             "--out", str(ROOT / "out" / "bench_guard"),
                             "--realtime-priority", str(realtime_priority), "--sched-slice-us", str(sched_slice_us)],
                            cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        proc.stdout.readline()  # the start line: the failsafe check passed, routing begins
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        time.sleep(0.5)
        c0, w0 = cpu_s(proc.pid), time.monotonic()
        guarded = stream(sock, ("127.0.0.1", ctl_port), seconds, sim, 0)
        cpu = (cpu_s(proc.pid) - c0) / (time.monotonic() - w0)
        direct = stream(sock, ("127.0.0.1", sim.sock.getsockname()[1]), min(5.0, seconds), sim, 1_000_000)
        sock.close()
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        sim.stop()
    return {"n": len(guarded), "sent": int(seconds * 50), "p50_ms": pct(guarded, 0.5), "p99_ms": pct(guarded, 0.99),
            "max_ms": max(guarded), "direct_p50_ms": pct(direct, 0.5), "direct_p99_ms": pct(direct, 0.99),
            "cpu_frac": cpu}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--realtime-priority", type=int, default=0, metavar="N",
                    help="run the guard with merlin guard --realtime-priority N (SCHED_FIFO; needs the privilege)")
    ap.add_argument("--sched-slice-us", type=int, default=0, metavar="US",
                    help="merlin guard --sched-slice-us (0, the default: the kernel's own slice)")
    a = ap.parse_args()
    runs = [one_run(a.seconds, a.realtime_priority, a.sched_slice_us) for _ in range(a.runs)]
    for r in runs:
        print(json.dumps({k: round(v, 4) for k, v in r.items()}))
    for k in ("p50_ms", "p99_ms", "max_ms", "direct_p50_ms", "direct_p99_ms", "cpu_frac"):
        xs = [r[k] for r in runs]
        print(f"{k}: median {statistics.median(xs):.4f}  min {min(xs):.4f}  max {max(xs):.4f}")
    print("load average:", os.getloadavg())


if __name__ == "__main__":
    main()
