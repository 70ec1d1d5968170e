"""A wheel built from the repository works on its own: installed into a fresh virtual environment outside
the repository, `merlin --version`, `merlin demo`, `merlin check-config` on a shipped default and `merlin sim`
on a shipped scenario all work, the example configurations' `$schema` lines resolve, and every declared
dependency is satisfied.

The wheel is built as pip builds it for a user (an isolated build, pure Python: no mypyc compile) from a copy
of the repository's files. Its dependencies are not downloaded again: the fresh environment sees this
environment's site-packages through a path file, after its own, so the wheel's `merlin` is the one imported
(checked) and `pip check` judges the wheel's declared requirements against what is there.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.integration]

ROOT = Path(__file__).resolve().parents[2]
IGNORED = shutil.ignore_patterns(".git", ".venv", "build", "dist", "out", "*.egg-info", "__pycache__", "*.so",
                                 ".pytest_cache", ".mypy_cache", ".ruff_cache", ".hypothesis")


def _sh(cmd: list[str], cwd: Path, env: dict[str, str], timeout: float = 600) -> subprocess.CompletedProcess[str]:
    res = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout, check=False)
    assert res.returncode == 0, f"{' '.join(cmd)} exited {res.returncode}\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}"
    return res


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str], Path]:
    base = tmp_path_factory.mktemp("wheel")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MERLIN_", "PYTHON"))}
    env["MERLIN_PURE_PYTHON"] = "1"
    src = base / "src"
    shutil.copytree(ROOT, src, ignore=IGNORED)
    dist = base / "dist"
    _sh([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(dist), str(src)], base, env, 900)
    wheels = list(dist.glob("merlin_autopilot-*.whl"))
    assert len(wheels) == 1, wheels
    venv = base / "venv"
    _sh([sys.executable, "-m", "venv", "--without-pip", str(venv)], base, env)
    py = venv / "bin" / "python"
    _sh([sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps", "--quiet", str(wheels[0])], base, env)
    site = Path(_sh([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], base, env)
                .stdout.strip())
    ours = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "zz_project_dependencies.pth").write_text("".join(p + "\n" for p in sorted(ours)))
    env.pop("MERLIN_PURE_PYTHON")
    run_dir = base / "user"
    run_dir.mkdir()
    return venv, env, run_dir


def test_the_wheel_carries_license_and_package_data(installed: tuple[Path, dict[str, str], Path]) -> None:
    venv, env, cwd = installed
    py = str(venv / "bin" / "python")
    out = _sh([py, "-c", "import merlin, merlin.resources as r; print(merlin.__file__); print(merlin.__version__); "
                         "print(r.data_root())"], cwd, env).stdout.split()
    assert out[0].startswith(str(venv)), f"merlin imported from {out[0]}, not the fresh environment"
    assert out[1] == "0.1.0"
    data = Path(out[2])
    assert data.is_relative_to(venv) and (data / "examples" / "scenarios" / "nominal.yaml").is_file()
    # every example configuration's $schema line resolves to the shipped schema
    with_schema = []
    for cfg in (data / "examples" / "configs").glob("*.yaml"):
        first = cfg.read_text().splitlines()[0]
        if first.startswith("# yaml-language-server: $schema="):
            with_schema.append(cfg.name)
            assert (cfg.parent / first.split("$schema=", 1)[1]).resolve().is_file(), cfg
    assert "default.yaml" in with_schema and "fixedwing_default.yaml" in with_schema
    dist_info = next((venv / "lib").rglob("merlin_autopilot-*.dist-info"))
    meta = (dist_info / "METADATA").read_text()
    assert "License-Expression: Apache-2.0" in meta
    assert "Requires-Dist: mavsdk>=4" in meta and "Requires-Dist: pyserial>=3.5" in meta
    assert any(p.name == "LICENSE" for p in dist_info.rglob("LICENSE"))
    # each runtime requirement the wheel declares is met where it is installed (pip check would also judge
    # the unrelated packages of this environment)
    _sh([py, "-c", CHECK_REQUIREMENTS], cwd, env)


CHECK_REQUIREMENTS = """
from importlib import metadata
from packaging.requirements import Requirement
bad = []
for text in metadata.requires("merlin-autopilot"):
    req = Requirement(text)
    if req.marker is not None and not req.marker.evaluate({"extra": ""}):
        continue
    try:
        have = metadata.version(req.name)
    except metadata.PackageNotFoundError:
        bad.append(f"{req}: not installed")
        continue
    if not req.specifier.contains(have, prereleases=True):
        bad.append(f"{req}: {have} installed")
assert not bad, bad
"""


def test_the_commands_work_from_the_install(installed: tuple[Path, dict[str, str], Path]) -> None:
    venv, env, cwd = installed
    merlin = str(venv / "bin" / "merlin")
    assert _sh([merlin, "--version"], cwd, env).stdout.strip() == "merlin 0.1.0"
    shown = _sh([merlin, "check-config", "default"], cwd, env).stdout
    assert "sha256:" in shown and str(venv) in shown
    _sh([merlin, "sim", "nominal", "--out", "nominal", "--no-plots", "--quiet"], cwd, env)
    assert (cwd / "nominal" / "summary.json").is_file() and (cwd / "nominal" / "flight.ulg").is_file()
    _sh([merlin, "demo", "--only", "nominal", "--out", "demo", "--workers", "1"], cwd, env)
    assert (cwd / "demo" / "report.html").is_file() and (cwd / "demo" / "nominal" / "ground_track.png").is_file()


def test_wheel_layout(installed: tuple[Path, dict[str, str], Path]) -> None:
    """(The wheel file itself: the data under merlin/_data, no compiled module of a pure build.)"""
    venv, _, _ = installed
    wheel = next(venv.parent.joinpath("dist").glob("*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    assert "merlin/_data/docs/config.schema.json" in names
    assert "merlin/_data/examples/configs/default.yaml" in names
    assert "merlin/link/merlin.xml" in names
