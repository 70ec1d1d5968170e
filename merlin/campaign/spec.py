"""A campaign scenario: an ordinary scenario file plus a top-level ``vary:`` mapping.

``vary`` maps a dotted key path into the scenario (``faults.0.start_s``, ``controller.params.speed_mps``,
``wind.steady_ned_mps.0``, ``config.geofence.margin_m``) to a distribution::

    vary:
      faults.0.start_s: {uniform: [12, 20]}
      controller.params.heading_deg: {choice: [0, 90, 180, 270]}
      wind.steady_ned_mps.0: {normal: [0, 2]}
      config.geofence.margin_m: {int_uniform: [3, 8]}

Each run's seed and samples derive from (campaign seed, SHA-256 of the scenario file, run index) through
numpy's ``SeedSequence``, so a run is reproducible alone and independent of how many workers flew it.
The configuration is inlined into every run's scenario (``config:`` becomes the resolved mapping), so a
run's YAML reproduces it standalone with ``merlin sim``.
"""

from __future__ import annotations

import copy
import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from merlin.config.loader import ConfigError, load_config, parse_yaml, validate_model
from merlin.config.models import MerlinConfig
from merlin.core.types import finite_number
from sims.scenario import Scenario

DISTRIBUTIONS = ("uniform", "normal", "choice", "int_uniform")


@dataclass(frozen=True, slots=True)
class Distribution:
    """One ``vary`` entry: the key path it sets and how its value is drawn."""

    path: str
    kind: str
    args: tuple[Any, ...]

    def centre(self) -> Any:
        if self.kind == "choice":
            return copy.deepcopy(self.args[0])
        if self.kind == "int_uniform":
            return int(self.args[0])
        if self.kind == "normal":
            return float(self.args[0])
        return 0.5 * (float(self.args[0]) + float(self.args[1]))

    def sample(self, rng: np.random.Generator) -> Any:
        if self.kind == "uniform":
            return float(rng.uniform(self.args[0], self.args[1]))
        if self.kind == "normal":
            return float(rng.normal(self.args[0], self.args[1]))
        if self.kind == "int_uniform":
            return int(rng.integers(self.args[0], self.args[1], endpoint=True))
        return copy.deepcopy(self.args[int(rng.integers(len(self.args)))])  # choice


def parse_distribution(path: str, spec: Any, source: str) -> Distribution:
    where = f"vary.{path}"
    if not isinstance(spec, dict) or len(spec) != 1:
        raise ConfigError(source, [f"{where}: expected one of {{{', '.join(DISTRIBUTIONS)}: ...}}, got {spec!r}"])
    kind, args = next(iter(spec.items()))
    if kind not in DISTRIBUTIONS:
        raise ConfigError(source, [f"{where}: unknown distribution {kind!r}; allowed: {list(DISTRIBUTIONS)}"])
    if not isinstance(args, list) or not args:
        raise ConfigError(source, [f"{where}.{kind}: expected a list, got {args!r}"])
    if kind != "choice":
        ok = len(args) == 2 and all(isinstance(a, int | float) and not isinstance(a, bool) for a in args)
        ok = ok and all(finite_number(a) for a in args)  # (an int no float holds too: math.isfinite raised)
        if not ok:
            raise ConfigError(source, [f"{where}.{kind}: expected two finite numbers [a, b], got {args!r}"])
        a, b = args
        if kind in ("uniform", "int_uniform") and a > b:
            raise ConfigError(source, [f"{where}.{kind}: lower bound {a} is above upper bound {b}"])
        if kind == "int_uniform" and (a != int(a) or b != int(b)):
            raise ConfigError(source, [f"{where}.int_uniform: bounds must be integers, got {args!r}"])
        if kind == "int_uniform" and not -(2**63) <= a <= b < 2**63:
            # numpy draws the integer as an int64: a bound beyond it raised at the first run's draw
            raise ConfigError(source, [f"{where}.int_uniform: bounds must be within [-2^63, 2^63), got {args!r}"])
        if kind == "normal" and b < 0:
            raise ConfigError(source, [f"{where}.normal: sigma must be >= 0, got {b}"])
        if kind == "int_uniform":
            args = [int(a), int(b)]
    return Distribution(path, kind, tuple(args))


def _split(path: str) -> list[str | int]:
    return [int(p) if p.lstrip("-").isdigit() else p for p in path.split(".")]


def set_path(data: Any, path: str, value: Any, source: str) -> None:
    """Set ``data[a][b][0]...`` for ``a.b.0``; the container must exist (a typo is an error, not a new key)."""
    keys = _split(path)
    cur = data
    for depth, k in enumerate(keys):
        last = depth == len(keys) - 1
        here = ".".join(str(x) for x in keys[: depth + 1])
        if isinstance(cur, list):
            if not isinstance(k, int) or not -len(cur) <= k < len(cur):
                raise ConfigError(source, [f"vary.{path}: {here} is not an index of a list of {len(cur)}"])
        elif isinstance(cur, dict):
            if isinstance(k, int):
                k = str(k)
            if not last and k not in cur:
                # an optional section that is absent (e.g. controller.params): create the mapping
                cur[k] = {}
        else:
            raise ConfigError(source, [f"vary.{path}: {here} is inside a {type(cur).__name__}, not a mapping"])
        if last:
            cur[k] = value
        else:
            cur = cur[k]


@dataclass(frozen=True, slots=True)
class CampaignScenario:
    """A parsed campaign scenario: the base (``vary`` removed, config inlined) and its distributions."""

    path: Path
    stem: str
    content_sha256: str
    base: dict[str, Any]
    vary: tuple[Distribution, ...]
    base_config: MerlinConfig
    # the top-level fields the file gave or varies: a run is built from these only, so that it flies what
    # merlin sim flies of the same file (a section's presence can be a setting: a redundancy section turns
    # the core's nav_redundancy monitor on, sims.vehicle_loop.core_source)
    given: frozenset[str] = frozenset()


def _inline_config(data: dict[str, Any], base_dir: Path, source: str) -> MerlinConfig:
    raw = data.get("config", "default")
    if isinstance(raw, dict):
        cfg = validate_model(MerlinConfig, raw, f"{source} (config:)", {})
    elif raw == "default":
        cfg = MerlinConfig()
    elif isinstance(raw, str):
        cp = (base_dir / raw).resolve()
        if not cp.exists():
            raise ConfigError(source, [f"config: file {raw!r} not found (looked in {base_dir})"])
        cfg = load_config(cp)
    else:
        raise ConfigError(source, [f"config: expected 'default', a path or a mapping, got {raw!r}"])
    data["config"] = cfg.model_dump(mode="json")
    return cfg


def load_campaign_scenario(path: str | Path) -> CampaignScenario:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(str(p), [f"cannot read the scenario: {exc.strerror or exc}"]) from None
    data, lines = parse_yaml(text, str(p))
    if not isinstance(data, dict):
        raise ConfigError(str(p), ["(top level): expected a mapping of keys"])
    vary_raw = data.pop("vary", None) or {}
    if not isinstance(vary_raw, dict):
        raise ConfigError(str(p), [f"vary: expected a mapping of key path -> distribution, got {vary_raw!r}"])
    sc = validate_model(Scenario, data, str(p), lines)  # the base must be a valid scenario on its own
    # every default written out, so a varied key path (wind.steady_ned_mps.0) exists even if not given
    config_raw = data.get("config", "default")
    data = sc.model_dump(mode="json")
    data["config"] = config_raw
    cfg = _inline_config(data, p.parent, str(p))
    vary = tuple(parse_distribution(str(k), v, str(p)) for k, v in vary_raw.items())
    # a path that does not exist fails now, not hours into the campaign: set every key to its distribution's centre
    probe = copy.deepcopy(data)
    for d in vary:
        set_path(probe, d.path, d.centre(), str(p))
    validate_model(Scenario, probe, f"{p} (vary: each key at its distribution's centre)", {})
    validate_model(MerlinConfig, probe["config"], f"{p} (vary: config keys at their centres)", {})
    given = frozenset(sc.model_fields_set | {d.path.split(".")[0] for d in vary} | {"name", "seed", "config"})
    return CampaignScenario(p, p.stem, hashlib.sha256(text.encode("utf-8")).hexdigest(), data, vary, cfg, given)


def run_seed_sequence(campaign_seed: int, content_sha256: str, index: int) -> np.random.SeedSequence:
    words = [int(content_sha256[i: i + 8], 16) for i in range(0, 32, 8)]
    return np.random.SeedSequence([campaign_seed & 0xFFFFFFFF, *words, index])


@dataclass(frozen=True, slots=True)
class RunSpec:
    """Everything one run needs, plain and picklable: its id, seed, samples and resolved scenario."""

    run_id: str
    index: int
    scenario_file: str
    seed: int
    samples: dict[str, Any]
    scenario: dict[str, Any]


def derive_run(cs: CampaignScenario, campaign_seed: int, index: int, run_id: str) -> RunSpec:
    """The run's resolved scenario; every sample is validated through the scenario model (errors name
    the varied keys and their values)."""
    ss = run_seed_sequence(campaign_seed, cs.content_sha256, index)
    sample_ss, sim_ss = ss.spawn(2)
    rng = np.random.default_rng(sample_ss)
    data = copy.deepcopy(cs.base)
    samples: dict[str, Any] = {}
    for d in cs.vary:
        v = d.sample(rng)
        samples[d.path] = v
        set_path(data, d.path, v, str(cs.path))
    seed = int(sim_ss.generate_state(1, dtype=np.uint32)[0])
    data["seed"] = seed
    data["name"] = f"{data.get('name', cs.stem)}#{run_id}"
    if cs.given:
        data = {k: v for k, v in data.items() if k in cs.given}
    src = f"{cs.path} run {run_id} (samples {samples})"
    validate_model(Scenario, data, src, {})
    validate_model(MerlinConfig, data["config"], f"{src} config", {})
    return RunSpec(run_id, index, str(cs.path), seed, samples, data)
