"""The search: CMA-ES over each adversary class's box, minimising the stop margin, on the campaign backends.

Falsification in the sense of S-TaLiRo and Breach: the property is "the vehicle stays inside the range",
its robustness is the run's least signed fence margin (``min_fence_margin_m``: distance to the nearest
boundary, ceiling or floor at the worst moment; negative is a breach), and an optimiser drives the
adversary's parameters towards the least robustness. The optimiser is CMA-ES (pycma, ``cma``), chosen
because:

* the search space is continuous and bounded (speeds, headings, distances, times), for which CMA-ES is the
  standard derivative-free method, invariant to the parameters' scaling and able to learn their
  correlations (a heading that only matters at a given distance);
* it works in generations: ``ask`` a population, fly it, ``tell`` the margins, so each generation is one
  batch on the campaign's backends (``merlin.campaign.scheduler.fly``: the local worker pool or Ray), and
  the flights of all classes' generations go out together;
* restarts with a doubled population (IPOP-CMA-ES, Auger and Hansen 2005) when a run of the strategy
  converges turn it into a global search of a multimodal landscape (every edge, corner and keep-out is a
  local minimum of its own).

The categorical choice (which adversary) is handled by one CMA-ES per class, the budget split equally.
Everything is deterministic for a seed: the strategies draw from their own seeded generators, the sims
share one seed (the vehicle and its sensors are the same in every run, so the landscape is a function of
the adversary alone), and the records are ordered by evaluation index, never by completion.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from merlin.campaign.spec import RunSpec
from merlin.falsify.space import AdversaryClass, Site

#: A run that errored (the simulation raised) is told to the optimiser as this margin: not a breach it
#: could chase, and reported as an error beside the search's result.
ERROR_MARGIN_M = 1.0e3
SIGMA0 = 0.3  # of the unit box: a first population spread over most of each range


@dataclass(slots=True)
class Evaluation:
    index: int
    adversary: str
    generation: int
    restart: int
    u: list[float]
    values: dict[str, float]
    scenario: dict[str, Any]
    margin_m: float | None = None
    breach_m: float | None = None
    status: str = "pending"
    error: str | None = None
    wall_s: float = 0.0

    @property
    def objective(self) -> float:
        return ERROR_MARGIN_M if self.margin_m is None or not math.isfinite(self.margin_m) else self.margin_m

    def record(self) -> dict[str, Any]:
        return {"index": self.index, "adversary": self.adversary, "generation": self.generation,
                "restart": self.restart, "u": self.u, "values": self.values, "margin_m": self.margin_m,
                "breach_m": self.breach_m, "status": self.status, "error": self.error, "wall_s": self.wall_s,
                "controller": self.scenario.get("controller"), "operator": self.scenario.get("operator"),
                "initial": self.scenario.get("initial"), "wind": self.scenario.get("wind"),
                "duration_s": self.scenario.get("duration_s")}


class ClassSearch:
    """IPOP-CMA-ES on one adversary class: a strategy in the unit box, restarted with a doubled population
    (from a fresh random mean) when it stops."""

    def __init__(self, adv: AdversaryClass, seed_seq: np.random.SeedSequence, budget: int,
                 popsize: int | None = None) -> None:
        self.adv = adv
        self.rng = np.random.default_rng(seed_seq)
        self.budget = budget
        self.used = 0
        self.restart = -1
        self.generation = 0
        self.base_popsize = popsize or 4 + int(3 * math.log(adv.dim))
        self.popsize = self.base_popsize
        self.es: Any = None
        self.best: float = math.inf
        self._new_strategy()

    def _new_strategy(self) -> None:
        import cma

        self.restart += 1
        self.popsize = self.base_popsize * 2 ** self.restart
        x0 = self.rng.uniform(0.15, 0.85, self.adv.dim)
        lower = [None if p.scale == "circ" else 0.0 for p in self.adv.params]
        upper = [None if p.scale == "circ" else 1.0 for p in self.adv.params]
        rng = self.rng
        opts = {"bounds": [lower, upper], "popsize": self.popsize, "verbose": -9,
                "seed": int(rng.integers(1, 2**31 - 1)),  # pycma seeds numpy's global generator with it
                "randn": lambda *shape: rng.standard_normal(shape),  # every draw from this class's own generator
                "tolfun": 1e-2, "tolx": 1e-3, "tolfunhist": 1e-2}
        self.es = cma.CMAEvolutionStrategy(list(x0), SIGMA0, opts)

    @property
    def left(self) -> int:
        return self.budget - self.used

    def ask(self) -> list[np.ndarray]:
        if self.left <= 0:
            return []
        if self.es.stop():
            self._new_strategy()
        xs = [np.asarray(x, dtype=float) for x in self.es.ask()]
        return xs[: self.left]

    def tell(self, xs: list[np.ndarray], fs: list[float]) -> None:
        self.used += len(xs)
        self.best = min([self.best, *fs])
        self.generation += 1
        if len(xs) == self.es.popsize:  # a last, truncated generation is flown but not told
            self.es.tell([list(x) for x in xs], list(fs))


Fly = Callable[[list[RunSpec]], dict[str, dict[str, Any]]]


@dataclass(slots=True)
class SearchResult:
    evaluations: list[Evaluation] = field(default_factory=list)
    restarts: dict[str, int] = field(default_factory=dict)

    def best(self, adversary: str | None = None) -> Evaluation | None:
        ok = [e for e in self.evaluations if e.status == "ok" and (adversary is None or e.adversary == adversary)]
        return min(ok, key=lambda e: (e.objective, e.index)) if ok else None


def search(site: Site, classes: tuple[AdversaryClass, ...], budget: int, seed: int, sim_seed: int, fly: Fly,
           on_generation: Callable[[list[Evaluation]], None] | None = None,
           popsize: int | None = None) -> SearchResult:
    """Run one IPOP-CMA-ES per class, ``budget`` evaluations in all (split equally), one generation of
    every class per batch flown by ``fly`` (run specs in, records by run id out). ``popsize``: the first
    population of each class (default pycma's 4 + 3 ln d)."""
    root = np.random.SeedSequence([seed & 0xFFFFFFFF, 0x4D45524C])  # "MERL": the falsifier's own stream
    children = root.spawn(len(classes))
    shares = [budget // len(classes) + (1 if i < budget % len(classes) else 0) for i in range(len(classes))]
    searches = [ClassSearch(c, ss, n, popsize) for c, ss, n in zip(classes, children, shares, strict=True)]
    result = SearchResult()
    while any(s.left > 0 for s in searches):
        batch: list[tuple[ClassSearch, list[np.ndarray], list[Evaluation]]] = []
        for s in searches:
            xs = s.ask()
            if not xs:
                continue
            evs = []
            for x in xs:
                idx = len(result.evaluations)
                ev = Evaluation(idx, s.adv.name, s.generation, s.restart, [round(float(a), 6) for a in x],
                                s.adv.values(x), s.adv.scenario(site, x, sim_seed))
                ev.scenario["name"] = f"falsify_{s.adv.name}_{idx:05d}"
                result.evaluations.append(ev)
                evs.append(ev)
            batch.append((s, xs, evs))
        specs = [RunSpec(run_id=f"{ev.index:05d}-{ev.adversary}", index=ev.index, scenario_file=f"falsify:{ev.adversary}",
                         seed=sim_seed, samples=ev.values, scenario=ev.scenario) for _, _, evs in batch for ev in evs]
        records = fly(specs)
        for s, xs, evs in batch:
            for ev in evs:
                rec = records.get(f"{ev.index:05d}-{ev.adversary}", {})
                ev.status = str(rec.get("status", "error"))
                ev.wall_s = float(rec.get("wall_s", 0.0))
                if ev.status == "ok":
                    m = rec.get("metrics", {})
                    ev.margin_m = m.get("min_fence_margin_m")
                    ev.breach_m = m.get("max_fence_breach_m")
                else:
                    ev.error = str(rec.get("error", "no record"))
            s.tell(xs, [ev.objective for ev in evs])
        if on_generation is not None:
            on_generation([ev for _, _, evs in batch for ev in evs])
    result.restarts = {s.adv.name: s.restart for s in searches}
    return result


def campaign_fly(backend: str, workers: int, address: str | None, out: Path) -> tuple[Fly, Callable[[], None]]:
    """A ``fly`` on the campaign backends and the function that releases it (Ray, started once here)."""
    from merlin.campaign.scheduler import CampaignOptions, fly, start_ray

    opts = CampaignOptions(scenarios=(), runs=1, out=out, backend=backend, address=address, workers=workers)
    started = start_ray(opts) if backend == "ray" else False

    def run(specs: list[RunSpec]) -> dict[str, dict[str, Any]]:
        got: dict[str, dict[str, Any]] = {}

        def emit(spec: RunSpec, rec: dict[str, Any]) -> None:
            got[spec.run_id] = rec

        fly(specs, opts, emit)
        return got

    def close() -> None:
        if started:
            import ray

            ray.shutdown()

    return run, close
