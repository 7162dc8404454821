"""Size limits of the package: no function over 100 lines, every module under 500 lines.

The allow-lists name today's offenders and only shrink: a listed file that is now within its limit
fails the test, so whoever shortens it also removes it from the list.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "stableins"
MAX_FUNCTION_LINES = 100  # a function (decorators excluded) has at most this many lines
MAX_MODULE_LINES = 499  # a module has fewer than 500 lines

# Modules of 500 lines or more (path relative to stableins/).
LONG_MODULES: set[str] = set()

# Modules holding a function of more than 100 lines.
LONG_FUNCTION_MODULES: set[str] = set()


def _modules() -> dict[str, Path]:
    return {path.relative_to(PACKAGE).as_posix(): path for path in sorted(PACKAGE.rglob("*.py"))}


def _module_lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def _long_functions(path: Path) -> list[str]:
    """``name (N lines)`` for each function of ``path`` longer than the limit."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    long = []
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            lines = node.end_lineno - node.lineno + 1
            if lines > MAX_FUNCTION_LINES:
                long.append(f"{node.name} ({lines} lines)")
    return long


def test_the_allow_lists_name_existing_modules():
    modules = _modules()
    assert not (LONG_MODULES | LONG_FUNCTION_MODULES) - modules.keys(), "remove deleted or moved modules from the allow-lists"


def test_modules_are_under_500_lines():
    too_long = {name for name, path in _modules().items() if _module_lines(path) > MAX_MODULE_LINES}
    assert not too_long - LONG_MODULES, f"modules of 500 lines or more: {sorted(too_long - LONG_MODULES)}"
    assert not LONG_MODULES - too_long, f"now under 500 lines, remove from LONG_MODULES: {sorted(LONG_MODULES - too_long)}"


def test_functions_are_at_most_100_lines():
    offenders = {name: found for name, path in _modules().items() if (found := _long_functions(path))}
    new = {name: found for name, found in offenders.items() if name not in LONG_FUNCTION_MODULES}
    assert not new, f"functions over {MAX_FUNCTION_LINES} lines: {new}"
    fixed = LONG_FUNCTION_MODULES - offenders.keys()
    assert not fixed, f"no function over {MAX_FUNCTION_LINES} lines any more, remove from LONG_FUNCTION_MODULES: {sorted(fixed)}"


def test_the_function_measure_counts_lines_from_def_to_last_statement(tmp_path):
    source = tmp_path / "m.py"
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    source.write_text(f"def short():\n    return 1\n\n\ndef long():\n{body}\n")
    assert _long_functions(source) == [f"long ({MAX_FUNCTION_LINES + 1} lines)"]
