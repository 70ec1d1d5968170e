"""Envelope stages: ``extends`` resolves by overriding the parent; missing parents and cycles are rejected."""

from __future__ import annotations

import pytest

from merlin.config.loader import ConfigError, load_config_text
from merlin.config.models import ENVELOPE_PARAMETERS, EnvelopeConfig, EnvelopeStage, Limit, MerlinConfig
from merlin.config.runtime import envelope_limits
from merlin.config.summary import envelope_table, stage_chain

FULL = {p: Limit(min=-10.0, max=10.0, duration_s=0.1) for p in ENVELOPE_PARAMETERS}


def _env(stages: dict[str, EnvelopeStage], active: str) -> EnvelopeConfig:
    return EnvelopeConfig(active_stage=active, stages=stages)


def test_child_overrides_parent_and_inherits_the_rest() -> None:
    env = _env(
        {
            "base": EnvelopeStage(**FULL),
            "mid": EnvelopeStage(extends="base", roll_deg=Limit(min=-20.0, max=20.0, duration_s=0.5)),
            "top": EnvelopeStage(extends="mid", pitch_deg=Limit(min=-30.0, max=30.0, duration_s=1.0)),
        },
        "top",
    )
    eff = env.effective()
    assert eff["roll_deg"] == Limit(min=-20.0, max=20.0, duration_s=0.5)  # from mid
    assert eff["pitch_deg"] == Limit(min=-30.0, max=30.0, duration_s=1.0)  # from top
    for p in set(ENVELOPE_PARAMETERS) - {"roll_deg", "pitch_deg"}:
        assert eff[p] == FULL[p]  # from base, through two levels
    assert env.resolve("mid")["pitch_deg"] == FULL["pitch_deg"]  # a parent never sees its child
    cfg = MerlinConfig(envelope=env)
    assert stage_chain(cfg, "top") == ("top", "mid", "base")
    set_in = {r["parameter"]: r["set_in"] for r in envelope_table(cfg).records()}
    assert set_in["roll_deg"] == "mid" and set_in["pitch_deg"] == "top" and set_in["yaw_deg"] == "base"


def test_a_child_can_switch_a_parameter_off() -> None:
    env = _env(
        {
            "base": EnvelopeStage(**FULL),
            "calm": EnvelopeStage(extends="base", yaw_deg=Limit(min=-180.0, max=180.0, enabled=False)),
        },
        "calm",
    )
    names = [lim.name for lim in envelope_limits(MerlinConfig(envelope=env))]
    assert "yaw_deg" not in names and len(names) == len(ENVELOPE_PARAMETERS) - 1


@pytest.mark.parametrize(
    "stages",
    [
        "a: {extends: a}",
        "a: {extends: b}\n    b: {extends: a}",
        "a: {extends: b}\n    b: {extends: c}\n    c: {extends: a}",
    ],
)
def test_cycles_are_rejected_with_the_cycle_named(stages: str) -> None:
    text = f"envelope:\n  active_stage: a\n  stages:\n    {stages}\n"
    with pytest.raises(ConfigError, match=r"extend each other in a cycle") as info:
        load_config_text(text, "cycle.yaml")
    assert "cycle.yaml" in str(info.value) and "line 1: envelope" in str(info.value)


def test_a_cycle_is_rejected_even_when_the_active_stage_is_not_in_it() -> None:
    text = "envelope:\n  active_stage: conservative\n  stages:\n    x: {extends: y}\n    y: {extends: x}\n"
    with pytest.raises(ConfigError, match="cycle"):
        load_config_text(text)


def test_a_missing_parent_is_rejected_with_its_name() -> None:
    text = "envelope:\n  active_stage: a\n  stages:\n    a: {extends: nowhere}\n"
    with pytest.raises(ConfigError, match="'nowhere', which is not a stage"):
        load_config_text(text)


def test_an_incomplete_stage_is_rejected() -> None:
    text = "envelope:\n  active_stage: a\n  stages:\n    a: {roll_deg: {min: -1, max: 1}}\n"
    with pytest.raises(ConfigError, match=r"leaves .* unset"):
        load_config_text(text)
