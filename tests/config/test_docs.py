"""The committed schema and reference page are what the models generate (``merlin config-docs --check``)."""

from __future__ import annotations

import json
import shutil

import pytest
import yaml

from merlin.cli import main
from merlin.config import docs
from merlin.config.models import ENVELOPE_PARAMETERS, MONITORS, MerlinConfig
from tests.config.paths import DATA, EXAMPLE_FILES, REPO_ROOT


def test_committed_docs_are_up_to_date(capsys) -> None:
    rc = main(["config-docs", "--check"])
    err = capsys.readouterr().err
    assert rc == 0, f"the generated docs drifted from the models; run `merlin config-docs`:\n{err}"


def test_generation_is_deterministic() -> None:
    assert docs.generated_files() == docs.generated_files()


def test_repo_root_is_found_from_the_module() -> None:
    assert docs.REPO_ROOT == REPO_ROOT
    assert (docs.REPO_ROOT / "pyproject.toml").is_file()


@pytest.fixture
def fake_repo(tmp_path):
    (tmp_path / "pyproject.toml").write_text("", encoding="utf-8")
    return tmp_path


def test_check_fails_on_drift_and_write_repairs_it(fake_repo, capsys) -> None:
    assert main(["config-docs", "--check", "--root", str(fake_repo)]) == 1  # missing files
    assert main(["config-docs", "--root", str(fake_repo)]) == 0
    assert main(["config-docs", "--check", "--root", str(fake_repo)]) == 0
    ref = fake_repo / docs.REFERENCE_PATH
    ref.write_text(
        ref.read_text(encoding="utf-8").replace("| `margin_m` |", "| `margin` |"), encoding="utf-8"
    )
    capsys.readouterr()
    assert main(["config-docs", "--check", "--root", str(fake_repo)]) == 1
    assert "config-reference.md is out of date" in capsys.readouterr().err
    assert main(["config-docs", "--root", str(fake_repo)]) == 0
    assert ref.read_text(encoding="utf-8") == docs.reference_markdown()


def test_not_a_repository_is_invalid_input(tmp_path) -> None:
    assert main(["config-docs", "--check", "--root", str(tmp_path)]) == 2


def test_schema_is_the_models_schema_with_sorted_keys() -> None:
    text = docs.schema_text()
    assert text.endswith("}\n") and not text.endswith("\n\n")
    schema = json.loads(text)
    assert schema["$schema"] == docs.SCHEMA_DIALECT
    del schema["$schema"]
    models = json.loads(json.dumps(MerlinConfig.model_json_schema()))
    docs._restore_compiled_docs(models)  # a compiled core enum's docstring is read from its source
    assert schema == models
    assert text == json.dumps(json.loads(text), indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def _row(md: str, key: str) -> list[str]:
    line = next(x for x in md.splitlines() if x.startswith(f"| `{key}` |"))
    return [c.strip() for c in line.strip("|").split(" | ")]


def test_reference_rows_carry_type_unit_default_constraints_description() -> None:
    md = docs.reference_markdown()
    assert _row(md, "duration_s") == [
        "`duration_s`",
        "number",
        "s",
        "`0`",
        ">= 0, <= 600",
        "exceedance duration tolerated, s",
    ]
    assert _row(md, "bank_limit_deg")[2:5] == ["deg", "`35`", "> 0, < 80"]
    assert _row(md, "max_horizontal_decel_mps2")[2] == "m/s²"
    assert _row(md, "max_thrust_rate_per_s")[2] == "1/s"
    assert _row(md, "low_frac")[2] == "fraction 0..1"
    assert _row(md, "radius_m")[3] == "required"
    for p in ENVELOPE_PARAMETERS:
        assert f"| `{p}` |" in md
    for m in MONITORS:
        assert f"| {m} |" in md  # the default arbiter table
    assert "### `conservative`" in md and "### `expanded`, extends `conservative`" in md


def test_every_model_field_is_documented() -> None:
    md = docs.reference_markdown()
    for sec in docs.sections():
        for name in sec.model.model_fields:
            assert f"| `{name}` |" in md, f"{sec.model.__name__}.{name}"


def test_a_validator_without_a_note_stops_generation(monkeypatch) -> None:
    notes = dict(docs.VALIDATOR_NOTES)
    del notes["Limit._ordered"]
    monkeypatch.setattr(docs, "VALIDATOR_NOTES", notes)
    with pytest.raises(LookupError, match=r"Limit\._ordered"):
        docs.reference_markdown()


def test_a_stale_note_stops_generation(monkeypatch) -> None:
    monkeypatch.setattr(docs, "VALIDATOR_NOTES", {**docs.VALIDATOR_NOTES, "Limit._gone": "old rule"})
    with pytest.raises(LookupError, match=r"Limit\._gone"):
        docs.reference_markdown()


def test_copy_of_committed_docs_checks_clean(fake_repo) -> None:
    for rel in docs.generated_files():
        (fake_repo / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(REPO_ROOT / rel, fake_repo / rel)
    assert docs.stale(fake_repo) == []


def test_examples_validate_against_the_committed_schema() -> None:
    jsonschema = pytest.importorskip("jsonschema")
    schema = json.loads((REPO_ROOT / docs.SCHEMA_PATH).read_text(encoding="utf-8"))
    validator = jsonschema.Draft202012Validator(schema)
    for path in EXAMPLE_FILES:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
        assert not list(validator.iter_errors(data)), path.name
    # what the schema can express, it rejects: an unknown key and a wrong type
    for name in ("broken_unknown_key.yaml", "broken_wrong_type.yaml"):
        data = yaml.safe_load((DATA / name).read_text(encoding="utf-8"))
        assert list(validator.iter_errors(data)), name
