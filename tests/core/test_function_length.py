"""The trusted core reads in short steps: no function or method in ``merlin/core`` is longer than
:data:`MAX_LINES` lines (its signature, docstring and body), so a reviewer can check each stage of the tick
against its description; nor any in the rest of ``merlin/`` longer than :data:`MAX_LINES_LIBRARY`."""

from __future__ import annotations

import ast
from pathlib import Path

MAX_LINES = 80
CORE = Path(__file__).resolve().parents[2] / "merlin" / "core"


def _long_functions(source: str, name: str, max_lines: int = MAX_LINES) -> list[str]:
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
            lines = (node.end_lineno or node.lineno) - first + 1
            if lines > max_lines:
                out.append(f"{name}:{node.lineno} {node.name} is {lines} lines")
    return out


def test_no_core_function_is_longer_than_the_limit() -> None:
    files = sorted(CORE.glob("*.py"))
    assert files, CORE
    long = [msg for f in files for msg in _long_functions(f.read_text(), f.name)]
    assert not long, "split these into one short function per step:\n" + "\n".join(long)


def test_the_check_sees_a_long_function() -> None:
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_LINES))
    assert _long_functions(f"def f():\n{body}\n", "m.py") == [f"m.py:1 f is {MAX_LINES + 1} lines"]
    assert _long_functions("def g():\n    return 1\n", "m.py") == []


#: The limit for every other function of the library (``merlin/``): longer ones are split the filterpy way,
#: one short function per step of the algorithm.
MAX_LINES_LIBRARY = 100
LIBRARY = CORE.parent


def test_no_library_function_is_longer_than_its_limit() -> None:
    files = sorted(LIBRARY.rglob("*.py"))
    assert len(files) > 50, LIBRARY
    long = [msg for f in files for msg in _long_functions(f.read_text(), str(f.relative_to(LIBRARY.parent)),
                                                          MAX_LINES_LIBRARY)]
    assert not long, "split these into one short function per step:\n" + "\n".join(long)
