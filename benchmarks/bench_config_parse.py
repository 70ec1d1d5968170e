"""CPU time to read a YAML file the way Merlin reads configurations, scenarios and vehicle files
(:func:`merlin.config.loader.parse_yaml`: the data and the line index for error messages), with libyaml's
parser (what the reader uses when PyYAML has it) against the pure-Python one, in this process.

The files: the multirotor's vehicle file (read on every run of a campaign, inside the run), the nominal
scenario and the example default configuration (every key, commented). Each is parsed ``--reps`` times per
run; a run's figure is the median of those; several runs give the median and the spread.

    .venv/bin/python benchmarks/bench_config_parse.py [--runs 5] [--reps 50]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import yaml

from merlin.config import loader

ROOT = Path(__file__).resolve().parents[1]
FILES = ("sims/vehicles/quadrotor_default.yaml", "examples/scenarios/nominal.yaml",
         "examples/configs/default.yaml")


def _parse(text: str, fast: bool) -> None:
    loader_cls = loader._FAST_LOADER if fast else yaml.SafeLoader
    yaml.load(text, Loader=loader_cls)
    loader._line_index(text, loader_cls)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--reps", type=int, default=50)
    args = ap.parse_args()
    print(f"libyaml: {yaml.__with_libyaml__}; fast parser {loader._FAST_LOADER.__name__}")
    print("| file | bytes | libyaml, ms (median, spread) | pure Python, ms (median, spread) | ratio |")
    print("|---|---|---|---|---|")
    for rel in FILES:
        path = ROOT / rel
        if not path.exists():
            continue
        text = path.read_text(encoding="utf-8")
        per: dict[bool, list[float]] = {True: [], False: []}
        for _ in range(args.runs):
            for fast in (True, False):  # alternating, so both see the same minutes
                times = []
                for _ in range(args.reps):
                    c0 = time.process_time()
                    _parse(text, fast)
                    times.append(time.process_time() - c0)
                per[fast].append(statistics.median(times) * 1e3)
        f, s = per[True], per[False]
        print(f"| {rel} | {len(text)} | {statistics.median(f):.3f} ({min(f):.3f}-{max(f):.3f}) |"
              f" {statistics.median(s):.3f} ({min(s):.3f}-{max(s):.3f}) |"
              f" {statistics.median(s) / statistics.median(f):.1f}× |", flush=True)


if __name__ == "__main__":
    main()
