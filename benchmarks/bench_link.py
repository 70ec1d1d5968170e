"""Throughput of the MAVLink link layer: receive (frame, verify, decode, validate) and send (encode, sign).

Run: .venv/bin/python benchmarks/bench_link.py [--runs 7] [--frames 3000]

Reports, per case, the median time per message over several runs and the spread (min..max of the runs),
and the resulting messages per second. The question it answers: what fraction of one core does the link
layer take at the rates the ICD specifies (controller setpoints 50 Hz, telemetry ~150 messages/s per link)?
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

from merlin.core.types import Authority, Behavior, ReasonCode
from merlin.link import outbound as o
from merlin.link.dialect import mavlink_module
from merlin.link.link import MavlinkLink
from merlin.link.px4_modes import OFFBOARD
from merlin.link.security import LinkPolicy
from merlin.link.signing import signing_timestamp

NOW = 1_800_000_000.0
KEY = bytes(range(32))


def _peer_frames(n: int, key: bytes | None) -> list[bytes]:
    M = mavlink_module()
    mav = M.MAVLink(None, 42, 191)
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = signing_timestamp(NOW)
    out = []
    for k in range(n):
        if k % 10 == 0:
            m = M.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)
        else:
            m = M.MAVLink_set_position_target_local_ned_message(
                k, 1, 1, 1, 0x09F8, 1.0 + k * 1e-3, 2.0, -10.0, 0, 0, 0, 0, 0, 0, 0.3, 0
            )
        out.append(bytes(m.pack(mav)))
        mav.seq = (mav.seq + 1) % 256
    return out


def _telemetry() -> list[o.OutMessage]:
    return [
        o.HeartbeatOut(OFFBOARD, True),
        o.AttitudeOut(1000, (0.1, -0.05, 1.2), (0.01, 0.02, 0.03)),
        o.LocalPositionNedOut(1000, (10.0, 20.0, -30.0), (1.0, 0.5, -0.1)),
        o.GlobalPositionIntOut(1000, 29.65, -82.32, 60.0, 30.0, (1.0, 0.5, -0.1), 1.2),
        o.AuthorityStatusOut(1000, Authority.EXPERIMENTAL, Behavior.HOLD, 3, 0, 0, 3, 0.0, ReasonCode.GRANTED, 1),
    ]


def _time_per_item(fn: Callable[[], int], runs: int) -> tuple[float, float, float]:
    per: list[float] = []
    for _ in range(runs):
        t0 = time.perf_counter()
        n = fn()
        per.append((time.perf_counter() - t0) / n)
    return statistics.median(per), min(per), max(per)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--frames", type=int, default=3000)
    args = ap.parse_args()

    cases: list[tuple[str, Callable[[], int]]] = []
    for label, key in (("unsigned", None), ("signed", KEY)):
        frames = _peer_frames(args.frames, key)

        def recv(frames: list[bytes] = frames, key: bytes | None = key) -> int:
            link = MavlinkLink(LinkPolicy("bench", signing_key=key))
            for k, f in enumerate(frames):
                link.receive(f, 0.0, NOW + k * 1e-3)
            assert link.stats().accepted == len(frames)
            return len(frames)

        cases.append((f"receive one datagram ({label}), 90% setpoints", recv))

        def send(key: bytes | None = key) -> int:
            link = MavlinkLink(LinkPolicy("bench", signing_key=key))
            msgs = _telemetry()
            n = args.frames
            for k in range(n):
                link.encode(msgs[k % len(msgs)], NOW + k * 1e-3)
            return n

        cases.append((f"send one telemetry message ({label})", send))

    print(f"bench_link: {args.runs} runs, {args.frames} messages per run")
    print(f"{'case':52s} {'median us':>10s} {'min..max us':>16s} {'msg/s':>9s}")
    for name, fn in cases:
        fn()  # warm-up: dialect load, caches
        med, lo, hi = _time_per_item(fn, args.runs)
        print(f"{name:52s} {med * 1e6:10.1f} {lo * 1e6:7.1f}..{hi * 1e6:<7.1f} {1 / med:9.0f}")


if __name__ == "__main__":
    main()
