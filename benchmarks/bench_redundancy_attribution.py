"""Benchmark: the sub-alert attribution (merlin/redundancy/attribution.py) on the synthetic seed-003 flight.

Run: MERLIN_USE_SOURCES=1 .venv/bin/python benchmarks/bench_redundancy_attribution.py [--particles 1024]
     [--onset 3.0] [--json out.json]
     MERLIN_USE_SOURCES=1 .venv/bin/python benchmarks/bench_redundancy_attribution.py --nominal 600 [--seeds 3]

Three IMU lanes fly the seed-003 manoeuvres (``duplex_scenarios.nominal_flight``, two independent draws, the
third lane taken from the second draw). Lane 2 freezes at 1 s, so the voter isolates it and the pair (0, 1)
goes to the duplex FDI. From ``--onset`` s, one gyro axis of lane 0 or lane 1 reads a bias of +0.11, +0.15,
+0.20, +0.27 or -0.13 rad/s: between the voter's duplex miscompare (0.1 rad/s) and the FDI's alert
(tau_g = 0.2853 rad/s, seed 003 Table 2), and one case just below it. 30 cases, ``merlin`` preset.

Per case: the lane isolated and when (after the onset), who decided (seed 003's FDI, or the attribution
layer and which of its evidences), from when the estimator was fed the healthy lane alone, and how long it
was fed the mean or the faulty lane alone. The count of cases where the faulty lane was isolated and the
healthy one never is the headline figure (docs/benchmarks/redundancy.md §9-§10). All times are simulated.

``--nominal S``: false alarms instead. The same flight, lane 2 frozen at 1 s and no other fault, for S
simulated seconds per seed (each seed draws new lanes, noises and turn-on biases): how many sub-alert
episodes the gyro layer opened (its own averaged detection included; a single sample over the voter's
0.1 rad/s opens one, and with this flight's 0.02 rad/s of vibration noise that happens), how many
persisted 1 s (``imu_duplex_unresolved``) and how many lanes were isolated after the pair formed. The accelerometer layer needs GPS, which this flight has not; its nominal
behaviour is in the closed-loop scenarios' digests.
"""

from __future__ import annotations

import argparse
import itertools
import json
from dataclasses import replace
from typing import Any

import numpy as np

from merlin.redundancy.degradation import ImuDegradationChain
from merlin.redundancy.duplex_fdi import MERLIN
from merlin.redundancy.duplex_scenarios import DT_S, nominal_flight
from merlin.redundancy.events import FaultKind
from merlin.redundancy.particle_filter import ParticleFilterConfig
from merlin.redundancy.sensor_voter import LaneSample

AXES = (0, 1, 2)
SIZES = (0.11, 0.15, 0.20, 0.27, -0.13)
LANES = (0, 1)


def _three_lanes(duration_s: float) -> tuple[np.ndarray, ...]:
    a = nominal_flight(duration_s, np.random.default_rng(1))
    b = nominal_flight(duration_s, np.random.default_rng(2))

    def cat(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.concatenate([x, y[:, :1]], axis=1)

    return a.t_s, cat(a.gyro, b.gyro), cat(a.accel, b.accel), cat(a.mag, b.mag)


def run_case(axis: int, size: float, lane: int, particles: int, onset_s: float,
             duration_s: float = 10.0) -> dict[str, Any]:
    t, gyro, acc, mag = _three_lanes(duration_s)
    k1 = int(1.0 / DT_S)
    gyro[k1:, 2], acc[k1:, 2] = gyro[k1 - 1, 2], acc[k1 - 1, 2]
    gyro[t >= onset_s, lane, axis] += size
    cfg = replace(MERLIN, pf=replace(ParticleFilterConfig(), n_particles=particles))
    chain = ImuDegradationChain(np.random.default_rng(5), cfg)
    first_healthy: float | None = None
    fed_bad = fed_mean = 0.0
    iso: tuple[float, int, str] | None = None
    detail = ""
    for k, tk in enumerate(t):
        imu = tuple(LaneSample(float(tk), (*gyro[k, i], *acc[k, i])) for i in range(3))
        out = chain.step(float(tk), imu, tuple(tuple(mag[k, i]) for i in range(3)))
        for e in out.events:
            if e.kind is FaultKind.ATTRIBUTED and not detail:
                detail = e.detail
            if e.kind is FaultKind.ISOLATED and e.lane != 2 and iso is None:
                iso = (float(tk) - onset_s, e.lane, e.detail)
        if tk >= onset_s and iso is None:
            used = out.imu.lanes_used
            if used == (lane,):
                fed_bad += DT_S
            elif len(used) == 2:
                fed_mean += DT_S
            elif first_healthy is None:
                first_healthy = float(tk) - onset_s
    by = "" if iso is None else iso[2]
    if "field trackers" in detail:
        by += " (field trackers)"
    elif "bias estimates" in detail:
        by += " (bias estimates)"
    return {"axis": axis, "size_radps": size, "faulty_lane": lane,
            "isolated_lane": None if iso is None else iso[1], "isolated_after_s": None if iso is None else iso[0],
            "by": by, "healthy_fed_from_s": first_healthy, "mean_fed_s": round(fed_mean, 3),
            "faulty_alone_s": round(fed_bad, 3)}


def nominal(duration_s: float, seed: int, particles: int) -> dict[str, Any]:
    a = nominal_flight(duration_s, np.random.default_rng(100 + seed))
    b = nominal_flight(duration_s, np.random.default_rng(200 + seed))
    t = a.t_s
    gyro = np.concatenate([a.gyro, b.gyro[:, :1]], axis=1)
    acc = np.concatenate([a.accel, b.accel[:, :1]], axis=1)
    mag = np.concatenate([a.mag, b.mag[:, :1]], axis=1)
    k1 = int(1.0 / DT_S)
    gyro[k1:, 2], acc[k1:, 2] = gyro[k1 - 1, 2], acc[k1 - 1, 2]
    cfg = replace(MERLIN, pf=replace(ParticleFilterConfig(), n_particles=particles))
    chain = ImuDegradationChain(np.random.default_rng(seed), cfg)
    episodes = isolations = alerts = unresolved = 0
    was_active = False
    for k, tk in enumerate(t):
        imu = tuple(LaneSample(float(tk), (*gyro[k, i], *acc[k, i])) for i in range(3))
        out = chain.step(float(tk), imu, tuple(tuple(mag[k, i]) for i in range(3)))
        isolations += sum(e.kind is FaultKind.ISOLATED and e.lane != 2 for e in out.events)
        alerts += sum(e.kind is FaultKind.ALERT for e in out.events)
        unresolved += sum(e.kind is FaultKind.DUPLEX_UNRESOLVED for e in out.events)
        active = chain.attribution is not None and chain.attribution.active
        episodes += active and not was_active
        was_active = active
    return {"seed": seed, "duration_s": duration_s, "episodes": episodes, "unresolved": unresolved,
            "isolations": isolations, "fdi_alerts": alerts}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--particles", type=int, default=1024)
    ap.add_argument("--onset", type=float, default=3.0)
    ap.add_argument("--json")
    ap.add_argument("--nominal", type=float, default=0.0, help="simulated seconds of nominal flight per seed")
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    if args.nominal > 0.0:
        res = [nominal(args.nominal, s, args.particles) for s in range(args.seeds)]
        for r in res:
            print(f"seed {r['seed']}: {r['duration_s']:.0f} s nominal duplex flight: {r['episodes']} sub-alert "
                  f"episodes opened, {r['unresolved']} persisting 1 s, {r['isolations']} isolations, "
                  f"{r['fdi_alerts']} FDI alerts", flush=True)
        if args.json:
            with open(args.json, "w") as f:
                json.dump(res, f, indent=1)
        return
    rows = []
    for axis, size, lane in itertools.product(AXES, SIZES, LANES):
        r = run_case(axis, size, lane, args.particles, args.onset)
        rows.append(r)
        iso = "none" if r["isolated_lane"] is None else f"lane {r['isolated_lane']} at +{r['isolated_after_s']:.2f} s"
        fed = "never" if r["healthy_fed_from_s"] is None else f"+{r['healthy_fed_from_s']:.2f} s"
        print(f"axis {axis} {size:+.2f} rad/s on lane {lane}: isolated {iso} by {r['by'] or '-'}; healthy lane "
              f"fed from {fed}, mean {r['mean_fed_s']:.2f} s, faulty alone {r['faulty_alone_s']:.2f} s",
              flush=True)
    right = sum(r["isolated_lane"] == r["faulty_lane"] for r in rows)
    wrong = sum(r["isolated_lane"] is not None and r["isolated_lane"] != r["faulty_lane"] for r in rows)
    print(f"faulty lane isolated in {right} of {len(rows)} cases; healthy lane isolated in {wrong}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"cases": rows, "right": right, "wrong": wrong}, f, indent=1)


if __name__ == "__main__":
    main()
