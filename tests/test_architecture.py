"""The dependency rule of docs/architecture.md, read from the sources' imports (ast, every import statement,
including the ones inside functions): a module imports only from its own layer or the layers below it, the
trusted core only from itself and plain data, and no import cycle closes among the project's modules.

Imports under ``if TYPE_CHECKING:`` count for the layers (a type is a dependency too) but not for cycles:
they never run, so they cannot make two modules' imports depend on each other's order (the usual way to
name a type for an annotation across a runtime dependency)."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("merlin", "sims", "experimental_controllers")

#: The layers, lowest first (docs/architecture.md, "Dependency rule"). A module belongs to the layer of the
#: longest prefix listed here.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("the decision and plain data",
     ("merlin", "merlin._build", "merlin.core", "merlin.measurements", "merlin.geodesy", "merlin.resources")),
    ("flight logic and its edges",
     ("merlin.autopilot", "merlin.nav", "merlin.redundancy", "merlin.vision", "merlin.config", "merlin.link",
      "merlin.ulog", "experimental_controllers")),
    ("the tick pipeline", ("merlin.pipeline",)),
    ("drivers", ("sims", "merlin.serve", "merlin.replay", "merlin.guard")),
    ("commands", ("merlin.commands", "merlin.cli", "merlin.campaign", "merlin.falsify")),
)
#: What the trusted core may import from the project besides itself: plain data and the package root.
CORE_MAY_IMPORT = ("merlin", "merlin._build", "merlin.measurements", "merlin.geodesy")


@cache
def modules() -> dict[str, Path]:
    """Every module of the project by dotted name (a package by its own name)."""
    out: dict[str, Path] = {}
    for pkg in PACKAGES:
        for f in sorted((ROOT / pkg).rglob("*.py")):
            parts = f.relative_to(ROOT).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = f
    return out


def _resolve(name: str) -> str | None:
    """The project module ``name`` refers to (the longest existing prefix), None outside the project."""
    mods = modules()
    while name and name not in mods:
        name = name.rpartition(".")[0]
    return name or None


def _type_checking_only(tree: ast.Module) -> set[int]:
    """The ids of the import statements under ``if TYPE_CHECKING:``."""
    out: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and (
                (isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING")
                or (isinstance(node.test, ast.Attribute) and node.test.attr == "TYPE_CHECKING")):
            out.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    return out


def _imported(module: str, path: Path) -> Iterator[tuple[str, int, bool]]:
    """(project module, line, whether the import runs) for every import statement of ``path``."""
    is_pkg = path.name == "__init__.py"
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    typing_only = _type_checking_only(tree)
    for node in ast.walk(tree):
        runs = id(node) not in typing_only
        if isinstance(node, ast.Import):
            for alias in node.names:
                r = _resolve(alias.name)
                if r is not None:
                    yield r, node.lineno, runs
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from the module's package (a package's own __init__ is its package)
                base = module.split(".")
                base = base[: len(base) - node.level + (1 if is_pkg else 0)]
                full = ".".join([*base, node.module] if node.module else base)
            else:
                full = node.module or ""
            for alias in node.names:
                r = _resolve(f"{full}.{alias.name}") or _resolve(full)
                if r is not None:
                    yield r, node.lineno, runs


@cache
def graph(runtime_only: bool = False) -> dict[str, dict[str, int]]:
    """module -> {imported project module: first line importing it} (self-imports left out; with
    ``runtime_only``, the imports under ``if TYPE_CHECKING:`` too)."""
    out: dict[str, dict[str, int]] = {}
    for module, path in modules().items():
        deps: dict[str, int] = {}
        for dep, line, runs in _imported(module, path):
            if dep != module and (runs or not runtime_only):
                deps.setdefault(dep, line)
        out[module] = deps
    return out


def layer_of(module: str) -> int | None:
    best, best_len = None, -1
    for i, (_, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and len(p) > best_len:
                best, best_len = i, len(p)
    return best


def _in(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def _core_to_autopilot(a: str, b: str) -> bool:
    return _in(a, "merlin.core") and _in(b, "merlin.autopilot")


def test_every_module_has_a_layer() -> None:
    """A new package must be placed in the rule (and in docs/architecture.md) before it can be imported."""
    assert len(modules()) > 100  # the scan found the project
    assert [m for m in modules() if layer_of(m) is None] == []


def test_no_module_imports_from_a_higher_layer() -> None:
    """``merlin.core`` <- flight logic (``merlin.autopilot``, ``merlin.nav``, ``merlin.redundancy``, ...) <- the
    tick pipeline <- drivers (``sims``, ``merlin.serve``, ``merlin.replay``) <- commands. The core's own
    import of the autopilot is the next test's."""
    bad = []
    for a, deps in graph().items():
        la = layer_of(a)
        for b, line in deps.items():
            lb = layer_of(b)
            if la is not None and lb is not None and lb > la and not _core_to_autopilot(a, b):
                bad.append(f"{modules()[a].relative_to(ROOT)}:{line}: {a} ({LAYERS[la][0]}) imports {b}"
                           f" ({LAYERS[lb][0]})")
    assert bad == []


def test_the_core_imports_only_itself_and_plain_data() -> None:
    bad = [f"{a} imports {b}" for a, deps in graph().items() if _in(a, "merlin.core")
           for b in deps if not _in(b, "merlin.core") and b not in CORE_MAY_IMPORT]
    assert bad == []


def _cycles(g: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan 1972), iteratively."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in g:
        if root in index:
            continue
        work = [(root, iter(g[root]))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in g:
                    continue
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(g[w])))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def test_only_the_type_checking_block_is_typing_only() -> None:
    tree = ast.parse("import a\nif TYPE_CHECKING:\n    import b\nelse:\n    import c\n"
                     "if typing.TYPE_CHECKING:\n    from d import e\n")
    only = _type_checking_only(tree)
    imports = [n for n in ast.walk(tree) if isinstance(n, ast.Import | ast.ImportFrom)]
    assert [(n.lineno, id(n) in only) for n in imports] == [(1, False), (3, True), (5, False), (7, True)]


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert _cycles({"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}, "d": {"a": 1}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b": 1}, "b": {}}) == []


def test_no_import_cycle_among_the_project_modules() -> None:
    """Not even through an import inside a function: a cycle means two modules that cannot be understood
    (or tested, or moved) one without the other."""
    assert _cycles(graph(runtime_only=True)) == []


def test_the_simulator_holds_no_flight_logic_module() -> None:
    """The stages a real vehicle needs are in ``merlin``: the simulator's loops hand them the sensor frame and
    fly what they return (``merlin.pipeline``); none of them imports ``sims``."""
    for stage in ("merlin.pipeline", "merlin.redundancy.lanes", "merlin.nav.fusion_stage",
                  "merlin.autopilot.multirotor_stage", "merlin.autopilot.fixedwing_behaviours"):
        assert stage in modules()
        assert [d for d in graph()[stage] if _in(d, "sims")] == []
    assert "sims.lanes" not in modules()


#: The modules outside ``merlin.link`` allowed to import pymavlink: the example of an out-of-process
#: controller written with pymavlink (it stands for a third party's program, which speaks MAVLink its own way).
PYMAVLINK_OUTSIDE_THE_LINK = ("experimental_controllers.pymavlink_dialect",)


def _third_party_imports(source: str, name: str = "<source>") -> Iterator[tuple[str, int]]:
    """(top-level package, line) of every absolute import statement of ``source``, inside functions too."""
    for node in ast.walk(ast.parse(source, name)):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name.partition(".")[0], node.lineno
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            yield node.module.partition(".")[0], node.lineno


def _imports_pymavlink(module: str) -> list[int]:
    path = modules()[module]
    return [line for top, line in _third_party_imports(path.read_text(encoding="utf-8"), str(path))
            if top == "pymavlink"]


def test_only_the_link_imports_pymavlink() -> None:
    """pymavlink is generated, global and stringly typed: it is wrapped once, at the edge (``merlin.link``),
    behind typed messages, and nothing else imports it (STYLE.md; docs/architecture.md, "Dependency rule")."""
    assert [m for m in modules() if _in(m, "merlin.link") and _imports_pymavlink(m)]  # the scan sees them
    bad = [f"{modules()[m].relative_to(ROOT)}:{line}: {m} imports pymavlink" for m in modules()
           if not _in(m, "merlin.link") and m not in PYMAVLINK_OUTSIDE_THE_LINK for line in _imports_pymavlink(m)]
    assert bad == []


def test_the_pymavlink_scan_sees_an_import_inside_a_function() -> None:
    source = "def f():\n    from pymavlink.dialects.v20 import ardupilotmega\n\nimport pymavlink.mavutil\nfrom . import x\n"
    assert sorted(_third_party_imports(source)) == [("pymavlink", 2), ("pymavlink", 4)]
