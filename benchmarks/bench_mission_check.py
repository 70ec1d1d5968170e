"""Cost of judging an uploaded waypoint mission in ``merlin serve``: decoding the items and checking every leg
against the fence (shapely), which runs in the receive path between two ticks when the last item arrives.

    .venv/bin/python benchmarks/bench_mission_check.py [--repeat 20]

Prints, for missions of 10, 100 and 500 waypoints on the built-in 300 m range and on a range with 12
keep-out circles, the median decode and check time in milliseconds. Not a timed test: a figure for
docs/benchmarks/px4-dropin.md.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.geodesy import LocalFrame
from merlin.link.mission_protocol import MAV_CMD_NAV_WAYPOINT, check_legs_against_fence, decode_mission
from merlin.link.mission_transfer import WireItem

HOME = LocalFrame(47.397742, 8.545594, 488.0)


def _items(n: int) -> tuple[WireItem, ...]:
    """A spiral of ``n`` waypoints inside 250 m of home, 30 m up."""
    out = []
    for k in range(n):
        r = 20.0 + 230.0 * k / max(1, n - 1)
        a = 0.7 * k
        lat, lon, _ = HOME.to_geodetic(r * math.cos(a), r * math.sin(a))
        out.append(WireItem(MAV_CMD_NAV_WAYPOINT, 0.0, 0.0, lat, lon, 30.0, 6))
    return tuple(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args()
    keep_outs = [{"center_ne_m": [400.0 * math.cos(a), 400.0 * math.sin(a)], "radius_m": 15.0}
                 for a in (2 * math.pi * k / 12 for k in range(12))]
    fences = {
        "built-in 300 m range": build_core_config(MerlinConfig()).fence,
        "600 m range, 12 keep-outs": build_core_config(MerlinConfig.model_validate({"geofence": {
            "inclusion_circles": [{"center_ne_m": [0.0, 0.0], "radius_m": 600.0}],
            "exclusion_circles": keep_outs}})).fence,
    }
    print(f"{'fence':28s} {'waypoints':>9s} {'decode ms':>10s} {'check ms':>9s}  verdict")
    for name, fence in fences.items():
        for n in (10, 100, 500):
            items = _items(n)
            dec, chk = [], []
            verdict = None
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                plan = decode_mission(items, HOME)
                t1 = time.perf_counter()
                assert not isinstance(plan, tuple), plan
                verdict = check_legs_against_fence(plan, fence, 5.0, 120.0)
                t2 = time.perf_counter()
                dec.append(t1 - t0)
                chk.append(t2 - t1)
            ok = "accepted" if verdict is None else f"refused ({verdict[1][:40]}...)"
            print(f"{name:28s} {n:9d} {1e3 * statistics.median(dec):10.2f} {1e3 * statistics.median(chk):9.2f}  {ok}")


if __name__ == "__main__":
    main()
