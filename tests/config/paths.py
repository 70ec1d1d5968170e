"""Where the files under test are: found from this file, never from the machine's layout."""

from __future__ import annotations

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = REPO_ROOT / "examples" / "configs"
DATA = Path(__file__).resolve().parent / "data"
EXAMPLE_FILES = sorted(EXAMPLES.glob("*.yaml"))
BROKEN_FILES = sorted(DATA.glob("broken_*.yaml"))
