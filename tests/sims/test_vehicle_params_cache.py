"""A vehicle file parsed once per process and text (sims.multirotor's _parsed, kept per process): loaded again it is the same
parameters; edited, it is parsed again; a broken one is refused every time; the store stays bounded."""

from __future__ import annotations

from pathlib import Path

import pytest

from merlin.config.loader import ConfigError
from sims import multirotor as mr


def test_the_same_file_is_parsed_once_and_an_edited_one_again(tmp_path: Path) -> None:
    mr._parsed.cache_clear()
    text = mr.DEFAULT_PARAMS_PATH.read_text(encoding="utf-8")
    f = tmp_path / "quad.yaml"
    f.write_text(text)
    first = mr.load_multirotor_params(f)
    assert mr.load_multirotor_params(f) is first
    assert first == mr.load_multirotor_params(mr.DEFAULT_PARAMS_PATH)  # same values from another path
    heavier = text.replace(f"mass_kg: {_value(text, 'mass_kg')}", "mass_kg: 2.5")
    assert heavier != text
    f.write_text(heavier)
    edited = mr.load_multirotor_params(f)
    assert edited.mass_kg == 2.5 and first.mass_kg != 2.5


def test_a_broken_file_is_refused_every_time(tmp_path: Path) -> None:
    mr._parsed.cache_clear()
    f = tmp_path / "bad.yaml"
    f.write_text(mr.DEFAULT_PARAMS_PATH.read_text(encoding="utf-8").replace("mass_kg:", "mass_kg: -1.0 #"))
    for _ in range(2):
        with pytest.raises(ConfigError, match="mass_kg"):
            mr.load_multirotor_params(f)
    assert mr._parsed.cache_info().currsize == 0


def test_the_store_keeps_only_the_newest_files(tmp_path: Path) -> None:
    mr._parsed.cache_clear()
    text = mr.DEFAULT_PARAMS_PATH.read_text(encoding="utf-8")
    files, loaded = [], []
    for k in range(mr._PARSED_MAX + 3):
        f = tmp_path / f"quad{k}.yaml"
        f.write_text(text)
        files.append(f)
        loaded.append(mr.load_multirotor_params(f))
    assert mr._parsed.cache_info().currsize == mr._PARSED_MAX
    # the newest files are kept (loaded again, the same object), the oldest are parsed again
    assert all(mr.load_multirotor_params(files[k]) is loaded[k] for k in range(3, mr._PARSED_MAX + 3))
    misses = mr._parsed.cache_info().misses
    assert mr.load_multirotor_params(files[0]) is not loaded[0]
    assert mr._parsed.cache_info().misses == misses + 1


def _value(text: str, key: str) -> str:
    line = next(x for x in text.splitlines() if x.strip().startswith(f"{key}:"))
    return line.split(":", 1)[1].split("#")[0].strip()
