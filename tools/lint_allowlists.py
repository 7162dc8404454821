"""Regenerate the shrinking allow-lists of pyproject.toml from what ruff and mypy report now.

The allow-lists let the checks pass while files are being cleaned: each not-yet-clean file is
listed with exactly what it still violates (ruff ``per-file-ignores``; mypy ``ignore_errors``
overrides).  Run after cleaning a file, then commit the shorter list::

    .venv/bin/python tools/lint_allowlists.py            # rewrite both lists
    .venv/bin/python tools/lint_allowlists.py --check    # exit 1 if a list is not exact

A list that names a clean file is not exact: ``--check`` (run by ``make test``) fails on it.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = ROOT / "pyproject.toml"
BIN = Path(sys.executable).parent
RUFF_TARGETS = ["stableins", "tests", "tools", "benchmarks"]


def _replace_block(text: str, name: str, body: list[str]) -> str:
    pattern = re.compile(rf"(# BEGIN {name}\n).*?(# END {name}\n)", re.S)
    if not pattern.search(text):
        raise SystemExit(f"pyproject.toml: markers '# BEGIN {name}' / '# END {name}' not found")
    return pattern.sub(lambda m: m.group(1) + "".join(line + "\n" for line in body) + m.group(2), text)


def _without_blocks(text: str) -> str:
    for name in ("ruff allow-list", "mypy allow-list"):
        text = _replace_block(text, name, [])
    return text


def ruff_violations(config_text: str) -> dict[str, set[str]]:
    """Return the codes each file violates under the configuration without its allow-list."""
    scratch = ROOT / ".lint_allowlists.toml"
    scratch.write_text(_ruff_only(config_text))
    try:
        out = subprocess.run(
            [str(BIN / "ruff"), "check", "--config", str(scratch), "--output-format", "json", "--exit-zero", *RUFF_TARGETS],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    finally:
        scratch.unlink()
    codes: dict[str, set[str]] = defaultdict(set)
    for item in json.loads(out):
        codes[Path(item["filename"]).resolve().relative_to(ROOT).as_posix()].add(item["code"])
    return codes


def _ruff_only(text: str) -> str:
    """Return the [tool.ruff*] tables of pyproject.toml as a ruff.toml (without the ``tool.ruff`` prefix)."""
    lines, keep = [], False
    for line in text.splitlines():
        header = re.match(r"\[\s*tool\.ruff(\.[^\]]*)?\]\s*$", line)
        if line.startswith("["):
            keep = bool(header)
            if keep:
                sub = header.group(1)
                lines.append(f"[{sub[1:]}]" if sub else "")
            continue
        if keep:
            lines.append(line)
    return "\n".join(lines) + "\n"


def mypy_modules(config_text: str) -> list[str]:
    """Return the modules with mypy errors under the configuration without its allow-list."""
    scratch = ROOT / ".lint_allowlists_mypy.toml"
    scratch.write_text(config_text)
    try:
        out = subprocess.run(
            [str(BIN / "mypy"), "--config-file", str(scratch)],
            cwd=ROOT,
            capture_output=True,
            text=True,
        ).stdout
    finally:
        scratch.unlink()
    files = {line.split(":", 1)[0] for line in out.splitlines() if re.match(r"^\S+\.py:\d+: error:", line)}
    modules = set()
    for file in files:
        module = file.removesuffix(".py").replace("/", ".").removesuffix(".__init__")
        modules.add(module)
    return sorted(modules)


def build(text: str) -> str:
    """Return the pyproject.toml text with both allow-lists regenerated."""
    bare = _without_blocks(text)
    ruff_lines = [f'"{path}" = {json.dumps(sorted(codes))}' for path, codes in sorted(ruff_violations(bare).items())]
    modules = mypy_modules(bare)
    mypy_lines = []
    if modules:
        mypy_lines = ["[[tool.mypy.overrides]]", "module = [", *(f'    "{m}",' for m in modules), "]", "ignore_errors = true"]
    return _replace_block(_replace_block(bare, "ruff allow-list", ruff_lines), "mypy allow-list", mypy_lines)


def main() -> int:
    """Rewrite the allow-lists, or with ``--check`` report whether they are exact."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="do not write; exit 1 if an allow-list is not exact")
    args = parser.parse_args()
    text = PYPROJECT.read_text()
    new = build(text)
    if args.check:
        if new != text:
            print("pyproject.toml: the lint allow-lists are not exact; run tools/lint_allowlists.py and commit", file=sys.stderr)
            import difflib

            sys.stderr.writelines(difflib.unified_diff(text.splitlines(True), new.splitlines(True), "now", "exact"))
            return 1
        return 0
    PYPROJECT.write_text(new)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
