"""Plan a campaign, fly the missing runs on a backend, store each result as it completes.

Backends: ``local`` -- worker processes owned by the driver (spawn context, each retired after
``max_tasks_per_child`` runs to bound its memory), all cores by default; ``ray`` -- Ray tasks, on a local
instance started here when no address is given, or unchanged on a cluster address (the cluster's nodes
need this repository importable; the driver alone writes the campaign directory). Either way the driver
appends each finished run to ``results.jsonl`` at once, so an interrupted campaign loses at most the runs
in flight; the same command resumes it and flies only what is missing. A run that kills its worker twice
is stored as an error (``worker died: ...``) and the campaign goes on.
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import os
import signal
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from multiprocessing.connection import wait as mp_wait
from pathlib import Path
from typing import Any

from merlin._exit import freeze_for_exit
from merlin.campaign.execute import death_cause, execute, worker_died_record, write_run_yaml
from merlin.campaign.spec import CampaignScenario, RunSpec, derive_run, load_campaign_scenario
from merlin.campaign.store import ResultStore, read_results
from merlin.config.loader import ConfigError

REPO_ROOT = Path(__file__).resolve().parents[2]
#: A run whose worker dies is flown again on a fresh worker; when it has cost this many workers it is
#: recorded as an error (``worker died: ...``) instead. Two, not one: a worker can also die of something
#: that is not the run's doing (the out-of-memory killer choosing it, a stray kill).
WORKER_ATTEMPTS = 2
WORKER_READY = "ready"  # a local worker's first message: its imports are done


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
    retry_errors: bool = False  # fly again the runs stored as errors (default: a stored error is final)

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


@dataclass(slots=True)
class _Worker:
    """One worker process of the local backend and the run it is flying (None: idle)."""

    proc: Any
    conn: Any
    spec: RunSpec | None = None
    flown: int = 0
    started: bool = False  # it has said WORKER_READY (imported everything)


def _worker_main(conn: Any) -> None:
    """A local worker: fly each spec the driver sends, send back its record; ``None`` or EOF ends it.

    Ctrl-C reaches the whole foreground process group: the driver handles it and stops its workers, so a
    worker ignores it rather than printing a traceback per run in flight."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    conn.send(WORKER_READY)  # imports done: a death from here on is a run's doing
    while True:
        try:
            spec = conn.recv()
        except (EOFError, OSError):  # the driver is gone
            break
        if spec is None:
            break
        conn.send(execute(spec))
    freeze_for_exit()  # the worker process ends here: no last walks over its objects (merlin._exit)


def _start_worker(ctx: Any) -> _Worker:
    parent, child = ctx.Pipe()
    proc = ctx.Process(target=_worker_main, args=(child,), name="merlin-campaign-worker")
    proc.start()
    child.close()  # the worker's end lives in the worker only: its death shows here as EOF
    return _Worker(proc, parent)


def _stop_worker(w: _Worker, timeout_s: float = 5.0) -> None:
    with contextlib.suppress(OSError, ValueError):  # already gone
        w.conn.send(None)
    w.proc.join(timeout_s if w.spec is None else 0.0)
    if w.proc.is_alive():  # busy (interrupted campaign) or not answering: no clean-up owed to it
        w.proc.kill()
        w.proc.join()
    w.conn.close()


def _receive(w: _Worker) -> Any:
    """The worker's next message if one is waiting (a record or ``WORKER_READY``), else None (nothing
    yet, or the pipe closed because the worker died)."""
    try:
        return w.conn.recv() if w.conn.poll() else None
    except (EOFError, OSError):
        return None


def _hand_over(w: _Worker, todo: deque[RunSpec]) -> bool:
    """Send ``w`` the next run; False (the run stays first in ``todo``) if the worker is already dead: no
    run of its own killed it, so no run is charged."""
    spec = todo.popleft()
    try:
        w.conn.send(spec)
    except OSError:  # BrokenPipeError: nobody reads the other end any more
        todo.appendleft(spec)
        return False
    w.spec = spec
    return True


def _local(specs: list[RunSpec], opts: CampaignOptions, emit: Emit) -> None:
    """Fly ``specs`` on ``n_workers`` processes the driver owns, one run at a time each.

    Each worker is the driver's own ``spawn`` process with a pipe, not a ``ProcessPoolExecutor``: the
    driver always knows which run each worker is flying, so a worker that dies (a run calling
    ``os._exit``, a segfault in a native library, the out-of-memory killer, a stray SIGKILL) costs only
    that run. The run is flown once more on a fresh worker; if that one dies too, the run is recorded as
    an error (:func:`~merlin.campaign.execute.worker_died_record`) and the campaign goes on. The runs on
    the other workers are neither lost nor flown twice. (A pool breaks as a whole: every run in flight
    fails with ``BrokenProcessPool`` and the culprit cannot be told apart.)

    A worker retires after ``max_tasks_per_child`` runs and a fresh one takes its place, which bounds a
    worker's memory. ``ProcessPoolExecutor``'s own ``max_tasks_per_child`` is not usable for this: on
    CPython 3.11 to 3.15.0b3 it deadlocks once a worker exits at its limit while work is queued (CPython
    gh-115634; a 1,000-run campaign hung that way after 2 x 25 runs).
    """
    ctx = multiprocessing.get_context("spawn")
    # spawned workers inherit the environment: the limits must be in it before numpy loads in them
    os.environ.update(worker_env())
    todo = deque(specs)
    deaths: dict[str, list[int]] = {}
    workers: list[_Worker] = []
    per_worker = max(1, opts.max_tasks_per_child)
    try:
        while todo or any(w.spec is not None for w in workers):
            for w in [w for w in workers if w.spec is None]:
                if todo and not _hand_over(w, todo):
                    workers.remove(w)  # an idle worker died: its replacement is started below
                    _stop_worker(w)
            while todo and len(workers) < opts.n_workers:
                w = _start_worker(ctx)
                workers.append(w)
                if not _hand_over(w, todo):
                    workers.remove(w)
                    _stop_worker(w)
                    raise RuntimeError("a campaign worker died as it was started (before its first run)")
            busy = [w for w in workers if w.spec is not None]
            ready = set(mp_wait([w.conn for w in busy] + [w.proc.sentinel for w in busy]))
            for w in busy:
                if w.conn not in ready and w.proc.sentinel not in ready:
                    continue
                spec = w.spec
                assert spec is not None
                msg = _receive(w)
                while msg == WORKER_READY:
                    w.started = True
                    msg = _receive(w)
                if isinstance(msg, dict):
                    w.spec = None
                    w.flown += 1
                    emit(spec, msg)
                    if w.flown >= per_worker:
                        _stop_worker(w)
                        workers.remove(w)
                    continue
                if w.proc.is_alive():
                    continue  # it said it is ready, or a spurious wake-up: the run is still flying
                w.proc.join()
                code = w.proc.exitcode if w.proc.exitcode is not None else 0
                w.conn.close()
                workers.remove(w)
                if not w.started:
                    # before any run could start (imports, environment): a bug to see, not a run to blame
                    raise RuntimeError(f"a campaign worker died while starting ({death_cause(code)}); run "
                                       f"{spec.run_id} was not charged. Is the environment importable?")
                died = deaths.setdefault(spec.run_id, [])
                died.append(code)
                if len(died) >= WORKER_ATTEMPTS:
                    emit(spec, worker_died_record(spec, died))
                else:
                    todo.appendleft(spec)  # once more, on a fresh worker
    finally:
        for w in workers:
            _stop_worker(w)


def start_ray(opts: CampaignOptions) -> bool:
    """Connect to ``opts.address`` or start a local Ray instance of ``n_workers`` CPUs; False (nothing
    done) when Ray is already initialised. A caller flying many batches (the falsifier) starts it once."""
    import ray

    if ray.is_initialized():
        return False
    if opts.address:
        # the cluster's nodes were started by someone else, with their own environment: the tasks get the
        # same thread limits as on one machine (a run is one CPU; numpy must not start a thread per core)
        ray.init(address=opts.address, log_to_driver=False, runtime_env={"env_vars": worker_env()})
    else:
        env = {"PYTHONPATH": os.pathsep.join([str(REPO_ROOT), os.environ.get("PYTHONPATH", "")]),
               **worker_env()}
        ray.init(num_cpus=opts.n_workers, include_dashboard=False, log_to_driver=False,
                 object_store_memory=200 * 1024 * 1024, runtime_env={"env_vars": env})
    return True


def fly(specs: list[RunSpec], opts: CampaignOptions, emit: Emit) -> None:
    """Fly ``specs`` on ``opts.backend`` and call ``emit(spec, record)`` as each finishes (completion
    order), with no store and no plan: for a caller that plans its own runs batch by batch, as the
    falsifier (``merlin.falsify``) does with each optimiser generation."""
    if opts.backend not in ("local", "ray"):
        raise ConfigError("merlin campaign", [f"--backend: {opts.backend!r}; allowed: local, ray"])
    (_ray if opts.backend == "ray" else _local)(specs, opts, emit)


def execute_on_ray(spec: RunSpec) -> dict[str, Any]:
    """:func:`execute` as a Ray task: the record also names the Ray node that flew the run
    (``worker.ray_node_id``; several nodes can share a host name, as on one machine)."""
    import ray

    rec = execute(spec)
    rec["worker"]["ray_node_id"] = ray.get_runtime_context().get_node_id()
    return rec


def _ray(specs: list[RunSpec], opts: CampaignOptions, emit: Emit) -> None:
    import ray

    started = start_ray(opts)
    try:
        # max_retries: Ray flies a task again when its worker process or node is lost (a cluster node
        # killed mid-campaign: tests/campaign/test_ray_cluster.py); after that the run is stored as an
        # error, as on the local backend (WORKER_ATTEMPTS in all)
        task = ray.remote(num_cpus=1, max_retries=WORKER_ATTEMPTS - 1)(execute_on_ray)
        window = 4 * opts.n_workers if not opts.address else 4 * int(ray.cluster_resources().get("CPU", 1))  # type: ignore[no-untyped-call]
        todo = list(specs)
        refs: dict[Any, RunSpec] = {}
        while todo or refs:
            while todo and len(refs) < window:
                s = todo.pop(0)
                refs[task.remote(s)] = s
            ready, _ = ray.wait(list(refs), num_returns=1)
            for r in ready:
                spec = refs.pop(r)
                try:
                    rec = ray.get(r)
                except ray.exceptions.RayError as exc:
                    # the worker or its node died on every attempt (execute itself never raises an
                    # Exception: a run's own crash is already an error record with its traceback)
                    first_line = (str(exc).strip().splitlines() or [""])[0]
                    rec = worker_died_record(spec, [], detail=f"{type(exc).__name__}: {first_line}",
                                             attempts=WORKER_ATTEMPTS)
                emit(spec, rec)
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
    """Fly every planned run not yet in ``out/results.jsonl``; returns all records (old and new).

    A run stored as an error (it raised, or killed its worker twice) counts as done: resuming does not fly
    it again, so a run that kills its worker cannot stall every resume. ``retry_errors`` flies those runs
    again (after a fix, say); the new record replaces the old one (the store keeps both lines, the last
    one wins)."""
    problems = []
    if opts.runs < 1:
        problems.append(f"--runs: must be at least 1, got {opts.runs}")
    if not 0 <= opts.seed < 2**32:
        # each run's seed derives from the campaign seed's low 32 bits (spec.run_seed_sequence): any other
        # value would fly the runs of another seed under its own name
        problems.append(f"--seed: must be in [0, 2^32), got {opts.seed}")
    if opts.workers < 0:
        problems.append(f"--workers: must be >= 0 (0: every core), got {opts.workers}")
    if opts.backend not in ("local", "ray"):
        problems.append(f"--backend: {opts.backend!r}; allowed: local, ray")
    if problems:
        raise ConfigError("merlin campaign", problems)
    scs = scenarios if scenarios is not None else load_scenarios(opts.scenarios)
    specs = plan(scs, opts.runs, opts.seed)
    _check_meta(opts.out, fingerprint(scs, opts.seed))
    results_path = opts.out / "results.jsonl"
    records = read_results(results_path)
    planned_ids = {s.run_id for s in specs}
    todo = [s for s in specs if s.run_id not in records
            or (opts.retry_errors and records[s.run_id].get("status") == "error")]
    todo_ids = {s.run_id for s in todo}
    outcome = Outcome(planned=len(specs), skipped=len(specs) - len(todo))
    failures = sum(1 for r in records.values()
                   if r["run_id"] in planned_ids and r["run_id"] not in todo_ids and not r.get("passed"))
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
