"""False exclusions of the GPS window test, and its delay against a position-only drag, by Monte Carlo.

The window test (``NavEstimator._window_statistic``) compares the GPS displacement over ``gps_window_s``
with the mechanisation's; a healthy receiver fails it only through its own wander. This flies the test
alone on the simulator's receiver model (``sims.sensors.GpsParams``: Gauss-Markov error plus white
noise, at the receiver's rate) against a perfect mechanisation, for thousands of flights at once, and
counts CUSUM alarms per flight-hour; then adds a position-only drag at a given speed and reports the time
from its onset to the alarm. The recursion is the one ``merlin.nav.estimator.Cusum`` implements, written
here over numpy arrays (one column per flight) because the estimator's scalar class would take hours for
the thousands of flight-hours a rate of one in hundreds of hours needs; the parameters are read from
``NavConfig`` and ``GpsParams``, so the figures follow the shipped defaults.

    .venv/bin/python benchmarks/bench_gps_window.py                       # the defaults, 500 flight-hours
    .venv/bin/python benchmarks/bench_gps_window.py --sigma 0.6 0.65 0.7 --hours 2000

The mechanisation's own velocity variance enters the test's C as P_vv W²; it is taken as in a nominal
closed-loop flight (``--pvv``, 0.002 m²/s², read from the filter in the redundancy_accel flight that
``examples/scenarios/gps_window_false_exclusion.yaml`` pins).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from merlin.nav.config import NavConfig  # noqa: E402
from sims.sensors import GpsParams  # noqa: E402

DRAG_DIRECTION_NE = (0.6, -0.8)  # as in tests/nav/test_nav_receiver_accuracy.py


def window_cusum(sigma_w: float, hours: float, seed: int, flights: int, pvv: float,
                 drag_mps: float = 0.0) -> dict[str, float]:
    """Alarms per flight-hour (drag 0), or the median delay from the drag's onset to the first alarm."""
    cfg, gps = NavConfig(), GpsParams()
    rng = np.random.default_rng(seed)
    dt = 1.0 / gps.rate_hz
    w = round(cfg.gps_window_s * gps.rate_hz)
    phi = math.exp(-dt / gps.pos_markov_tau_s)
    q = math.sqrt(1.0 - phi * phi) * gps.pos_h_markov_sigma_m
    var = sigma_w**2 + pvv * cfg.gps_window_s**2
    n = int(hours * 3600.0 * gps.rate_hz) + w
    err = rng.standard_normal((flights, 2)) * gps.pos_h_markov_sigma_m  # stationary at the start
    ring = np.zeros((w + 1, flights, 2))
    g = np.zeros(flights)
    alarms = 0
    first = np.full(flights, np.nan)
    drag = np.array(DRAG_DIRECTION_NE) * drag_mps * dt
    for k in range(n):
        err = phi * err + q * rng.standard_normal((flights, 2))
        meas = err + gps.pos_h_white_sigma_m * rng.standard_normal((flights, 2))
        if drag_mps and k >= w:  # onset once the first window is full
            meas = meas + drag * (k - w)
        ring[k % (w + 1)] = meas
        if k < w:
            continue
        d = meas - ring[(k - w) % (w + 1)]
        s = (d * d).sum(axis=1) / var / 2.0
        g = np.maximum(0.0, g + np.minimum(s, cfg.gps_cusum_clip) - cfg.gps_cusum_allowance)
        alarm = g > cfg.gps_cusum_threshold
        alarms += int(alarm.sum())
        new = alarm & np.isnan(first)
        first[new] = (k - w) * dt
        g[alarm] = 0.0  # an exclusion resets the window and its CUSUM
    if drag_mps:
        return {"median_delay_s": float(np.nanmedian(first)), "missed": float(np.isnan(first).mean())}
    return {"alarms": alarms, "flight_hours": flights * hours, "per_hour": alarms / (flights * hours)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sigma", type=float, nargs="*", default=None,
                    help="window sigmas to fly, m (default: NavConfig's gps_window_sigma_m)")
    ap.add_argument("--hours", type=float, default=500.0, help="flight-hours per sigma for the false alarms")
    ap.add_argument("--flights", type=int, default=2000, help="flights flown side by side")
    ap.add_argument("--drag", type=float, nargs="*", default=[0.5, 1.0], help="drag speeds, m/s")
    ap.add_argument("--pvv", type=float, default=0.002, help="the filter's horizontal velocity variance, m²/s²")
    ap.add_argument("--seed", type=int, default=11)
    args = ap.parse_args()
    sigmas = args.sigma or [NavConfig().gps_window_sigma_m]
    out = {}
    for sw in sigmas:
        row = {"false": window_cusum(sw, args.hours / args.flights, args.seed, args.flights, args.pvv)}
        for v in args.drag:
            row[f"drag_{v}_mps"] = window_cusum(sw, 20.0 / 3600.0, args.seed + 1, 400, args.pvv, drag_mps=v)
        out[str(sw)] = row
        drags = "; ".join(f"drag {v} m/s: {row[f'drag_{v}_mps']['median_delay_s']:.1f} s "
                          f"(missed in 20 s {100 * row[f'drag_{v}_mps']['missed']:.0f} %)" for v in args.drag)
        print(f"sigma_w {sw} m: {row['false']['alarms']} alarms in {row['false']['flight_hours']:.0f} flight-hours, "
              f"{row['false']['per_hour']:.4f} per hour; {drags}", flush=True)
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
