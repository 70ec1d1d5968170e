"""Benchmark: hardware redundancy in the closed loop — the shipped redundancy scenarios over several seeds.

Run: .venv/bin/python benchmarks/bench_redundancy_loop.py [--seeds 52 1 2 3] [-k NAME] [--rtf-runs 3]
     [--compare-alert-feed] [--seed000] [--fdi-preset sequential] [--json out.json]

For every redundancy scenario (``examples/scenarios``: the IMU, sensor-lane and autopilot-lane ones) and
every seed: whether all its expectations were met, the simulated times of its key events after the fault
(isolations, the duplex FDI's verdict, lane switches, the core's warning), GPS exclusions and revocations.
Times are simulated time, so the machine's load does not enter them. ``--rtf-runs N`` also flies each
scenario N times on its own seed and reports the closed loop's real-time factor (simulated s / wall s,
median and range): the cost of three EKFs per tick with ``lane_navigation: own``.
``--compare-alert-feed`` flies the yaw-bias duplex scenario with the estimator fed the voted mean during
the FDI's alert (seed 003 §2, the previous behaviour) beside Merlin's lowest-residual lane.
``--compare-attribution`` flies the sub-alert gyro-bias scenario with Merlin's sub-alert attribution
(merlin/redundancy/attribution.py) switched off (seed 003's FDI alone, the previous behaviour) beside it on.
``--seed000`` flies seed 000's three experiments (``seed000_*``: GPS failure, magnetometer failure,
communication loss of lane 0) with the ``thesis`` and ``fast`` presets on the shipped seed and ``--seeds``,
and tabulates, from the fault's onset, when lane 0 charges itself, when its peers charge it or mark it
silent (detection), the lane switch (replacement) and the motor-command steps at the switch against the
bumpless limit, median and range over the seeds, beside the thesis's Table 6.1.
``--fdi-preset NAME`` flies the duplex-FDI scenarios (``DUPLEX_SCENARIOS``) with that FDI preset instead
of the one each file names (the ``sequential`` preset's closed-loop check).
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path
from typing import Any

import sims.runner as runner_mod
from sims.expectations import evaluate_all
from sims.runner import run_scenario
from sims.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = [
    "imu_stuck_isolated", "imu_second_fault_duplex", "imu_second_fault_yaw", "sensor_lanes_isolated",
    "autopilot_lane_failure", "autopilot_lane_self_isolation", "autopilot_lane_own_sensors",
    "redundancy_sub_alert_gyro_bias",
]
# every scenario whose IMU pair the duplex particle-filter FDI arbitrates (a ``fdi_preset`` applies)
DUPLEX_SCENARIOS = [
    "imu_second_fault_duplex", "imu_second_fault_yaw", "redundancy_sub_alert_gyro_bias",
    "redundancy_sub_alert_accel_bias", "redundancy_accel_bias_long_alert", "redundancy_duplex_bias_at_threshold",
    "redundancy_duplex_bias_near_field", "redundancy_duplex_declaration_cross_check",
    "redundancy_duplex_instant_declaration", "redundancy_duplex_marginal_declaration",
]
# seed 000 Table 6.1: detection and replacement times, s after the fault's injection
SEED000_TABLE_6_1 = {"gps_failure": (6.0, 10.0), "mag_failure": (43.0, 46.0), "comm_loss": (4.0, 7.0)}
SEED000 = [f"seed000_{e}_{p}" for e in SEED000_TABLE_6_1 for p in ("thesis", "fast")]
KEY_EVENTS = ("imu_isolated", "imu_alert", "imu_fault_declared", "imu_attributed", "imu_duplex_unresolved",
              "baro_isolated", "gps_isolated", "mag_isolated",
              "autopilot_peer_silent", "autopilot_self_isolated", "autopilot_lane_switch", "warning",
              "nav_excluded", "revoked")


def _seed000_times(events: list[dict[str, Any]], fault_t: float) -> dict[str, float | None]:
    """Seed 000's times after the fault's onset: lane 0 charging itself, its first peer charging it or
    marking it silent (the thesis's detection), the first lane switch (its replacement)."""
    def first(pred: Any) -> float | None:
        ts = [e["t"] - fault_t for e in events if e["t"] >= fault_t - 1e-9 and pred(e)]
        return min(ts) if ts else None
    peer = lambda e: e.get("lane") == 0 and str(e.get("detail", "")) != "seen by lane 0"  # noqa: E731
    return {"self_charge_s": first(lambda e: e["type"] == "autopilot_flag_fault" and not peer(e) and e.get("lane") == 0),
            "detection_s": first(lambda e: e["type"] in ("autopilot_flag_fault", "autopilot_peer_silent") and peer(e)),
            "replacement_s": first(lambda e: e["type"] == "autopilot_lane_switch")}


def _fly(name: str, seed: int | None, alert_feed: str | None = None, attribution: bool = True,
         fdi_preset: str | None = None) -> dict[str, Any]:
    path = ROOT / "examples" / "scenarios" / f"{name}.yaml"
    sc, cfg = load_scenario(path, seed=seed)
    if fdi_preset is not None:
        sc = sc.model_copy(update={"redundancy": sc.redundancy.model_copy(update={"fdi_preset": fdi_preset})})
    loop: Any = runner_mod.make_loop(sc, cfg, str(path))
    if alert_feed is not None or not attribution:
        chain = loop.redundancy.voter.suite.imu
        if alert_feed is not None:
            chain.alert_feed = alert_feed
        if not attribution:
            chain.attribution_config = None  # read when the duplex pair forms
    r = run_scenario(sc, cfg, source=str(path), loop=loop)
    verdicts = evaluate_all(sc.expectations, r.events, r.log, r.metrics)
    fault_t = min((f.start_s for f in sc.faults), default=0.0)
    first: dict[str, str] = {}
    for e in r.events:
        if e["type"] in KEY_EVENTS and e["t"] >= fault_t - 0.05:
            key = e["type"] + (f"[{e['lane']}]" if isinstance(e.get("lane"), int) and e["lane"] >= 0 else "")
            first.setdefault(key, f"{e['t']:.3f}")
    return {"scenario": name, "seed": sc.seed, "passed": sum(v.passed for v in verdicts), "of": len(verdicts),
            "failed": [v.name for v in verdicts if not v.passed], "events": first,
            "seed000": _seed000_times(r.events, fault_t) if name.startswith("seed000_") else {},
            "metrics": {k: r.metrics[k] for k in ("revocations", "lane_switches", "max_lane_switch_added_step",
                                                  "max_lane_switch_motor_step", "max_motor_step_outside_switches",
                                                  "lane_switch_command_delay_ticks", "bumpless_limit")
                        if k in r.metrics},
            "realtime_factor": r.metrics["realtime_factor"]}


def _stat(vals: list[float | None], digits: int = 2) -> str:
    """Median (range) of the values present, and how many runs lacked the event."""
    got = [v for v in vals if v is not None]
    if not got:
        return "none"
    miss = len(vals) - len(got)
    return (f"{statistics.median(got):.{digits}f} ({min(got):.{digits}f}-{max(got):.{digits}f})"
            + (f" [{miss} run(s) without]" if miss else ""))


def _seed000_table(runs: list[dict[str, Any]]) -> None:
    """Median (range) over the seeds of each seed 000 scenario, beside Table 6.1."""
    print("\n### seed 000 in closed loop, s after the fault's onset: median (range) over the seeds")
    print("scenario | runs meeting every expectation | lane 0 charges itself | detection | replacement | "
          "step added at the switch | largest step near the switch | bumpless limit | thesis det. / repl.")
    for name in SEED000:
        rows = [r for r in runs if r["scenario"] == name]
        if not rows:
            continue
        th = SEED000_TABLE_6_1[name.removeprefix("seed000_").rsplit("_", 1)[0]]
        times = [_stat([r["seed000"][k] for r in rows]) for k in ("self_charge_s", "detection_s", "replacement_s")]
        steps = [_stat([r["metrics"].get(k) for r in rows], 4)
                 for k in ("max_lane_switch_added_step", "max_lane_switch_motor_step", "bumpless_limit")]
        print(f"{name} | {sum(r['passed'] == r['of'] for r in rows)}/{len(rows)} | {' | '.join(times)} | "
              f"{' | '.join(steps)} | {th[0]:g} / {th[1]:g}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="*", default=[])
    ap.add_argument("-k", action="append", default=[])
    ap.add_argument("--rtf-runs", type=int, default=0)
    ap.add_argument("--compare-alert-feed", action="store_true")
    ap.add_argument("--compare-attribution", action="store_true")
    ap.add_argument("--seed000", action="store_true", help="seed 000's three experiments (SEED000) instead")
    ap.add_argument("--fdi-preset", help="fly the duplex-FDI scenarios (DUPLEX_SCENARIOS) with this FDI preset")
    ap.add_argument("--json")
    args = ap.parse_args()
    pool = SEED000 if args.seed000 else DUPLEX_SCENARIOS if args.fdi_preset else SCENARIOS
    names = [n for n in pool if not args.k or any(k in n for k in args.k)]
    out: dict[str, Any] = {"runs": [], "rtf": {}, "alert_feed": [], "attribution": []}
    for name in names:
        for seed in [None, *args.seeds]:
            row = _fly(name, seed, fdi_preset=args.fdi_preset)
            out["runs"].append(row)
            print(f"{name:32s} seed {row['seed']:3d}: {row['passed']}/{row['of']} met"
                  f"{' FAILED ' + str(row['failed']) if row['failed'] else ''}  {row['events']}  {row['metrics']}",
                  flush=True)
        if args.rtf_runs:
            rtfs = []
            for _ in range(args.rtf_runs):
                rtfs.append(_fly(name, None)["realtime_factor"])  # wall time of the whole run (run_scenario)
            out["rtf"][name] = rtfs
            print(f"{name:32s} real-time factor median {statistics.median(rtfs):.2f} (range {min(rtfs):.2f}-"
                  f"{max(rtfs):.2f}, {len(rtfs)} runs)", flush=True)
    if args.seed000:
        _seed000_table(out["runs"])
    if args.compare_alert_feed:
        for feed in ("mean", "lowest_residual"):
            for seed in [None, *args.seeds]:
                row = _fly("imu_second_fault_yaw", seed, feed)
                out["alert_feed"].append({"feed": feed, **row})
                print(f"alert feed {feed:15s} seed {row['seed']:3d}: {row['passed']}/{row['of']} met "
                      f"{row['failed']}  {row['events']}", flush=True)
    if args.compare_attribution:
        for on in (False, True):
            for seed in [None, *args.seeds]:
                row = _fly("redundancy_sub_alert_gyro_bias", seed, attribution=on)
                out["attribution"].append({"attribution": on, **row})
                print(f"sub-alert attribution {'on ' if on else 'off'} seed {row['seed']:3d}: {row['passed']}/{row['of']}"
                      f" met {row['failed']}  {row['events']}", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
