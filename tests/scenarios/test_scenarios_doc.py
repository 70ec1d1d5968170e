"""docs/scenarios.md keeps up with the scenario format: every shipped scenario file is named in it, and so
are every expectation type, every expectation field and every camera setting a scenario may use."""

from __future__ import annotations

import itertools
import re
from pathlib import Path

from sims.scenario import Camera, Expectation

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "scenarios.md"


def _named_files(text: str) -> set[str]:
    """File names in backticks, with shell-style brace groups expanded (``figure4_{a,b}_{3,6}mps.yaml``)."""
    names: set[str] = set()
    for token in re.findall(r"`([^`\s]+\.yaml)`", text):
        parts = re.split(r"\{([^}]*)\}", token)
        choices = [[p] if i % 2 == 0 else p.split(",") for i, p in enumerate(parts)]
        names.update("".join(c) for c in itertools.product(*choices))
    return names


def test_every_shipped_scenario_is_named_in_the_docs():
    named = _named_files(DOC.read_text(encoding="utf-8"))
    shipped = {p.name for p in (ROOT / "examples" / "scenarios").glob("*.yaml")}
    missing = sorted(shipped - named)
    assert not missing, f"docs/scenarios.md does not name {missing}: add a row to 'Shipped scenarios'"


def test_every_expectation_type_and_field_is_documented():
    text = DOC.read_text(encoding="utf-8")
    kinds = Expectation.model_fields["type"].annotation.__args__
    missing = [k for k in kinds if f"`{k}`" not in text]
    assert not missing, f"docs/scenarios.md, 'Expectations': no row for {missing}"
    fields = [f for f in Expectation.model_fields if f not in ("type", "name")]
    missing = [f for f in fields if f"`{f}`" not in text]
    assert not missing, f"docs/scenarios.md, 'Expectations': fields {missing} are not described"


def test_every_camera_setting_is_documented():
    text = DOC.read_text(encoding="utf-8")
    missing = [f for f in Camera.model_fields if f"`{f}`" not in text]
    assert not missing, f"docs/scenarios.md, 'Camera': settings {missing} are not described"
