"""Cost of one trusted-core tick with a realistic configuration (issue: median <= 50 µs, p99 <= 150 µs).

Configuration: every envelope parameter of the paper's Table 2 enabled, a 50-vertex non-convex inclusion
polygon about 1 km across, 5 exclusion zones (3 polygons, 2 circles), the 4 watchdogs live. The vehicle
flies a figure-eight over the range under EXPERIMENTAL authority with a fresh setpoint every tick, so the
envelope timers, the velocity-projected fence and every watchdog are evaluated on every tick.

    .venv/bin/python benchmarks/bench_core.py [--ticks 20000] [--runs 7]

A benchmark, not a test: the machine is shared; report the median of the per-run medians and the spread.
"""

from __future__ import annotations

import argparse
import gc
import math
import platform
import statistics
import time

from merlin.config.models import (
    ENVELOPE_PARAMETERS,
    EnvelopeStage,
    FenceCircle,
    FencePolygon,
    GeofenceConfig,
    Limit,
    MerlinConfig,
)
from merlin.config.runtime import build_core_config
from merlin.core.step import TrustedCore
from merlin.core.types import (
    AuthorityRequest,
    EventKind,
    ExperimentalInput,
    GcsCommand,
    GcsCommandKind,
    Inputs,
    OperatorInput,
    RequestKind,
    Setpoint,
    SetpointKind,
    VehicleState,
)

DT = 0.0025


def realistic_config() -> MerlinConfig:
    # 50-vertex star-ish non-convex polygon, radius 450-550 m
    verts = []
    for i in range(50):
        a = 2 * math.pi * i / 50
        r = 500.0 + (50.0 if i % 2 else -50.0)
        verts.append([r * math.cos(a), r * math.sin(a)])
    excl_polys = [
        FencePolygon(name=f"keep-out {k}", vertices_ne_m=[[cx - 20, cy - 20], [cx + 20, cy - 20], [cx + 20, cy + 20], [cx - 20, cy + 20]])
        for k, (cx, cy) in enumerate([(200.0, 150.0), (-250.0, 100.0), (50.0, -300.0)])
    ]
    excl_circles = [FenceCircle(name="mast", center_ne_m=[-150.0, -200.0], radius_m=30.0),
                    FenceCircle(name="tower", center_ne_m=[300.0, -100.0], radius_m=25.0)]
    fence = GeofenceConfig(inclusion_polygons=[FencePolygon(name="range", vertices_ne_m=verts)], inclusion_circles=[],
                           exclusion_polygons=excl_polys, exclusion_circles=excl_circles)
    cfg = MerlinConfig(geofence=fence)
    base = cfg.envelope.resolve("expanded")
    all_on = {p: Limit(min=base[p].min, max=base[p].max, duration_s=base[p].duration_s, enabled=True)
              for p in ENVELOPE_PARAMETERS}
    all_on["yaw_deg"] = Limit(min=-180.0, max=180.0, duration_s=0.0)
    all_on["airspeed_mps"] = Limit(min=0.0, max=20.0, duration_s=0.5)
    all_on["alpha_deg"] = Limit(min=-90.0, max=90.0, duration_s=0.2)
    stages = dict(cfg.envelope.stages, bench=EnvelopeStage(**all_on))
    return cfg.model_copy(update={"envelope": cfg.envelope.model_copy(update={"stages": stages, "active_stage": "bench"})})


def _state(t: float) -> VehicleState:
    # a figure-eight of 150 m at ~6 m/s, 20 m up, banking gently
    w = 0.04
    n, e = 150.0 * math.sin(w * t), 75.0 * math.sin(2 * w * t)
    vn, ve = 150.0 * w * math.cos(w * t), 150.0 * w * math.cos(2 * w * t)
    return VehicleState(pos_ned_m=(n, e, -20.0), vel_ned_mps=(vn, ve, 0.1), att_rpy_rad=(0.08, -0.05, 0.3),
                        rates_frd_radps=(0.02, 0.01, 0.03), accel_frd_mps2=(0.3, 0.2, -9.8), airspeed_mps=6.0,
                        armed=True, landed=False)


def one_run(cfg, ticks: int) -> list[float]:
    core = TrustedCore(cfg)
    t = 0.0
    ground = VehicleState(landed=True)
    core.step(t, Inputs(state=ground, gcs_link_t_s=t, gcs_commands=(GcsCommand(GcsCommandKind.ARM),)))
    # fly: place the state airborne, establish the heartbeat, exchange
    sp_first = None
    for k in range(1, 800):
        t = k * DT
        s = _state(t)
        sp = Setpoint(SetpointKind.VELOCITY, vel_ned_mps=s.vel_ned_mps)
        reqs = (AuthorityRequest(RequestKind.REQUEST),) if k == 600 else ()
        d = core.step(t, Inputs(state=s, experimental=ExperimentalInput(t, sp, t, reqs), operator=OperatorInput(t),
                                gcs_link_t_s=t))
        for e in d.events:
            if e.kind is EventKind.GRANTED:
                sp_first = e.seq
        if sp_first and k == 601:
            core.step(t + DT / 2, Inputs(state=s, experimental=ExperimentalInput(t, sp, t, (AuthorityRequest(RequestKind.ACK, seq=sp_first),)),
                                         operator=OperatorInput(t), gcs_link_t_s=t))
    assert core.state.arbiter.authority.name == "EXPERIMENTAL", core.state.arbiter
    inputs = []
    k0 = 800
    for k in range(k0, k0 + ticks):
        t = k * DT
        s = _state(t)
        sp = Setpoint(SetpointKind.VELOCITY, vel_ned_mps=s.vel_ned_mps)
        inputs.append((t, Inputs(state=s, experimental=ExperimentalInput(t, sp, t), operator=OperatorInput(t),
                                 gcs_link_t_s=t)))
    times = []
    pc = time.perf_counter_ns
    gc.collect()
    for t, inp in inputs:
        t0 = pc()
        core.step(t, inp)
        times.append((pc() - t0) / 1000.0)
    assert core.state.arbiter.authority.name == "EXPERIMENTAL", "the benchmark must measure supervised flight"
    return times


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--ticks", type=int, default=20000)
    ap.add_argument("--runs", type=int, default=7)
    a = ap.parse_args()
    cfg = build_core_config(realistic_config())
    print(f"python {platform.python_version()} on {platform.machine()}; envelope parameters: {len(cfg.envelope)};"
          f" compiled core: {_compiled()}")
    medians, p99s = [], []
    for r in range(a.runs):
        ts = sorted(one_run(cfg, a.ticks))
        med, p99 = ts[len(ts) // 2], ts[int(len(ts) * 0.99)]
        medians.append(med)
        p99s.append(p99)
        print(f"run {r + 1}: median {med:6.1f} µs   p99 {p99:6.1f} µs   max {ts[-1]:8.1f} µs")
    print(f"median of medians {statistics.median(medians):.1f} µs (spread {min(medians):.1f}-{max(medians):.1f});"
          f" median p99 {statistics.median(p99s):.1f} µs (spread {min(p99s):.1f}-{max(p99s):.1f})")


def _compiled() -> bool:
    import merlin.core.step as s

    return not s.__file__.endswith(".py")


if __name__ == "__main__":
    main()
