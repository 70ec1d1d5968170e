"""`merlin --version`, `merlin.__version__`, shipped examples by name, and the plotting modules leaving an
importer's matplotlib backend alone (only the `merlin` command picks one)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import merlin
from merlin.cli import main
from merlin.resources import examples_dir, schema_path, shipped

ROOT = Path(__file__).resolve().parents[2]


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    assert merlin.__version__ and merlin.__version__ != "0+unknown"
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"merlin {merlin.__version__}"


def test_shipped_examples_by_name(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    assert examples_dir() == ROOT / "examples" and schema_path() == ROOT / "docs" / "config.schema.json"
    assert shipped("nominal", "scenarios") == ROOT / "examples" / "scenarios" / "nominal.yaml"
    assert shipped("default", "configs") == ROOT / "examples" / "configs" / "default.yaml"
    assert shipped("no_such_thing", "scenarios") == Path("no_such_thing")  # the command then says not found
    mine = tmp_path / "nominal"
    mine.write_text("x")
    monkeypatch.chdir(tmp_path)  # restored after the test: later tests load scenarios by relative path
    assert shipped("nominal", "scenarios") == Path("nominal")  # a file of that name wins


def test_plot_modules_keep_the_importers_backend() -> None:
    code = ("import matplotlib; matplotlib.use('pdf'); import sims.report, sims.nav_report, sims.redundancy_plot, "
            "merlin.campaign.plots, merlin.commands.replay; print(matplotlib.get_backend())")
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT,
                         timeout=120, check=True).stdout
    assert out.strip() == "pdf"
