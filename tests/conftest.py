"""Suite-wide settings: every hypothesis test is seeded (issue 31).

The ``stableins`` profile derandomizes hypothesis (its examples follow from each test's name, so every run and CI
see the same cases) and keeps no example database; a test's own ``@settings`` (``max_examples``, ``deadline``) inherit
it.  ``benchmarks/bench_fuzz.py`` seeds its own runs (``--seed``).

``fuzz_workspace``: one valid file of every kind (``tests/fuzzing.py``'s ``Workspace``), built once per test process
and shared by the modules that read it (bad input, fuzzing, the CLI options); they copy a file before changing it and
write their outputs elsewhere (issue 31: the suite's time).
"""

import pytest
from hypothesis import settings

settings.register_profile("stableins", derandomize=True, database=None)
settings.load_profile("stableins")


@pytest.fixture(scope="session")
def fuzz_workspace(tmp_path_factory):
    import fuzzing

    return fuzzing.Workspace(tmp_path_factory.mktemp("workspace"))
