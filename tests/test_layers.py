"""Imports run one way: the layer table of docs/architecture.md, enforced over the whole package.

Every module of ``stableins`` is parsed with :mod:`ast` (nothing is imported), and every import
statement counts: module level, inside functions and under ``if TYPE_CHECKING`` (issue 29).  A module
may import only from its own layer or a lower one; the layers form no cycle; the modules themselves
form no import cycle, counting every import (a lazy import inside a function or one under
``TYPE_CHECKING`` ties two modules as much as one at the top); the commands never import the CLI
that dispatches to them; and no driver reads a run's journal (the replay driver is handed the
recorded operations, :mod:`stableins.procedures.replay`).
"""

from __future__ import annotations

import ast
import re
from functools import cache
from pathlib import Path

import pytest

import stableins

PACKAGE = Path(stableins.__file__).resolve().parent
ARCHITECTURE = PACKAGE.parent / "docs" / "architecture.md"

#: The layers, lowest first (docs/architecture.md, "Layers").  A prefix names a module or a package.
LAYERS: dict[str, int] = {
    # 0 physics, and the plain types every layer shares
    "stableins": 0,
    "stableins._version": 0,
    "stableins.conventions": 0,
    "stableins.dwell_mode": 0,
    "stableins.errormodel": 0,
    "stableins.terms": 0,
    "stableins.coremodel": 0,
    "stableins.units": 0,
    "stableins.status": 0,
    "stableins.errors": 0,
    "stableins.platform": 0,
    "stableins.turns": 0,
    "stableins.noise": 0,
    "stableins.display": 0,
    "stableins.site": 0,
    "stableins.schema": 0,
    "stableins.samples": 0,
    "stableins.identifiers": 0,
    "stableins.documents": 0,
    "stableins.navigation": 0,
    # 1 world
    "stableins.simulator": 1,
    # 2 data
    "stableins.data": 2,
    # 3 estimators
    "stableins.estimators": 3,
    # 4 discovery
    "stableins.discovery": 4,
    # 5 procedures
    "stableins.procedures": 5,
    "stableins.drivers": 5,
    # 6 records and reports
    "stableins.records": 6,
    "stableins.history": 6,
    "stableins.history_store": 6,
    "stableins.runs": 6,
    "stableins.campaign": 6,
    "stableins.reporting": 6,
    # 7 interface
    "stableins.commands": 7,
    "stableins.cli": 7,
    "stableins.web": 7,
    "stableins.output": 7,
    "stableins.progress": 7,
    "stableins.console": 7,
    "stableins.__main__": 7,
}
LAYER_NAMES = ("physics", "world", "data", "estimators", "discovery", "procedures", "records and reports", "interface")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


@cache
def modules() -> dict[str, Path]:
    """Every module of the package by dotted name."""
    return {_module_name(path): path for path in sorted(PACKAGE.rglob("*.py"))}


def layer_of(module: str) -> int:
    """The layer of a module: its longest prefix in :data:`LAYERS` (a module not in the table fails)."""
    parts = module.split(".")
    for cut in range(len(parts), 0, -1):
        prefix = ".".join(parts[:cut])
        if prefix in LAYERS and (cut > 1 or module == "stableins"):
            return LAYERS[prefix]
    raise KeyError(module)


def _resolve(module: str, node: ast.ImportFrom) -> str:
    """The absolute name an ``from ... import`` statement reads from."""
    if not node.level:
        return node.module or ""
    package = module.split(".") if _is_package(module) else module.split(".")[:-1]
    base = package[: len(package) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


def _is_package(module: str) -> bool:
    return modules()[module].name == "__init__.py"


def _target(name: str) -> str | None:
    """The package module an imported name refers to (``stableins.errors.InputError`` -> the module)."""
    known = modules()
    while name:
        if name in known:
            return name
        name = name.rpartition(".")[0]
    return None


@cache
def imports(module: str) -> tuple[tuple[str, int, bool], ...]:
    """``(imported module, line, at module level)`` for every stableins import of ``module``.

    "At module level" means executed when the module is imported: not inside a function and not
    under ``if TYPE_CHECKING``.
    """
    tree = ast.parse(modules()[module].read_text(encoding="utf-8"), filename=str(modules()[module]))
    found: list[tuple[str, int, bool]] = []

    def visit(node: ast.AST, *, eager: bool) -> None:
        for child in ast.iter_child_nodes(node):
            child_eager = eager
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
                child_eager = False
            elif isinstance(child, ast.If) and _is_type_checking(child.test):
                for statement in child.body:
                    visit_statement(statement, eager=False)
                for statement in child.orelse:
                    visit_statement(statement, eager=eager)
                continue
            visit_statement(child, eager=child_eager, recurse=False)
            visit(child, eager=child_eager)

    def visit_statement(node: ast.AST, *, eager: bool, recurse: bool = True) -> None:
        if isinstance(node, ast.Import | ast.ImportFrom):
            found.extend((target, node.lineno, eager) for target in _import_targets(module, node))
        if recurse:
            visit(node, eager=eager and not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef))

    visit(tree, eager=True)
    return tuple(found)


def _import_targets(module: str, node: ast.Import | ast.ImportFrom) -> list[str]:
    """The stableins modules one import statement of ``module`` imports."""
    if isinstance(node, ast.Import):
        return [target for alias in node.names if (target := _target(alias.name))]
    base = _resolve(module, node)
    if not (base == "stableins" or base.startswith("stableins.")):
        return []
    return [target for alias in node.names if (target := _target(f"{base}.{alias.name}") or _target(base))]


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def test_every_module_has_a_layer() -> None:
    missing = []
    for module in modules():
        try:
            layer_of(module)
        except KeyError:
            missing.append(module)
    assert not missing, f"modules missing from the layer table (tests/test_layers.py, docs/architecture.md): {missing}"


def test_no_upward_import() -> None:
    upward = [
        f"{module}:{line} ({LAYER_NAMES[layer_of(module)]}) imports {target} ({LAYER_NAMES[layer_of(target)]})"
        for module in modules()
        for target, line, _ in imports(module)
        if layer_of(target) > layer_of(module)
    ]
    assert not upward, "upward imports:\n" + "\n".join(upward)


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (or with a self-loop), Tarjan's algorithm."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def connect(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for successor in sorted(graph.get(node, ())):
            if successor not in index:
                connect(successor)
                low[node] = min(low[node], low[successor])
            elif successor in on_stack:
                low[node] = min(low[node], index[successor])
        if low[node] == index[node]:
            component = _pop_component(stack, on_stack, node)
            if len(component) > 1 or node in graph.get(node, ()):
                components.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            connect(node)
    return components


def _pop_component(stack: list[str], on_stack: set[str], root: str) -> list[str]:
    """Pop the strongly connected component whose root is ``root`` off Tarjan's stack."""
    component = []
    while True:
        member = stack.pop()
        on_stack.discard(member)
        component.append(member)
        if member == root:
            return component


def test_no_cycle_between_layers() -> None:
    graph: dict[str, set[str]] = {}
    for module in modules():
        for target, _, _ in imports(module):
            if layer_of(target) != layer_of(module):
                graph.setdefault(LAYER_NAMES[layer_of(module)], set()).add(LAYER_NAMES[layer_of(target)])
    assert not _cycles(graph)


def module_graph() -> dict[str, set[str]]:
    """The import graph of the package's modules, every import statement counted (a module importing itself aside)."""
    graph: dict[str, set[str]] = {}
    for module in modules():
        for target, _, _ in imports(module):
            if target != module:
                graph.setdefault(module, set()).add(target)
    return graph


def test_no_import_cycle_between_modules() -> None:
    """No strongly connected component of more than one module, counting imports in functions and under TYPE_CHECKING."""
    cycles = _cycles(module_graph())
    assert not cycles, "import cycles (every import counted):\n" + "\n".join(" <-> ".join(cycle) for cycle in cycles)


def test_commands_never_import_the_cli() -> None:
    """The CLI dispatches to the commands; a command runs another as a user would (a process of its own)."""
    bad = [
        f"{module}:{line} imports {target}"
        for module in modules()
        if module.startswith("stableins.commands")
        for target, line, _ in imports(module)
        if target == "stableins.cli"
    ]
    assert not bad


def test_drivers_never_read_journals() -> None:
    """A driver talks to a platform (or plays recorded answers back); reading a run's journal is the procedures' job."""
    bad = [
        f"{module}:{line} imports {target}"
        for module in modules()
        if module.startswith("stableins.drivers")
        for target, line, _ in imports(module)
        if target.startswith("stableins.procedures")
    ]
    assert not bad


def test_the_simulator_imports_no_data_drivers_estimators_or_discovery() -> None:
    """The world is independent: it computes from the physics layer only (docs/architecture.md)."""
    bad = [
        f"{module}:{line} imports {target}"
        for module in modules()
        if module.startswith("stableins.simulator")
        for target, line, _ in imports(module)
        if layer_of(target) != layer_of(module) and layer_of(target) != 0
    ]
    assert not bad


#: The estimators' model: the simulator must not import it, even inside a function (issue 31), so that a sign or
#: axis error in it cannot hide in every simulate-then-fit test.  ``stableins.terms`` and ``stableins.coremodel`` are
#: its parts (:mod:`stableins.errormodel` re-exports them).
ESTIMATORS_MODEL = ("stableins.errormodel", "stableins.terms", "stableins.coremodel", "stableins.estimators", "stableins.discovery")
#: Names of :mod:`stableins.conventions` that are the estimators' installation matrix and its sign table.
ESTIMATORS_INSTALLATION = {"dcm_platform_to_accelerometer", "INSTALLATION_ENTRIES"}


def _simulator_uses_of_the_estimators_model(found: dict[str, Path]) -> list[str]:
    bad = []
    for module, path in found.items():
        if not module.startswith("stableins.simulator"):
            continue
        for target, line, _ in imports(module):
            if any(target == m or target.startswith(m + ".") for m in ESTIMATORS_MODEL):
                bad.append(f"{module}:{line} imports {target}")
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            name = node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else None
            if isinstance(node, ast.alias):
                name = node.name
            if name in ESTIMATORS_INSTALLATION:
                bad.append(f"{module}:{getattr(node, 'lineno', '?')} uses conventions.{name}")
    return bad


def test_the_simulator_never_imports_the_estimators_model() -> None:
    """No module of ``stableins.simulator`` imports errormodel, terms, coremodel, estimators or discovery (functions too)."""
    assert not _simulator_uses_of_the_estimators_model(modules())


def test_the_simulator_model_check_can_fail(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """An import of the error model inside a function, or the estimators' installation matrix, is found."""
    fake = _synthetic_package(
        tmp_path,
        {
            "stableins.simulator.device": "def f():\n    from stableins.errormodel import ErrorModel\n",
            "stableins.simulator.system": "from stableins import conventions\nC = conventions.dcm_platform_to_accelerometer\n",
            "stableins.simulator.truth": "from stableins.conventions import INSTALLATION_ENTRIES\n",
            "stableins.errormodel": "",
            "stableins.conventions": "",
        },
    )
    monkeypatch.setattr(f"{__name__}.modules", lambda: fake)
    imports.cache_clear()
    try:
        bad = _simulator_uses_of_the_estimators_model(fake)
    finally:
        imports.cache_clear()
    assert bad == [
        "stableins.simulator.device:2 imports stableins.errormodel",
        "stableins.simulator.system:2 uses conventions.dcm_platform_to_accelerometer",
        "stableins.simulator.truth:1 uses conventions.INSTALLATION_ENTRIES",
    ]


def test_docs_hold_the_layer_table() -> None:
    """docs/architecture.md lists every entry of :data:`LAYERS` in the row of its layer."""
    rows = {}
    for line in ARCHITECTURE.read_text(encoding="utf-8").splitlines():
        match = re.match(r"\|\s*(\d)\s+([a-z ]+?)\s*\|(.*?)\|", line)
        if match:
            rows[int(match.group(1))] = (match.group(2), match.group(3))
    assert sorted(rows) == list(range(len(LAYER_NAMES)))
    for number, name in enumerate(LAYER_NAMES):
        assert rows[number][0] == name
    for prefix, number in LAYERS.items():
        if prefix in ("stableins", "stableins._version"):
            continue
        short = prefix.removeprefix("stableins.")
        assert re.search(rf"`{re.escape(short)}/?`", rows[number][1]), f"{short} not in layer row {number} of docs/architecture.md"


def _synthetic_package(tmp_path: Path, sources: dict[str, str]) -> dict[str, Path]:
    out = {}
    for name, source in sources.items():
        path = tmp_path.joinpath(*name.split(".")).with_suffix(".py")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(source)
        out[name] = path
    return out


def test_the_parser_sees_lazy_and_type_checking_imports(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """The checks above can fail: an import in a function or under TYPE_CHECKING is found."""
    fake = _synthetic_package(
        tmp_path,
        {
            "stableins.conventions": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from stableins.records import X\n",
            "stableins.records": "def f():\n    from stableins import commands\n",
            "stableins.commands": "import stableins.records\nfrom . import records\n",
        },
    )
    monkeypatch.setattr(f"{__name__}.modules", lambda: fake)
    imports.cache_clear()
    try:
        found = {module: imports(module) for module in fake}
        graph = module_graph()
    finally:
        imports.cache_clear()
    assert found["stableins.conventions"] == (("stableins.records", 3, False),)
    assert found["stableins.records"] == (("stableins.commands", 2, False),)
    assert found["stableins.commands"] == (("stableins.records", 1, True), ("stableins.records", 2, True))
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert graph["stableins.conventions"] == {"stableins.records"}  # the TYPE_CHECKING import is an edge
    assert graph["stableins.records"] == {"stableins.commands"}  # and so is the import inside a function
    assert _cycles(graph) == [["stableins.commands", "stableins.records"]]  # a cycle through a lazy import
