"""Suite-wide settings: every hypothesis test is seeded (issue 31).

The ``stableins`` profile derandomizes hypothesis (its examples follow from each test's name, so every run and CI
see the same cases) and keeps no example database; a test's own ``@settings`` (``max_examples``, ``deadline``) inherit
it.  ``benchmarks/bench_fuzz.py`` seeds its own runs (``--seed``).
"""

from hypothesis import settings

settings.register_profile("stableins", derandomize=True, database=None)
settings.load_profile("stableins")
