"""Adversarial setpoint steps against the geofence, in closed loop (not a test; see docs/benchmarks/adversary.md).

A multirotor hovers at ``distance`` metres south of the north edge of a square range (half-side 300 m,
margin 3 m, sigma_k 2, the truth-plus-noise estimator) and, once granted, its experimental controller
(``experimental_controllers.adversaries``) steps the velocity setpoint to ``speed`` m/s towards
``heading`` (0: straight at the north edge) and holds it. The envelope's velocity limits are opened to
the validator's bound (100 m/s) so that the geofence alone must catch the step; the attitude limits of
the "expanded" stage stay. Each run reports:

* the stop margin: the smallest true distance to the boundary after the step (negative: a breach);
* the projection excess: after the first fence trip, how much farther the vehicle travelled along its
  velocity before stopping than the projection counted (the projected path length ``stopping_distance_m``
  of that trip). The safety promise is that this never exceeds 1 m.

Modes:

* ``--sweep`` (default): step size 5..100 m/s, heading 0..360 deg, distance 15..250 m, from a seeded
  random generator (``--runs N``, ``--seed S``); reports the breaches and the distribution of the margins.
* ``--ramped``: the "not over-conservative" figure: ramped (3 m/s^2) approaches at 15 m/s straight at
  the edge from 150 m; the median stop margin against margin + k sigma.

    MERLIN_USE_SOURCES=1 .venv/bin/python benchmarks/bench_adversary_steps.py --sweep --runs 200
    MERLIN_USE_SOURCES=1 .venv/bin/python benchmarks/bench_adversary_steps.py --ramped --runs 20
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from dataclasses import dataclass
from typing import Any

import numpy as np

from merlin.config.models import MerlinConfig
from sims.runner import run_scenario
from sims.scenario import Scenario

HALF_SIDE_M = 300.0
MARGIN_M = 3.0
SIGMA_K = 2.0


def range_config(open_velocity: bool = True) -> MerlinConfig:
    """The square range; the "expanded" envelope stage, its velocity limits opened when asked."""
    base = MerlinConfig()
    data: dict[str, Any] = base.model_dump(mode="json")
    h = HALF_SIDE_M
    data["geofence"].update(
        mode="velocity_projection",
        margin_m=MARGIN_M,
        sigma_k=SIGMA_K,
        altitude_ceiling_m=120.0,
        inclusion_circles=[],
        exclusion_circles=[],
        exclusion_polygons=[],
        inclusion_polygons=[{"name": "range", "vertices_ne_m": [[-h, -h], [h, -h], [h, h], [-h, h]]}],
    )
    data["envelope"]["active_stage"] = "expanded"
    if open_velocity:
        stage = data["envelope"]["stages"]["expanded"]
        for k in ("vel_n_mps", "vel_e_mps"):
            stage[k].update(min=-100.0, max=100.0)
        stage["vel_d_mps"].update(min=-100.0, max=100.0)
        stage["altitude_m"].update(max=1000.0)
    return MerlinConfig.model_validate(data)


@dataclass(frozen=True)
class Outcome:
    speed_mps: float
    heading_deg: float
    distance_m: float
    stop_margin_m: float
    excess_m: float  # achieved minus projected stop along the velocity at the first trip (nan: no trip)
    revoked_by: str


def fly(
    cfg: MerlinConfig,
    speed_mps: float,
    heading_deg: float,
    distance_m: float,
    *,
    accel_mps2: float = 0.0,
    seed: int = 1,
    duration_s: float = 30.0,
) -> Outcome:
    start_n = HALF_SIDE_M - distance_m
    sc = Scenario.model_validate(
        {
            "name": "adversary_step",
            "duration_s": duration_s,
            "seed": seed,
            "initial": {"pos_ned_m": [start_n, 0.0, 0.0]},
            "gcs": [{"t": 0.5, "command": "arm"}, {"t": 1.0, "command": "takeoff", "param": 10}],
            "controller": {
                "type": "experimental_controllers.adversaries:VelocityStep",
                "params": {
                    "request_at_s": 8.0,
                    "start_at_s": 8.5,
                    "heading_deg": heading_deg,
                    "speed_mps": speed_mps,
                    "accel_mps2": accel_mps2,
                },
            },
            "log_rate_hz": 400.0,
        }
    )
    r = run_scenario(sc, cfg)
    log = r.log
    t = log["t"]
    after = t >= 8.5
    margin = float(np.nanmin(log["fence_margin"][after]))
    revoked = next((e for e in r.events if e["type"] == "revoked"), None)
    trip = next(
        (e for e in r.events if e["type"] == "monitor_tripped" and e["reason_detail"]["monitor"] == "geofence"),
        None,
    )
    excess = math.nan
    if trip is not None:
        i = int(np.searchsorted(t, trip["t"]))
        p0 = np.array([log["truth_n"][i], log["truth_e"][i]])
        v0 = np.array([log["truth_vn"][i], log["truth_ve"][i]])
        sp = float(np.hypot(*v0))
        if sp > 0.5:
            u = v0 / sp
            along = (log["truth_n"][i:] - p0[0]) * u[0] + (log["truth_e"][i:] - p0[1]) * u[1]
            excess = float(np.max(along)) - float(trip["reason_detail"]["value"])
    return Outcome(speed_mps, heading_deg, distance_m, margin, excess, revoked["reason"] if revoked else "")


def _summary(xs: list[float]) -> str:
    a = np.array([x for x in xs if math.isfinite(x)])
    if a.size == 0:
        return "n/a"
    q = np.percentile(a, [0, 5, 25, 50, 75, 95, 100])
    return "min {:.2f} / p5 {:.2f} / p25 {:.2f} / median {:.2f} / p75 {:.2f} / p95 {:.2f} / max {:.2f} (n={})".format(
        *q, a.size
    )


def _duration_s(heading_deg: float, distance_m: float) -> float:
    """Long enough to reach the range's edge along the heading at the vehicle's top speed (~17 m/s), and stop."""
    h = math.radians(heading_deg)
    un, ue = math.cos(h), math.sin(h)
    n0 = HALF_SIDE_M - distance_m
    ray = min(
        ((HALF_SIDE_M - n0) / un if un > 1e-9 else ((-HALF_SIDE_M - n0) / un if un < -1e-9 else math.inf)),
        (HALF_SIDE_M / abs(ue) if abs(ue) > 1e-9 else math.inf),
    )
    return min(8.5 + ray / 12.0 + 12.0, 80.0)


def sweep(runs: int, seed: int) -> int:
    rng = np.random.default_rng(seed)
    cfg = range_config(open_velocity=True)
    out: list[Outcome] = []
    for k in range(runs):
        speed = float(rng.uniform(5.0, 100.0))
        heading = float(rng.uniform(0.0, 360.0))
        dist = float(rng.uniform(15.0, 250.0))
        o = fly(cfg, speed, heading, dist, seed=k + 1, duration_s=_duration_s(heading, dist))
        out.append(o)
        flag = "BREACH" if o.stop_margin_m < 0.0 else ""
        print(
            f"{k:4d} speed {speed:6.1f} heading {heading:6.1f} dist {dist:6.1f}: margin {o.stop_margin_m:7.2f}"
            f" excess {o.excess_m:6.2f} revoked by {o.revoked_by or '-'} {flag}",
            flush=True,
        )
    breaches = [o for o in out if o.stop_margin_m < 0.0]
    print(f"\nruns {len(out)}, breaches {len(breaches)}")
    print("stop margin (m):", _summary([o.stop_margin_m for o in out]))
    print("stop margin, headings within 60 deg of the edge's normal (m):",
          _summary([o.stop_margin_m for o in out if min(o.heading_deg, 360.0 - o.heading_deg) <= 60.0]))
    print("projection excess at the first trip (m):", _summary([o.excess_m for o in out]))
    return 1 if breaches else 0


def ramped(runs: int) -> int:
    cfg = range_config(open_velocity=False)
    out = [fly(cfg, 15.0, 0.0, 150.0, accel_mps2=3.0, seed=k + 1, duration_s=40.0) for k in range(runs)]
    for o in out:
        print(f"margin {o.stop_margin_m:6.2f} excess {o.excess_m:6.2f} revoked by {o.revoked_by}")
    med = statistics.median(o.stop_margin_m for o in out)
    print(f"\nramped 15 m/s approaches: median stop margin {med:.2f} m (margin {MARGIN_M} m + k sigma)")
    print("stop margin (m):", _summary([o.stop_margin_m for o in out]))
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sweep", action="store_true")
    ap.add_argument("--ramped", action="store_true")
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--seed", type=int, default=16)
    a = ap.parse_args(argv)
    if a.ramped:
        return ramped(a.runs)
    return sweep(a.runs, a.seed)


if __name__ == "__main__":
    sys.exit(main())
