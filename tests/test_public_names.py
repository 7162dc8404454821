"""One vocabulary (issue 29): a public class or function is defined once in the package, and ``dict[str, Any]`` is rare.

Every module of ``stableins`` is parsed with :mod:`ast`.  A public name is a module-level class or function whose name
does not start with ``_``; the command protocol (``configure`` and ``run`` of every ``stableins.commands`` module, the
interface :mod:`stableins.cli` dispatches to) and the generated ``stableins._version`` are not counted.  The names still
defined in more than one module are listed in :data:`KNOWN_DUPLICATES`, to be renamed or merged: the list may only
shrink (a new duplicate fails, and so does a listed name that is no longer one); public module-level constants
(``UPPER_CASE`` names assigned) likewise, against :data:`KNOWN_DUPLICATE_CONSTANTS`.  The ``dict[str, Any]`` annotations
are counted the same way against :data:`DICT_ANY_CEILING`, which may only come down (issue 29's target: 50).
"""

from __future__ import annotations

import ast
import re
from collections import defaultdict
from pathlib import Path

import stableins

PACKAGE = Path(stableins.__file__).resolve().parent

#: Public names defined in more than one module (issue 29: 24 once, 22, now none); never add to this list.
KNOWN_DUPLICATES: dict[str, set[str]] = {}

#: Public module-level constants (``UPPER_CASE = ...``) defined in more than one module: one concept, one name, defined
#: once (issue 29: 30 when first counted, among them ``AXES`` three times; now none).  Like :data:`KNOWN_DUPLICATES`,
#: this list may only shrink.
KNOWN_DUPLICATE_CONSTANTS: dict[str, set[str]] = {}

#: ``dict[str, Any]`` annotations in the package today; may only come down (issue 29's target: 50).  182 when the
#: count was made; 206 after the merge of work done beside it: the fleet web app's JSON documents (``stableins.web``,
#: 22: they have pydantic models in ``web.models`` to return instead), the progress bar's chunk source and one record
#: reader check; 192 with the stage settings typed and the record writer's documents ``stableins.documents.JSONObject``
#: (issue 29: not met, to be typed); 170 with the web app's JSON documents returned as their ``web.models`` and the
#: plan ``web.runs`` reads from ``procedure.json`` a frozen dataclass (none left in ``stableins.web``); 36 with the data
#: readers' columns ``schema.Columns``, check's per-kind summaries, the procedure's sections and the plan's steps, the
#: navigation budget's and discovery's documents typed (TypedDicts, frozen dataclasses), and the parsed documents still
#: unvalidated ``documents.JSONObject`` / ``documents.TOMLTable``.
DICT_ANY_CEILING = 36

_COMMAND_PROTOCOL = {"configure", "run"}
_DICT_ANY = re.compile(r"\bdict\[str,\s*Any\]")
_CONSTANT = re.compile(r"[A-Z][A-Z0-9_]*")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def public_definitions() -> dict[str, set[str]]:
    """Every public module-level class and function of the package: name -> the modules defining it."""
    found: dict[str, set[str]] = defaultdict(set)
    for path in sorted(PACKAGE.rglob("*.py")):
        module = _module_name(path)
        if module == "stableins._version":
            continue
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if not isinstance(node, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef) or node.name.startswith("_"):
                continue
            if module.startswith("stableins.commands.") and node.name in _COMMAND_PROTOCOL:
                continue
            found[node.name].add(module)
    return found


def public_constants() -> dict[str, set[str]]:
    """Every public module-level constant of the package (an ``UPPER_CASE`` name assigned): name -> the modules defining it."""
    found: dict[str, set[str]] = defaultdict(set)
    for path in sorted(PACKAGE.rglob("*.py")):
        module = _module_name(path)
        if module == "stableins._version":
            continue
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
            for target in targets:
                if isinstance(target, ast.Name) and _CONSTANT.fullmatch(target.id):
                    found[target.id].add(module)
    return found


def dict_any_annotations() -> int:
    """The number of ``dict[str, Any]`` annotations (arguments, returns, variables, fields) in the package."""
    count = 0
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            annotations: list[ast.expr | None] = []
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                arguments = node.args
                every = [*arguments.posonlyargs, *arguments.args, *arguments.kwonlyargs, arguments.vararg, arguments.kwarg]
                annotations += [a.annotation for a in every if a is not None] + [node.returns]
            elif isinstance(node, ast.AnnAssign):
                annotations.append(node.annotation)
            count += sum(len(_DICT_ANY.findall(ast.unparse(a))) for a in annotations if a is not None)
    return count


def test_no_new_duplicate_public_name() -> None:
    duplicates = {name: modules for name, modules in public_definitions().items() if len(modules) > 1}
    new = {name: sorted(modules) for name, modules in duplicates.items() if not modules <= KNOWN_DUPLICATES.get(name, set())}
    assert not new, f"public names defined in more than one module (give each concept one name): {new}"
    gone = sorted(name for name in KNOWN_DUPLICATES if name not in duplicates)
    assert not gone, f"no longer defined twice: take them off KNOWN_DUPLICATES: {gone}"


def test_no_new_duplicate_constant() -> None:
    duplicates = {name: modules for name, modules in public_constants().items() if len(modules) > 1}
    new = {name: sorted(modules) for name, modules in duplicates.items() if not modules <= KNOWN_DUPLICATE_CONSTANTS.get(name, set())}
    assert not new, f"constants defined in more than one module (import the one definition, or name each concept): {new}"
    gone = sorted(name for name in KNOWN_DUPLICATE_CONSTANTS if name not in duplicates)
    assert not gone, f"no longer defined twice: take them off KNOWN_DUPLICATE_CONSTANTS: {gone}"


def test_dict_any_annotations_do_not_grow() -> None:
    count = dict_any_annotations()
    assert count <= DICT_ANY_CEILING, f"{count} dict[str, Any] annotations, more than {DICT_ANY_CEILING}: type the new ones"
    assert count == DICT_ANY_CEILING, f"{count} dict[str, Any] annotations: lower DICT_ANY_CEILING to {count}"


def test_the_counts_see_what_they_count(tmp_path: Path, monkeypatch) -> None:
    """The checks above can fail: a second definition and an annotation are found."""
    package = tmp_path / "stableins"
    (package / "commands").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text(
        "from typing import Any\nclass Step: ...\ndef f(x: dict[str, Any]) -> dict[str, Any]: ...\nAXES: tuple = ()\n_HIDDEN = 2\n"
    )
    (package / "b.py").write_text("def Step(): ...\ndef _private(): ...\nrows: dict[str, Any] = {}\nAXES = 1\n_HIDDEN = 2\n")
    (package / "commands" / "x.py").write_text("def run(args): ...\ndef configure(parser): ...\n")
    (package / "commands" / "y.py").write_text("def run(args): ...\n")
    monkeypatch.setattr(f"{__name__}.PACKAGE", package)
    assert {name: modules for name, modules in public_definitions().items() if len(modules) > 1} == {"Step": {"stableins.a", "stableins.b"}}
    assert {name: modules for name, modules in public_constants().items() if len(modules) > 1} == {"AXES": {"stableins.a", "stableins.b"}}
    assert dict_any_annotations() == 3
