"""Fly one campaign run in the worker and return its compact summary (never the heavy log).

Runs in a worker process (local pool or Ray). Anything the run raises becomes an ``error`` record with
its traceback: a crashed run is evidence, never silently dropped.
"""

from __future__ import annotations

import math
import signal
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from merlin.campaign.spec import RunSpec


def run_yaml_path(out_dir: Path, run_id: str) -> Path:
    return out_dir / "runs" / f"{run_id}.yaml"


def write_run_yaml(spec: RunSpec, out_dir: Path, campaign_seed: int) -> Path:
    p = run_yaml_path(out_dir, spec.run_id)
    p.parent.mkdir(parents=True, exist_ok=True)
    head = (f"# campaign run {spec.run_id}: {spec.scenario_file}, run index {spec.index}, campaign seed "
            f"{campaign_seed}\n# samples: {spec.samples}\n# reproduce: merlin sim {p} --out <dir>\n")
    tmp = p.with_suffix(".tmp")
    tmp.write_text(head + yaml.safe_dump(spec.scenario, sort_keys=False), encoding="utf-8")
    tmp.replace(p)
    return p


def takeover_latency_s(events: list[dict[str, Any]]) -> float | None:
    """From the first injected fault's onset to the first revocation at or after it (None: no fault or
    no revocation)."""
    starts = [e["t"] for e in events if e.get("type") == "fault_start"]
    if not starts:
        return None
    t0 = min(starts)
    rev = [e["t"] for e in events if e.get("type") == "revoked" and e["t"] >= t0 - 1e-9]
    return min(rev) - t0 if rev else None


def nav_error_max_m(log: dict[str, np.ndarray]) -> float | None:
    if "est_n" not in log or not len(log["est_n"]):
        return None
    err = np.hypot(log["est_n"] - log["truth_n"], log["est_e"] - log["truth_e"])
    return float(np.nanmax(err))


def one_thread_per_run() -> dict[str, Any]:
    """OpenCV keeps its own thread pool (one thread per core), outside OMP_NUM_THREADS: limit it too, so a
    worker flying a camera scenario uses the one core it was given (see scheduler.WORKER_THREAD_ENV).
    Returns the worker's thread settings, kept in the run's record."""
    import os

    import cv2

    if cv2.getNumThreads() != 1:
        cv2.setNumThreads(1)
    return {"OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS"),
            "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS"), "opencv": cv2.getNumThreads()}


def _identity(spec: RunSpec) -> dict[str, Any]:
    return {"run_id": spec.run_id, "index": spec.index, "scenario_file": spec.scenario_file,
            "scenario": spec.scenario.get("name", ""), "seed": spec.seed, "samples": spec.samples}


def expectation_names(scenario: dict[str, Any]) -> list[str]:
    """The names the run's expectations are reported under, for a run that never got to evaluate them (a
    crash counts against each, merlin.campaign.aggregate)."""
    raw = scenario.get("expectations") or []
    try:
        from sims.expectations import _describe  # the naming the verdicts use
        from sims.scenario import Expectation

        return [_describe(Expectation.model_validate(x)) for x in raw]
    except Exception:  # an invalid expectation is itself why the run crashed: name it as written
        return [str(x.get("name") or x.get("type")) if isinstance(x, dict) else str(x) for x in raw]


def death_cause(exitcode: int) -> str:
    """``exit code 3`` or ``killed by signal SIGKILL (9)`` (multiprocessing's negative exit codes)."""
    if exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = "signal"
        return f"killed by signal {name} ({-exitcode})"
    return f"exit code {exitcode}"


def worker_died_record(spec: RunSpec, exitcodes: list[int], detail: str = "",
                       attempts: int | None = None) -> dict[str, Any]:
    """The record of a run whose worker process died on every attempt (``exitcodes``, one per attempt;
    empty when the backend reports only ``detail``, as Ray does). There is no traceback: the process that
    could have written one is gone. ``merlin sim`` on the run's YAML reproduces the crash in the
    foreground."""
    causes = list(dict.fromkeys(death_cause(c) for c in exitcodes))  # each cause once, in order
    why = "; ".join(causes) if causes else detail
    n = attempts if attempts is not None else len(exitcodes)
    tries = f" ({n} attempts)" if n > 1 else ""
    return {**_identity(spec), "run_yaml": f"runs/{spec.run_id}.yaml", "status": "error", "passed": False,
            "error": f"worker died: {why}{tries}", "traceback": None, "worker_died": True,
            "expectation_names": expectation_names(spec.scenario),
            "worker_exit_codes": exitcodes, "wall_s": 0.0}


def where_flown() -> dict[str, Any]:
    """The machine and process that flew a run, kept in its record (``worker``): which node of a cluster
    flew what is otherwise lost once the campaign is over, and a run that misbehaves on one machine only
    is found by it. Like the timings, it differs between two flights of the same run."""
    import os
    import socket

    return {"host": socket.gethostname(), "pid": os.getpid()}


def execute(spec: RunSpec) -> dict[str, Any]:
    """Fly ``spec``; the record for ``results.jsonl``. Reads and writes no file: on a Ray cluster the
    worker's machine need not share the campaign directory (the driver writes the run's YAML)."""
    wall0 = time.perf_counter()
    rec: dict[str, Any] = {**_identity(spec), "threads": one_thread_per_run(), "worker": where_flown()}
    try:
        rec["run_yaml"] = f"runs/{spec.run_id}.yaml"
        p = Path(rec["run_yaml"])
        from merlin.config.loader import validate_model
        from sims.expectations import evaluate_all
        from sims.runner import run_scenario
        from sims.scenario import Scenario, resolve_config

        sc = validate_model(Scenario, spec.scenario, str(p), {})
        cfg = resolve_config(sc, p.parent, str(p))
        result = run_scenario(sc, cfg, source=str(p))
        verdicts = evaluate_all(sc.expectations, result.events, result.log, result.metrics)
        revs = [{"t": e["t"], "reason": e.get("reason", ""), "text": e.get("reason_detail", {}).get("text", "")}
                for e in result.events if e.get("type") == "revoked"]
        m = result.metrics
        rec.update({
            "status": "ok",
            "passed": all(v.passed for v in verdicts),
            "estimator": sc.estimator,
            "expectations": [v.to_dict() for v in verdicts],
            "config_sha256": result.config_sha256,
            "log_digest_sha256": result.decisions_digest,
            "revocations": revs,
            "metrics": {
                "min_fence_margin_m": m["min_fence_margin_m"],
                "max_fence_breach_m": m["max_fence_breach_m"],
                "takeover_latency_s": takeover_latency_s(result.events),
                "nav_error_max_m": nav_error_max_m(result.log),
                "max_command_jump_mps": m["max_authority_change_command_jump_mps"],
                "final_distance_from_home_m": m["final_distance_from_home_m"],
                "sim_time_s": sc.duration_s,
            },
            "run_wall_s": m["wall_time_s"],
        })
    except Exception as exc:  # a crashing run is recorded, with its traceback, and the campaign goes on
        rec.update({"status": "error", "passed": False, "error": f"{type(exc).__name__}: {exc}",
                    "traceback": traceback.format_exc(), "expectation_names": expectation_names(spec.scenario)})
    rec["wall_s"] = time.perf_counter() - wall0
    for k, v in list(rec.get("metrics", {}).items()):
        if isinstance(v, float) and not math.isfinite(v):
            rec["metrics"][k] = None
    return rec
