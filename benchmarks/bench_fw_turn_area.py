"""A falsification budget for the fixed-wing fence projection's turn area, beyond what the suite samples.

The suite's property test (``tests/core/test_geofence_fixedwing_inner_edge.py``,
``test_no_trip_beside_a_wall_means_every_slowing_turn_on_the_open_side_stays_clear``) draws 120 cases: an
aircraft beside a wall (its left turn always blocked) at 15-38 m/s, a keep-out anywhere on its right, and the
claim that when the monitor does not trip, every right turn the loops may fly (begun after any part of the
reaction time, at any bank from the projection's to the loops' steepest, slowing towards the full-bank
airspeed at any rate) stays the margin clear. This script runs the same property on many more random cases
and reports how many fail and by how much, the near misses among those that pass, and the rate.

    .venv/bin/python benchmarks/bench_fw_turn_area.py --cases 2000 --seed 11
"""

from __future__ import annotations

import argparse
import math
import random
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from merlin.core.geofence import check  # noqa: E402
from tests.core import test_geofence_fixedwing_inner_edge as prop  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=11)
    args = ap.parse_args()
    rng = random.Random(args.seed)
    fails: list[tuple[float, dict[str, float]]] = []
    tripped = 0
    least = math.inf
    t0 = time.perf_counter()
    for _ in range(args.cases):
        a = {"cn": rng.uniform(-50.0, 330.0), "ce": rng.uniform(0.0, 330.0), "radius": rng.uniform(5.0, 60.0),
             "v": rng.uniform(15.0, 38.0), "course_deg": rng.uniform(-20.0, 20.0), "bank_deg": rng.uniform(0.0, 45.0)}
        zone = ((a["cn"], a["ce"]), a["radius"])
        if math.hypot(a["cn"], a["ce"]) < a["radius"] + 20.0:
            continue
        fence = prop._walled_fast(*zone)
        c = math.radians(a["course_deg"])
        vel = (a["v"] * math.cos(c), a["v"] * math.sin(c), 0.0)
        if check(fence, (0.0, 0.0, -120.0), vel, 0.0, 0.0, True, (0.0, 0.0), None, math.radians(a["bank_deg"])).tripped:
            tripped += 1
            continue
        worst = min(prop._walled_margin(zone, p)
                    for p in prop.slowing_turns(0.0, 0.0, c, a["v"], 1, math.radians(a["bank_deg"])))
        least = min(least, worst)
        if worst < -0.05:
            fails.append((worst, a))
    dt = time.perf_counter() - t0
    print(f"cases {args.cases}, seed {args.seed}: tripped {tripped}, not tripped {args.cases - tripped}, "
          f"failures {len(fails)}; least margin of a reference turn where no trip: {least:.3f} m; "
          f"{args.cases / dt:.1f} cases/s")
    for worst, a in sorted(fails, key=lambda x: x[0])[:10]:
        print(f"  {worst:.2f} m: " + ", ".join(f"{k}={v:.3f}" for k, v in a.items()))
    return 1 if fails else 0


if __name__ == "__main__":
    raise SystemExit(main())
