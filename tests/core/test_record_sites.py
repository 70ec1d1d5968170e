"""Every place that builds a per-tick record with ``new_record(Cls, (...))`` (``tuple.__new__``: no defaults,
no count check) hands it exactly its class's fields, in order.

Read from the sources, so the check holds in the compiled build too. Per call site:
- the tuple has as many items as the class has fields (a field added to a class and forgotten at one site
  would build a short record, which only fails when that field is read);
- an item that is a plain name, or an attribute, spelled like one of the class's fields sits at that field's
  position (two such items swapped would build a wrong record without any error).
Items that are expressions are not judged; the behaviour and digest tests cover what they compute.
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("merlin", "sims")


def _sites() -> list[tuple[str, int, str, ast.Tuple]]:
    found = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            if "generated" in path.parts:
                continue
            tree = ast.parse(path.read_text(encoding="utf-8"))
            module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            for node in ast.walk(tree):
                if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "new_record"
                        and len(node.args) == 2 and isinstance(node.args[0], ast.Name)
                        and isinstance(node.args[1], ast.Tuple)):
                    found.append((module, node.lineno, node.args[0].id, node.args[1]))
    return found


SITES = _sites()


def _spelled(item: ast.expr) -> str | None:
    if isinstance(item, ast.Name):
        return item.id
    if isinstance(item, ast.Attribute):
        return item.attr
    return None


def test_the_sites_are_found() -> None:
    """The scan itself: the records built per tick through new_record are there to check."""
    classes = {cls for _, _, cls, _ in SITES}
    assert len(SITES) >= 25, SITES
    assert {"CoreState", "Decision", "MonitorReport", "SensorFrame", "MultirotorTruth", "Setpoint"} <= classes


@pytest.mark.parametrize("module, line, cls_name, items", SITES,
                         ids=[f"{m}:{line}:{c}" for m, line, c, _ in SITES])
def test_each_site_gives_every_field_in_order(module: str, line: int, cls_name: str, items: ast.Tuple) -> None:
    cls = getattr(importlib.import_module(module), cls_name)
    fields = tuple(cls._fields)
    assert not any(isinstance(e, ast.Starred) for e in items.elts), f"{module}:{line}: starred items are not checkable"
    assert len(items.elts) == len(fields), (
        f"{module}:{line}: {cls_name} has {len(fields)} fields {fields}, the site gives {len(items.elts)}")
    for position, item in enumerate(items.elts):
        name = _spelled(item)
        if name in fields:
            assert fields.index(name) == position, (
                f"{module}:{line}: {name!r} is given as {cls_name}'s field {position} ({fields[position]!r}), "
                f"but it is field {fields.index(name)}")
