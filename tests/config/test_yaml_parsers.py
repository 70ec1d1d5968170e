"""The configuration reader's two YAML parsers (merlin.config.loader): libyaml's, which reads every file when
PyYAML has it, and the pure-Python one, which reports errors. On every YAML file in the repository they must
give the same data and the same line for every key path, or an error message would point at the wrong line
and a file would fly differently depending on how PyYAML was installed."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
import yaml

from merlin.config import loader

ROOT = Path(__file__).resolve().parents[2]


def _yaml_files() -> list[Path]:
    out = subprocess.run(["git", "ls-files", "*.yaml", "*.yml"], cwd=ROOT, capture_output=True, text=True)
    files = [ROOT / line for line in out.stdout.splitlines() if line.strip()]
    if not files:  # not a git checkout (an sdist): the same folders by walking them
        files = [p for d in ("examples", "sims", "tests", "docs") for p in (ROOT / d).rglob("*.y*ml")]
    return sorted(files)


def test_libyaml_is_what_reads_the_files() -> None:
    # the wheels this project installs are built with libyaml; without it the fast path is the slow one
    assert yaml.__with_libyaml__ and loader._FAST_LOADER is yaml.CSafeLoader


@pytest.mark.parametrize("path", _yaml_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_both_parsers_read_every_file_alike(path: Path) -> None:
    text = path.read_text(encoding="utf-8")
    try:
        slow = yaml.load(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        with pytest.raises(loader.ConfigError):  # a broken file on purpose: reported, whichever reads it
            loader.parse_yaml(text, str(path))
        return
    data, lines = loader.parse_yaml(text, str(path))
    assert data == slow
    assert lines == loader._line_index(text, yaml.SafeLoader)
    assert len(lines) > 1 or not isinstance(slow, dict) or len(slow) <= 1


def test_a_broken_file_is_reported_as_the_pure_parser_reports_it() -> None:
    path = ROOT / "tests" / "config" / "data" / "broken_yaml_syntax.yaml"
    text = path.read_text(encoding="utf-8")
    with pytest.raises(yaml.YAMLError) as slow:
        yaml.load(text, Loader=yaml.SafeLoader)
    with pytest.raises(loader.ConfigError) as err:
        loader.parse_yaml(text, str(path))
    mark = slow.value.problem_mark  # type: ignore[attr-defined]
    assert f"line {mark.line + 1}, column {mark.column + 1}: not valid YAML ({slow.value.problem})" in str(
        err.value)  # type: ignore[attr-defined]
