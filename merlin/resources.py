"""Where the shipped examples (scenarios, configurations, campaigns) and the configuration schema are,
in a source tree and in an installed wheel alike.

In the repository they are ``examples/`` and ``docs/config.schema.json`` at its root. A wheel carries copies
in the package, under ``merlin/_data/`` with the same layout (``setup.py``'s ``build_py`` puts them there), so
an example configuration's ``$schema`` line (``../../docs/config.schema.json``) and a scenario's relative
``config:`` path resolve in both.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent
_REPOSITORY = _PACKAGE.parent


def data_root() -> Path:
    """The directory holding ``examples/`` and ``docs/config.schema.json``: the repository's root when run
    from a source tree (a checkout or an editable install), else the installed package's ``_data``."""
    if (_REPOSITORY / "examples" / "scenarios").is_dir() and (_REPOSITORY / "pyproject.toml").is_file():
        return _REPOSITORY
    return _PACKAGE / "_data"


def examples_dir() -> Path:
    return data_root() / "examples"


def scenarios_dir() -> Path:
    return examples_dir() / "scenarios"


def configs_dir() -> Path:
    return examples_dir() / "configs"


def schema_path() -> Path:
    return data_root() / "docs" / "config.schema.json"


def shipped(argument: str | Path, kind: str) -> Path:
    """``argument`` as a path when it is a file; else the shipped example of that name (``nominal`` ->
    ``examples/scenarios/nominal.yaml`` for ``kind="scenarios"``, ``default`` -> ``examples/configs/
    default.yaml`` for ``kind="configs"``), so a command works from an install without a checkout; else
    ``argument`` unchanged (the command then says the file was not found)."""
    p = Path(argument)
    if p.exists() or p.suffix in (".yaml", ".yml") or len(p.parts) > 1:
        return p
    candidate = examples_dir() / kind / f"{p.name}.yaml"
    return candidate if candidate.is_file() else p
