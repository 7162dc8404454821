"""Suite-wide settings: every hypothesis test is seeded (issue 31).

The ``stableins`` profile derandomizes hypothesis (its examples follow from each test's name, so every run and CI
see the same cases) and keeps no example database; a test's own ``@settings`` (``max_examples``, ``deadline``) inherit
it.  ``benchmarks/bench_fuzz.py`` seeds its own runs (``--seed``).

``fuzz_workspace``: one valid file of every kind (``tests/fuzzing.py``'s ``Workspace``), built once per test process
and shared by the modules that read it (bad input, fuzzing, the CLI options); they copy a file before changing it and
write their outputs elsewhere (issue 31: the suite's time).

One BLAS thread: the suite's matrices are small, as the commands' are, and ``stableins.cli.main`` gives a command
one linear-algebra thread (``single_threaded_blas``, issue 30), but only to libraries loaded after it: the test
process has numpy loaded before the first ``cli.main``, so without this the in-process commands and every estimator
test ran OpenBLAS's default threads, two spinning per process on two cores under ``-n auto`` (issue 31:
``tests/test_system_stage.py`` 31 s of CPU with them, 12 s with one).  It runs here, before any test module imports
numpy; xdist's workers and the subprocesses the tests start inherit it; a variable set by hand is kept.
"""

import sys
import warnings

import pytest
from hypothesis import settings

from stableins.cli import single_threaded_blas

single_threaded_blas()
if "numpy" in sys.modules:  # pragma: no cover - a plugin loaded it first: the setting came too late to apply
    warnings.warn("numpy was imported before tests/conftest.py set one BLAS thread: the suite runs with its default threads", stacklevel=1)

settings.register_profile("stableins", derandomize=True, database=None)
settings.load_profile("stableins")


@pytest.fixture(scope="session")
def fuzz_workspace(tmp_path_factory):
    import fuzzing

    return fuzzing.Workspace(tmp_path_factory.mktemp("workspace"))
