"""A broken configuration is rejected with a message naming the file, the line, the key path and the value."""

from __future__ import annotations

import pytest
import yaml

from merlin.cli import main
from merlin.commands.check_config import allowed_keys, load_and_build, yaml_context
from merlin.config.loader import ConfigError, load_config_text
from merlin.config.models import EnvelopeStage, FenceCircle, Limit, MerlinConfig, Rule
from tests.config.paths import BROKEN_FILES, DATA, EXAMPLES

# file -> (line, key path, offending value as it appears in the message)
EXPECTED: dict[str, tuple[int, str, str]] = {
    "broken_unknown_key.yaml": (13, "envelope.stages.conservative.pich_deg", "'min': -30.0"),
    "broken_wrong_type.yaml": (5, "geofence.margin_m", "'five metres'"),
    "broken_min_gt_max.yaml": (11, "envelope.stages.conservative.roll_deg", "{'min': 30.0, 'max': -30.0}"),
    # The models check `extends` on the whole `envelope` section, so the line is that of `envelope:`;
    # the missing parent is named in the message.
    "broken_missing_parent.yaml": (3, "envelope", "'conservatve'"),
    "broken_stage_cycle.yaml": (3, "envelope", "a -> b -> a"),
    "broken_self_intersecting.yaml": (8, "geofence.inclusion_polygons[0]", "north 100.00 m, east 0.00 m"),
    "broken_yaml_syntax.yaml": (5, "geofence.inclusion_polygons.name", "'- name: field: north'"),
    "broken_boolean_number.yaml": (7, "geofence.inclusion_polygons[0].vertices_ne_m[0][0]", "value true is true/false"),
}


def test_every_broken_file_has_an_expectation() -> None:
    assert {p.name for p in BROKEN_FILES} == set(EXPECTED)


def _error(name: str) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        load_and_build(DATA / name)
    return info.value


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_broken_file_message_names_file_line_key_and_value(name: str) -> None:
    line, path, value = EXPECTED[name]
    err = _error(name)
    msg = str(err)
    assert name in msg
    assert err.source.endswith(name)
    assert len(err.problems) == 1, msg
    problem = err.problems[0]
    assert problem.startswith(f"line {line}:") or problem.startswith(f"line {line}, column"), problem
    assert path in problem, problem
    assert value in problem, problem


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_check_config_exits_2_and_prints_the_problem_to_stderr(name: str, capsys) -> None:
    assert main(["check-config", str(DATA / name)]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    line, path, value = EXPECTED[name]
    assert name in err and f"line {line}" in err and path in err and value in err
    assert "Traceback" not in err


@pytest.mark.parametrize("json_flag", [[], ["--json"]])
def test_missing_file_is_invalid_input(tmp_path, capsys, json_flag) -> None:
    missing = tmp_path / "nope.yaml"
    assert main(["check-config", str(missing), *json_flag]) == 2
    err = capsys.readouterr().err
    assert "nope.yaml" in err and "cannot read" in err


def test_unknown_stage_option_is_invalid_input(capsys) -> None:
    from tests.config.paths import EXAMPLES

    assert main(["check-config", str(EXAMPLES / "figure5_instant.yaml"), "--stage", "no_such_stage"]) == 2
    err = capsys.readouterr().err
    assert "'no_such_stage'" in err and "figure5" in err


def test_an_unknown_key_is_answered_with_the_keys_allowed_there() -> None:
    problem = _error("broken_unknown_key.yaml").problems[0]
    assert problem.endswith("allowed keys here: " + ", ".join(EnvelopeStage.model_fields))
    assert "pitch_deg" in problem


def test_allowed_keys_follow_mappings_lists_and_optionals() -> None:
    assert allowed_keys(()) == list(MerlinConfig.model_fields)
    assert allowed_keys(("envelope", "stages", "any_stage")) == list(EnvelopeStage.model_fields)
    assert allowed_keys(("envelope", "stages", "s", "roll_deg")) == list(Limit.model_fields)
    assert allowed_keys(("geofence", "exclusion_circles", 3)) == list(FenceCircle.model_fields)
    assert allowed_keys(("arbiter", "rules", "geofence")) == list(Rule.model_fields)
    assert allowed_keys(("geofence", "margin_m")) is None
    assert allowed_keys(("no_such_section",)) is None


def test_yaml_context_follows_block_indentation() -> None:
    text = "a:\n  b:\n    - c: 1\n      d: [\n  e: 2\n"
    assert yaml_context(text, 3) == ("a.b.d", "d: [")
    assert yaml_context(text, 4) == ("a.e", "e: 2")
    assert yaml_context("", 0) == ("", "")



def _default_with(path: tuple[str, ...], value: object) -> str:
    data = yaml.safe_load((EXAMPLES / "default.yaml").read_text())
    node = data
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    return yaml.safe_dump(data)


@pytest.mark.parametrize(("path", "value", "problem"), [
    (("vehicle", "reaction_time_s"), True, "vehicle.reaction_time_s: value true is true/false where a number is"),
    (("handover", "max_revocations_per_flight"), False, "handover.max_revocations_per_flight: value false"),
    (("envelope", "stages", "conservative", "roll_deg", "max"), True,
     "envelope.stages.conservative.roll_deg.max: value true"),
])
def test_true_or_false_where_a_number_belongs_is_refused(path: tuple[str, ...], value: bool, problem: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_config_text(_default_with(path, value), "bools.yaml")
    assert any(problem in p for p in info.value.problems), info.value.problems


def test_true_and_false_still_set_the_switches() -> None:
    cfg = load_config_text(_default_with(("envelope", "stages", "conservative", "roll_deg", "enabled"), False))
    assert cfg.envelope.stages["conservative"].roll_deg.enabled is False  # type: ignore[union-attr]
