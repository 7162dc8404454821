"""The docs stay true: the notebook runs, the package's doctests pass, the Python snippets of README and docs/ run."""

from __future__ import annotations

import doctest
import importlib
import pkgutil
import re
from pathlib import Path

import pytest

import stableins

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "docs" / "discovery-loop.ipynb"


def _doctest_modules() -> list[str]:
    names = []
    for info in pkgutil.walk_packages(stableins.__path__, "stableins."):
        spec = importlib.util.find_spec(info.name)
        if spec is not None and spec.origin and spec.origin.endswith(".py") and ">>>" in Path(spec.origin).read_text(encoding="utf-8"):
            names.append(info.name)
    return names


@pytest.mark.parametrize("module", _doctest_modules())
def test_doctests(module):
    result = doctest.testmod(importlib.import_module(module), optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False)
    assert result.failed == 0


def test_doctests_exist():
    assert {"stableins.display", "stableins.errormodel", "stableins.discovery.library"} <= set(_doctest_modules())


# ----------------------------------------------------------------------------- snippets
def _snippets() -> list[tuple[str, int, str]]:
    out = []
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = path.read_text(encoding="utf-8")
        for match in re.finditer(r"^```python\n(.*?)^```", text, re.S | re.M):
            out.append((path.name, text[: match.start()].count("\n") + 1, match.group(1)))
    return out


#: Snippets that are fragments of a larger example (they use names or files the doc does not create), by file and the
#: start of their first line.  The docs part of issue 13 (branch ``console``) makes them self-contained; each is expected
#: to fail until then (strict: a snippet that starts to run turns this test red, so its entry is removed).
PENDING: set[tuple[str, str]] = set()


def _pending(name: str, code: str) -> bool:
    return any(name == doc and code.startswith(start) for doc, start in PENDING)


@pytest.mark.parametrize(
    "name, line, code",
    [
        pytest.param(
            name,
            line,
            code,
            id=f"{name}:{line}",
            marks=[pytest.mark.xfail(strict=True, reason="a fragment until the docs make it self-contained")]
            if _pending(name, code)
            else [],
        )
        for name, line, code in _snippets()
    ],
)
def test_python_snippet_runs(name, line, code, tmp_path, monkeypatch):
    """Each ```python block of README.md and docs/*.md runs as written, in an empty working directory."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("STABLEINS_HISTORY", str(tmp_path / "history"))
    exec(compile(code, f"{name}:{line}", "exec"), {"__name__": "__snippet__"})


def test_snippets_are_found():
    snippets = _snippets()
    assert any(name == "README.md" for name, _, _ in snippets)
    stale = {(doc, start) for doc, start in PENDING if not any(name == doc and code.startswith(start) for name, _, code in snippets)}
    assert not stale, stale  # an entry whose snippet changed or moved must be updated


# ----------------------------------------------------------------------------- notebook
def test_discovery_notebook_runs_and_finds_the_hidden_effect(tmp_path):
    nbformat = pytest.importorskip("nbformat")  # the test extra installs nbformat, nbclient and ipykernel
    nbclient = pytest.importorskip("nbclient")
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(notebook, timeout=120, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}})
    client.execute()  # the timeout is a guard against a hung cell, not a bound this test asserts (issue 31)
    text, html, images = [], [], 0
    for cell in notebook.cells:
        for output in cell.get("outputs", []):
            assert output.get("output_type") != "error", output
            if output.get("name") == "stdout":
                text.append(output["text"])
            data = output.get("data", {})
            html.append(data.get("text/html", ""))
            text.append(data.get("text/plain", ""))
            images += "image/png" in data
    text, html = "\n".join(text), "\n".join(html)
    assert "next: add Kcc_xxy" in text  # the ranking finds the hidden effect and says what to do
    assert "Ranking of candidate effects" in html and "Calibration record of SIM-2018" in html  # the results render as HTML
    assert "Kcc_xxy: kept" in html  # the recalibration keeps it
    match = re.search(r"Kcc_xxy: truth ([\d.]+), estimate ([\d.]+) ± ([\d.]+)", text)
    assert match, text[-2000:]
    truth, estimate, sigma = map(float, match.groups())
    assert abs(estimate - truth) < 4 * sigma
    assert images >= 2  # residuals before and after, the history
    assert re.search(r"\d+ pages, (PASS|FAIL|[A-Za-z ]+): .*certificate\.pdf", text)
