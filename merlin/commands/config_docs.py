"""``merlin config-docs [--check]``: regenerate, or check, the configuration's schema and reference page.

Writes ``docs/config.schema.json`` and ``docs/config-reference.md`` from the pydantic models
(:mod:`merlin.config.docs`). With ``--check`` nothing is written: exit 1 if a committed file is missing or
differs from what the models generate (the docs drifted: run ``merlin config-docs`` and commit).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from merlin.config import docs


def run(args: argparse.Namespace) -> int:
    root: Path = args.root
    if not (root / "pyproject.toml").is_file():
        print(
            f"merlin config-docs: {root} is not the Merlin repository (no pyproject.toml); "
            "pass the repository with --root",
            file=sys.stderr,
        )
        return 2
    if args.check:
        stale = docs.stale(root)
        for path in stale:
            print(f"merlin config-docs: {path} is out of date; run `merlin config-docs`", file=sys.stderr)
        if not stale:
            print("merlin config-docs: docs are up to date")
        return 1 if stale else 0
    changed = docs.write(root)
    for rel in docs.generated_files():
        state = "written" if root / rel in changed else "unchanged"
        print(f"{rel}: {state}")
    return 0


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "config-docs",
        help="generate docs/config.schema.json and docs/config-reference.md from the config models",
        description=(
            "Generate docs/config.schema.json and docs/config-reference.md from the configuration models. "
            "With --check, write nothing and exit 1 if a committed file is missing or out of date."
        ),
    )
    p.add_argument("--check", action="store_true", help="write nothing; exit 1 if the files are out of date")
    p.add_argument(
        "--root",
        type=Path,
        default=docs.REPO_ROOT,
        help="the repository to write into (default: the one this module is in)",
    )
    p.set_defaults(func=run)
