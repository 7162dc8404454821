"""Installable: procedures are package data found by name anywhere; the version comes from git and is stamped.

The wheel itself is built, installed into a fresh venv outside the checkout and run by
``.ci/installed-demo`` (``make test``); these tests pin what makes that work.
"""

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import stableins
from stableins import cli
from stableins.procedures.definition import PROCEDURE_DIRECTORY, load_procedure, resolve, shipped_procedures

ROOT = Path(__file__).resolve().parents[1]


def test_procedures_are_package_data_found_by_name_from_any_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    package = Path(stableins.__file__).resolve().parent
    assert PROCEDURE_DIRECTORY.is_relative_to(package)
    assert set(shipped_procedures()) >= {"device-coarse", "device-fine", "field-recal-device", "system-static"}
    for name in shipped_procedures():
        assert resolve(name).parent == PROCEDURE_DIRECTORY
        assert load_procedure(name).name == name
    # the wheel carries them: the package-data pattern matches every definition
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    patterns = config["tool"]["setuptools"]["package-data"]["stableins"]
    assert any(PROCEDURE_DIRECTORY.joinpath(f"{n}.toml").relative_to(package).match(p) for p in patterns for n in shipped_procedures())


def test_the_top_level_procedures_are_links_to_the_packaged_definitions_not_copies():
    top = ROOT / "procedures"
    linked = {p.stem: p for p in top.glob("*.toml")}
    assert set(linked) == set(shipped_procedures())
    for name, path in linked.items():
        assert path.is_symlink(), f"procedures/{path.name} must link to the packaged definition, not copy it"
        assert path.resolve() == (PROCEDURE_DIRECTORY / f"{name}.toml").resolve()
    assert "stableins/procedures/definitions" in (top / "README.md").read_text()


def test_an_unknown_procedure_name_lists_the_shipped_ones(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["simulate", "device", "--procedure", "device-corase", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "not found" in err and "procedure definition" in err and "device-coarse" in err
    assert "truth written" not in err and not (tmp_path / "x").exists()  # validated before anything is written


def _git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True, check=True).stdout.strip()


def test_the_version_comes_from_git_and_names_the_commit():
    """In a checkout the version is computed from git: it changes with every commit and names it."""
    version = stableins._code_version()  # computed now (stableins.__version__ is cached at its first use)
    head = _git("rev-parse", "HEAD")
    assert version != "0.1.0"
    local = version.partition("+")[2]
    assert local.startswith("g"), version
    commit = local[1:].split(".")[0]
    assert len(commit) >= 7 and head.startswith(commit), (version, head)
    dirty = bool(_git("status", "--porcelain", "--untracked-files=no"))
    assert (".d" in local) == dirty  # uncommitted changes are stamped as such
    from setuptools_scm import get_version

    assert version == get_version(root=str(ROOT))  # the scheme the wheel's build uses


def test_version_is_printed_and_stamped_in_records(capsys):
    import numpy as np

    from stableins.errormodel import ErrorModel
    from stableins.estimators.result import FitResult
    from stableins.records import CalibrationRecord

    assert cli.main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"stableins {stableins.__version__}"
    n = len(ErrorModel.standard())
    fit = FitResult("coarse", ErrorModel.standard().terms, np.ones(n), np.eye(n) * 1e-12, ("estimated",) * n, np.zeros(3), np.ones(3))
    assert CalibrationRecord.from_fit_result(fit, serial_number="SN1").provenance.software == f"stableins {stableins.__version__}"


def test_an_installed_package_reads_its_stamp_not_git(tmp_path):
    """Outside a checkout (a wheel in site-packages) the version is the one the build wrote."""
    import shutil
    import sys

    stamp = ROOT / "stableins" / "_version.py"
    assert stamp.is_file(), "the build (make setup / pip install) writes stableins/_version.py"
    shutil.copytree(ROOT / "stableins", tmp_path / "site" / "stableins", ignore=shutil.ignore_patterns("__pycache__"))
    code = "import stableins; print(stableins.__version__); print(stableins._ROOT)"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"} | {"PYTHONPATH": str(tmp_path / "site")}
    done = subprocess.run([sys.executable, "-S", "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    version, root = done.stdout.split()
    namespace: dict = {}
    exec(stamp.read_text(), namespace)
    assert version == namespace["version"] and Path(root) == tmp_path / "site"


def test_importing_every_submodule_keeps_the_version_readable():
    """A tool that imports every submodule (Sphinx autodoc, pkgutil walkers) imports ``stableins._version`` too.

    The submodule then lands in the package namespace; the version must still be computed (issue 29: a function
    named ``_version`` was shadowed by the submodule and ``stableins.__version__`` raised ``TypeError``).
    """
    code = (
        "import importlib, pkgutil, stableins\n"
        "for m in pkgutil.walk_packages(stableins.__path__, 'stableins.'):\n"
        "    if m.name.endswith('__main__'):\n"
        "        continue\n"
        "    importlib.import_module(m.name)\n"
        "import stableins._version\n"
        "print(stableins.__version__)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == stableins._code_version()
