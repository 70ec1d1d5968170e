"""Cost of planning a trusted escape's route in the core's tick (``merlin.autopilot.route`` via
``merlin.autopilot.guidance.enter``): the multirotor's RTL, HOLD and LAND plan once, on the tick their
behaviour starts, so that tick is the slow one. What is timed is exactly the call the tick makes,
``guidance.enter(behavior, state, cfg.trusted, cfg.fence)``.

Ranges: the shipped ``examples/configs/default.yaml`` (a 600 m x 400 m field with a notch, a barn and a
radio-mast keep-out) and ``examples/configs/l_range.yaml`` (an L-shaped range with two keep-outs). Starts:
every ``--spacing`` metres of each range's allowed area, at 25 m, flying 6 m/s towards home (RTL) or away
from it (HOLD, LAND), GPS sigma 0.5 m. The sweep finds each range's worst start per behaviour; that start
is then re-timed ``--repeat`` times (interleaved) for the median and the spread (p10-p90, max).

Wall-clock process time on a shared machine is noisy: the figures are a cost estimate, never a test.

    .venv/bin/python benchmarks/bench_route.py [--spacing 20] [--repeat 30]
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import shapely

from merlin.autopilot import guidance
from merlin.config.loader import load_config
from merlin.config.runtime import build_core_config
from merlin.core.config import CoreConfig
from merlin.core.types import Behavior, VehicleState

CONFIGS = ("default.yaml", "l_range.yaml")
BEHAVIORS = (Behavior.RTL, Behavior.HOLD, Behavior.LAND)


def _state(n: float, e: float, towards_home: bool) -> VehicleState:
    d = math.hypot(n, e)
    k = (-6.0 if towards_home else 6.0) / d if d > 1e-9 else 0.0
    return VehicleState(pos_ned_m=(n, e, -25.0), vel_ned_mps=(n * k, e * k, 0.0), armed=True, landed=False,
                        pos_sigma_h_m=0.5)


def _time_ms(cfg: CoreConfig, behavior: Behavior, s: VehicleState) -> tuple[float, guidance.GuidanceState]:
    t0 = time.process_time()
    g = guidance.enter(behavior, s, cfg.trusted, cfg.fence)
    return 1e3 * (time.process_time() - t0), g


def sweep(cfg: CoreConfig, spacing_m: float) -> dict[Behavior, list[tuple[float, tuple[float, float], str]]]:
    """Every start of the grid once per behaviour: (ms, start, what the plan was)."""
    assert cfg.fence is not None
    allowed = cfg.fence.allowed_area
    n0, e0, n1, e1 = (float(x) for x in shapely.bounds(allowed))
    starts = [
        (n0 + spacing_m * (i + 0.5), e0 + spacing_m * (j + 0.5))
        for i in range(int((n1 - n0) / spacing_m))
        for j in range(int((e1 - e0) / spacing_m))
    ]
    starts = [p for p in starts if allowed.contains(shapely.Point(p))]
    out: dict[Behavior, list[tuple[float, tuple[float, float], str]]] = {b: [] for b in BEHAVIORS}
    for p in starts:
        for b in BEHAVIORS:
            ms, g = _time_ms(cfg, b, _state(p[0], p[1], b is Behavior.RTL))
            kind = "no route" if g.fallback else (f"{len(g.path_ne_m)} pts" if g.path_ne_m else "in place")
            out[b].append((ms, p, kind))
    return out


def _pct(v: list[float], q: float) -> float:
    s = sorted(v)
    return s[min(len(s) - 1, int(q * len(s)))]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spacing", type=float, default=20.0, help="grid spacing of the starts, m")
    ap.add_argument("--repeat", type=int, default=30, help="re-timings of each worst start")
    args = ap.parse_args()
    root = Path(__file__).resolve().parents[1] / "examples" / "configs"
    print(f"process time per guidance.enter, ms; starts every {args.spacing:g} m; worst start re-timed "
          f"{args.repeat}x")
    print(f"{'range':14} {'behaviour':9} {'starts':>6} {'sweep median':>12} {'sweep p95':>9} {'worst start':>16}"
          f" {'plan':>9} {'worst median':>12} {'p10-p90':>13} {'max':>7}")
    for name in CONFIGS:
        cfg = build_core_config(load_config(root / name))
        res = sweep(cfg, args.spacing)
        for b in BEHAVIORS:
            rows = res[b]
            ms_all = [r[0] for r in rows]
            worst = max(rows, key=lambda r: r[0])
            s = _state(worst[1][0], worst[1][1], b is Behavior.RTL)
            again = [_time_ms(cfg, b, s)[0] for _ in range(args.repeat)]
            print(f"{name:14} {b.name:9} {len(rows):6d} {statistics.median(ms_all):12.2f} {_pct(ms_all, 0.95):9.2f}"
                  f" {f'({worst[1][0]:.0f}, {worst[1][1]:.0f})':>16} {worst[2]:>9} {statistics.median(again):12.2f}"
                  f" {f'{_pct(again, 0.1):.2f}-{_pct(again, 0.9):.2f}':>13} {max(again):7.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
