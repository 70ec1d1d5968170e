"""Plan a campaign, fly the missing runs on a backend, store each result as it completes.

Backends: ``local`` -- a ``ProcessPoolExecutor`` (spawn context, recycled every ``max_tasks_per_child``
runs per worker to bound a worker's memory), all cores by default; ``ray`` -- Ray tasks, on a local instance started here when no
address is given, or unchanged on a cluster address (the cluster's nodes need this repository importable;
the driver alone writes the campaign directory). Either way the driver appends each finished run to
``results.jsonl`` at once, so an interrupted campaign loses at most the runs in flight; the same command
resumes it and flies only what is missing.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import time
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from merlin.campaign.execute import execute, write_run_yaml
from merlin.campaign.spec import CampaignScenario, RunSpec, derive_run, load_campaign_scenario
from merlin.campaign.store import ResultStore, read_results
from merlin.config.loader import ConfigError

REPO_ROOT = Path(__file__).resolve().parents[2]
MAX_POOL_RESTARTS = 3  # a worker lost this many times in one campaign stops it (resume continues it)


@dataclass(frozen=True, slots=True)
class CampaignOptions:
    scenarios: tuple[str, ...]
    runs: int
    out: Path
    seed: int = 0
    backend: str = "local"
    address: str | None = None
    workers: int = 0  # 0: every core
    # A worker's memory stays flat over runs (170-179 MB resident over 48 mixed runs in one process,
    # docs/benchmarks/campaign.md), so a generation can be long: each generation ends with idle workers
    # waiting for the last run, which at 25 runs per worker cost ~10 % of a 2-worker campaign.
    max_tasks_per_child: int = 200
    quiet: bool = True

    @property
    def n_workers(self) -> int:
        return self.workers if self.workers > 0 else (os.cpu_count() or 1)


@dataclass(slots=True)
class Outcome:
    planned: int
    flown_now: int = 0
    skipped: int = 0  # already in the store
    wall_s: float = 0.0
    startup_s: float | None = None  # pool / Ray start-up: first result's arrival minus that run's own time
    records: dict[str, dict[str, Any]] = field(default_factory=dict)


def plan(scenarios: list[CampaignScenario], runs: int, seed: int) -> list[RunSpec]:
    """Run ``i`` flies scenario ``i mod len(scenarios)``; its id and seed do not depend on ``runs``, so a
    campaign can be extended with a larger ``--runs``."""
    out = []
    for i in range(runs):
        cs = scenarios[i % len(scenarios)]
        out.append(derive_run(cs, seed, i, f"{i:05d}-{cs.stem}"))
    return out


def fingerprint(scenarios: list[CampaignScenario], seed: int) -> dict[str, Any]:
    return {"seed": seed, "scenarios": [{"file": str(c.path), "sha256": c.content_sha256} for c in scenarios]}


def _check_meta(out: Path, fp: dict[str, Any]) -> None:
    meta = out / "campaign_meta.json"
    if meta.exists():
        old = json.loads(meta.read_text())
        same = old.get("seed") == fp["seed"] and [s["sha256"] for s in old.get("scenarios", [])] == [
            s["sha256"] for s in fp["scenarios"]]
        if not same:
            raise ConfigError(str(out), [
                f"this directory holds another campaign (seed {old.get('seed')}, scenarios "
                f"{[s['file'] for s in old.get('scenarios', [])]}); resume it with the same seed and unchanged"
                " scenario files, or give a fresh --out"])
    else:
        out.mkdir(parents=True, exist_ok=True)
        tmp = meta.with_suffix(".tmp")
        tmp.write_text(json.dumps(fp, indent=2) + "\n")
        tmp.replace(meta)


Emit = Callable[[RunSpec, dict[str, Any]], None]


#: Each run gets one core: numerical libraries must not start a thread per core inside every worker. With
#: their defaults (OpenBLAS/OpenMP one thread per core, OpenCV's own pool) two workers on two cores ran
#: four-plus busy threads and two workers flew only 1.14x the runs of one; with one thread each, 1.70x
#: (docs/benchmarks/campaign.md). A value the user has set is kept.
WORKER_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                     "NUMEXPR_NUM_THREADS": "1"}


def worker_env() -> dict[str, str]:
    """The thread limits for campaign workers, with any the user has set in the environment kept."""
    return {k: os.environ.get(k, v) for k, v in WORKER_THREAD_ENV.items()}


def _local(specs: list[RunSpec], opts: CampaignOptions, emit: Emit) -> None:
    """Fly ``specs`` on a process pool, recycling the pool every ``max_tasks_per_child`` runs per worker.

    The recycling is done here, by generations of pools, and NOT with ``ProcessPoolExecutor``'s own
    ``max_tasks_per_child``: on CPython 3.11 to 3.15.0b3 that option deadlocks once a worker exits at its
    limit while work is queued (no replacement worker is started; CPython gh-115634). A 1,000-run campaign
    hung that way after 2 x 25 runs.
    """
    ctx = multiprocessing.get_context("spawn")
    # spawned workers inherit the environment: the limits must be in it before numpy loads in them
    os.environ.update(worker_env())
    pending = {s.run_id: s for s in specs}
    restarts = 0
    generation = max(1, opts.max_tasks_per_child) * opts.n_workers
    while pending:
        batch = list(pending.values())[:generation]
        ex = ProcessPoolExecutor(max_workers=min(opts.n_workers, len(batch)), mp_context=ctx)
        try:
            futs = {ex.submit(execute, s): s for s in batch}
            live = set(futs)
            while live:
                done, live = wait(live, return_when=FIRST_COMPLETED)
                for f in done:
                    spec = futs[f]
                    emit(spec, f.result())
                    pending.pop(spec.run_id, None)
            ex.shutdown(wait=True)  # this generation's workers exit before the next one starts
        except BrokenProcessPool:
            # a worker died (killed, out of memory): fly what is missing on a fresh pool
            restarts += 1
            if restarts > MAX_POOL_RESTARTS:
                raise
        finally:
            ex.shutdown(wait=False, cancel_futures=True)


def _ray(specs: list[RunSpec], opts: CampaignOptions, emit: Emit) -> None:
    import ray

    started = False
    if not ray.is_initialized():
        if opts.address:
            ray.init(address=opts.address, log_to_driver=False)
        else:
            env = {"PYTHONPATH": os.pathsep.join([str(REPO_ROOT), os.environ.get("PYTHONPATH", "")]),
                   **worker_env()}
            ray.init(num_cpus=opts.n_workers, include_dashboard=False, log_to_driver=False,
                     object_store_memory=200 * 1024 * 1024, runtime_env={"env_vars": env})
        started = True
    try:
        # max_retries: Ray flies a task again when its worker process or node is lost
        task = ray.remote(num_cpus=1, max_retries=3)(execute)
        window = 4 * opts.n_workers if not opts.address else 4 * int(ray.cluster_resources().get("CPU", 1))  # type: ignore[no-untyped-call]
        todo = list(specs)
        refs: dict[Any, RunSpec] = {}
        while todo or refs:
            while todo and len(refs) < window:
                s = todo.pop(0)
                refs[task.remote(s)] = s
            ready, _ = ray.wait(list(refs), num_returns=1)
            for r in ready:
                emit(refs.pop(r), ray.get(r))
    finally:
        if started:
            ray.shutdown()


def load_scenarios(paths: Iterable[str]) -> list[CampaignScenario]:
    out = [load_campaign_scenario(p) for p in paths]
    if not out:
        raise ConfigError("merlin campaign", ["give at least one scenario file"])
    stems = [c.stem for c in out]
    dup = sorted({s for s in stems if stems.count(s) > 1})
    if dup:
        raise ConfigError("merlin campaign", [f"scenario file names must differ (run ids use them): {dup}"])
    return out


def run_campaign(opts: CampaignOptions, scenarios: list[CampaignScenario] | None = None) -> Outcome:
    """Fly every planned run not yet in ``out/results.jsonl``; returns all records (old and new)."""
    if opts.runs < 1:
        raise ConfigError("merlin campaign", [f"--runs: must be at least 1, got {opts.runs}"])
    if opts.backend not in ("local", "ray"):
        raise ConfigError("merlin campaign", [f"--backend: {opts.backend!r}; allowed: local, ray"])
    scs = scenarios if scenarios is not None else load_scenarios(opts.scenarios)
    specs = plan(scs, opts.runs, opts.seed)
    _check_meta(opts.out, fingerprint(scs, opts.seed))
    results_path = opts.out / "results.jsonl"
    records = read_results(results_path)
    planned_ids = {s.run_id for s in specs}
    todo = [s for s in specs if s.run_id not in records]
    outcome = Outcome(planned=len(specs), skipped=len(planned_ids & set(records)))
    failures = sum(1 for r in records.values() if r["run_id"] in planned_ids and not r.get("passed"))
    bar = None
    if not opts.quiet:
        from tqdm import tqdm

        bar = tqdm(total=len(specs), initial=outcome.skipped, unit="run", desc="campaign", dynamic_ncols=True,
                   smoothing=0.05)
        bar.set_postfix(failures=failures)
    t0 = time.perf_counter()
    with ResultStore(results_path) as store:

        def emit(spec: RunSpec, rec: dict[str, Any]) -> None:
            nonlocal failures
            write_run_yaml(spec, opts.out, opts.seed)
            store.append(rec)
            records[spec.run_id] = rec
            outcome.flown_now += 1
            if outcome.startup_s is None:
                outcome.startup_s = max(0.0, time.perf_counter() - t0 - float(rec.get("wall_s", 0.0)))
            if not rec.get("passed"):
                failures += 1
            if bar is not None:
                bar.update(1)
                bar.set_postfix(failures=failures)

        try:
            if todo:
                (_ray if opts.backend == "ray" else _local)(todo, opts, emit)
        finally:
            outcome.wall_s = time.perf_counter() - t0
            if bar is not None:
                bar.close()
    outcome.records = {k: v for k, v in read_results(results_path).items() if k in planned_ids}
    return outcome
