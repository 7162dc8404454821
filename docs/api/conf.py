"""Sphinx configuration of the API reference (``make docs``; built by ``make test`` with warnings as errors).

The page of each public module is written here at build time from the package itself (every module of
``stableins`` except the command-line interface, which docs/cli.md documents), so a module added, moved or
removed needs no edit of this directory.  Nothing is fetched from the network.
"""

from __future__ import annotations

import pkgutil
from pathlib import Path

import stableins

project = "stableins"
author = "The stableins developers"
copyright = "2026, The stableins developers"
release = version = stableins.__version__

extensions = ["sphinx.ext.autodoc", "numpydoc"]
exclude_patterns = ["_build"]
html_theme = "alabaster"

autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "none"  # numpydoc's Parameters sections carry the types in words
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

# The interface layer (argument parsing, console output) is documented in docs/cli.md, not here.
INTERFACE = ("stableins.cli", "stableins.commands", "stableins.output", "stableins.progress", "stableins.__main__", "stableins._version")
# Modules whose docstrings do not build clean yet (the list only shrinks; empty since issue 15).
NOT_YET_CLEAN: set[str] = set()
HERE = Path(__file__).resolve().parent
GENERATED = HERE / "modules"


def public_modules() -> list[str]:
    """Return the importable modules of the package the reference documents, sorted by name."""
    names = [info.name for info in pkgutil.walk_packages(stableins.__path__, "stableins.")]
    private = {n for n in names if n.rsplit(".", 1)[-1].startswith("_")}
    return sorted(n for n in ["stableins", *names] if not n.startswith(INTERFACE) and n not in private | NOT_YET_CLEAN)


def _write_pages() -> None:
    GENERATED.mkdir(exist_ok=True)
    wanted = {}
    for name in public_modules():
        title = f"``{name}``"
        wanted[f"{name}.rst"] = f"{title}\n{'=' * len(title)}\n\n.. automodule:: {name}\n"
    for stale in GENERATED.glob("*.rst"):
        if stale.name not in wanted:
            stale.unlink()
    for file, text in wanted.items():
        path = GENERATED / file
        if not path.is_file() or path.read_text() != text:
            path.write_text(text)


_write_pages()
