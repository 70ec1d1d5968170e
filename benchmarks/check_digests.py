"""Safety net for performance work on the closed loop: every shipped scenario must decide exactly as before.

Runs each scenario of ``examples/scenarios/*.yaml`` with :func:`sims.runner.run_scenario` and reduces its
result to digests: the run's own ``decisions_digest`` (SHA-256 of every log column), and SHA-256 of the
events, the metrics, the fence triggers, the controller log and the EKF's nav trace. A speed-up is
acceptable only if every digest is bit-identical to the one recorded before it.

Left out of the digests, because they legitimately differ between two runs of the same code: the metrics
``wall_time_s`` and ``realtime_factor`` and the nav trace's ``cpu_*`` figures (time measurements), and an
event's ``traceback`` (it names source lines, which move when the runner is edited). Caveat
(``sims/runner.py``'s docstring): a plug-in controller that overruns its CPU budget makes a run depend on
the machine; no shipped scenario does by design, but a host that charges a stall to the plug-in's thread
can make one overrun: the script names every run that had an overrun (``OVERRUN``), and a changed one says so.

    # before the change: record
    .venv/bin/python benchmarks/check_digests.py --record /tmp/digests_before.json --fixed-wing
    # after each change: compare (exit status 1 and the differing parts named when anything moved)
    .venv/bin/python benchmarks/check_digests.py --check /tmp/digests_before.json --fixed-wing

To check that the 100 Hz default (``core_dt_s`` and ``nav_dt_s`` not given: 10 ms, rounded down to whole
ticks; the filter's only with the EKF) flies exactly what the same periods given by hand flew before it,
record on a tree from before the default with ``--at-default-periods`` (each scenario that leaves a period
unset flown at the default's value), then check on the tree with the default.

Options: ``--skip-ekf`` leaves out the ``estimator: ekf`` scenarios (4-10 s CPU each, the others 1-5 s),
``--fixed-wing`` adds the JSBSim fixed-wing (``vehicle: aerosonde``) ones, ``-k TEXT`` keeps the scenarios
whose file name contains TEXT (repeatable). A check compares only the scenarios it ran. The EKF scenarios
also depend on ``merlin/nav`` and ``sims/vision_loop.py``: if those change between the record and the
check, record the baseline again from a copy of the old tree with the new files in it (``PYTHONPATH``
pointing at the copy runs it), then check.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from sims.runner import FIXED_WING_VEHICLES, RunResult, run_scenario
from sims.scenario import Scenario, load_scenario

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "examples" / "scenarios"
#: metrics that measure time, not behaviour
TIMING_METRICS = ("wall_time_s", "realtime_factor")


def _canon(obj: Any) -> Any:
    """``obj`` as plain JSON-able data: arrays by dtype, shape and the SHA-256 of their bytes (their repr
    elides the middle of long arrays), CPU-time measurements (``cpu_*`` keys) left out."""
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        return ["ndarray", a.dtype.str, list(a.shape), hashlib.sha256(a.tobytes()).hexdigest()]
    if isinstance(obj, dict):
        return {str(k): _canon(v) for k, v in obj.items() if not str(k).startswith("cpu_")}
    if isinstance(obj, list | tuple):
        return [_canon(v) for v in obj]
    return obj


def _sha(obj: Any) -> str:
    # repr of a float is exact (shortest round-trip), so equal text means bit-identical numbers
    text = json.dumps(_canon(obj), sort_keys=True, default=repr, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def digests(r: RunResult) -> dict[str, str]:
    log = hashlib.sha256()
    for key in sorted(r.log):
        a = np.ascontiguousarray(r.log[key])
        log.update(f"{key}:{a.dtype.str}:{a.shape}".encode())
        log.update(a.tobytes())
    return {
        "decisions_digest": r.decisions_digest,
        "log": log.hexdigest(),
        "events": _sha([{k: v for k, v in e.items() if k != "traceback"} for e in r.events]),
        "metrics": _sha({k: v for k, v in r.metrics.items() if k not in TIMING_METRICS}),
        "fence_triggers": _sha(r.fence_triggers),
        "controller_log": _sha(r.controller_log),
        "nav": _sha(r.nav),
    }


def _at_default_periods(sc: Scenario) -> Scenario:
    """``sc`` with each of ``core_dt_s`` and ``nav_dt_s`` it leaves unset at what the 100 Hz default gives it:
    10 ms rounded down to whole ticks (at least one), the filter's only with the EKF. Written out here, not
    imported, so that it runs on a tree from before the default."""
    period = max(1, int(0.01 / sc.dt_s + 1e-9)) * sc.dt_s
    update: dict[str, Any] = {}
    if sc.core_dt_s is None:
        update["core_dt_s"] = period
    if sc.nav_dt_s is None and sc.estimator == "ekf":
        update["nav_dt_s"] = period
    # Scenario.with_fields written out: the fields the scenario gave, so that a section it left out stays out
    return Scenario.model_validate({**sc.model_dump(exclude_unset=True), **update}) if update else sc


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument("--record", type=Path, help="write the digests to this JSON file")
    mode.add_argument("--check", type=Path, help="compare with the digests in this JSON file")
    ap.add_argument("--skip-ekf", action="store_true", help="leave out the estimator: ekf scenarios")
    ap.add_argument("--fixed-wing", action="store_true", help="include the JSBSim fixed-wing scenarios")
    ap.add_argument("-k", action="append", default=[], help="only scenario files whose name contains this")
    ap.add_argument("--at-default-periods", action="store_true",
                    help="fly a period a scenario leaves unset (null) at what the 100 Hz default resolves it to")
    a = ap.parse_args()

    results: dict[str, dict[str, str]] = {}
    overruns: dict[str, str] = {}
    for path in sorted(SCENARIOS.glob("*.yaml")):
        if a.k and not any(s in path.name for s in a.k):
            continue
        sc, cfg = load_scenario(path)
        if sc.vehicle in FIXED_WING_VEHICLES and not a.fixed_wing:
            continue
        if sc.estimator == "ekf" and a.skip_ekf:
            continue
        if a.at_default_periods:
            sc = _at_default_periods(sc)
        c0 = time.process_time()
        run = run_scenario(sc, cfg, source=str(path))
        d = digests(run)
        results[path.stem] = d
        over = [e for e in run.events if e.get("type") == "controller_fault" and e.get("kind") == "cpu_budget"]
        if over:  # the one input of a simulated run that depends on the machine (module docstring)
            overruns[path.stem] = f"{len(over)} CPU-budget overrun(s), the first at {over[0]['t']:.4f} s: {over[0]['detail']}"
        print(f"{path.stem:34s} {time.process_time() - c0:6.1f} s CPU  {d['decisions_digest'][:16]}", flush=True)

    if a.record:
        a.record.write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")
        print(f"recorded {len(results)} scenarios in {a.record}")
        return 0
    before = json.loads(a.check.read_text())
    bad = 0
    for name, d in results.items():
        if name not in before:
            print(f"NEW      {name}: not in {a.check}")
            bad += 1
            continue
        moved = [k for k in d if d[k] != before[name].get(k)]
        if moved:
            print(f"CHANGED  {name}: {', '.join(moved)}"
                  + (f" (the plug-in controller's {overruns[name]})" if name in overruns else ""))
            bad += 1
    for name, text in overruns.items():
        print(f"OVERRUN  {name}: {text}")
    print(f"{len(results) - bad} of {len(results)} scenarios bit-identical to {a.check}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
