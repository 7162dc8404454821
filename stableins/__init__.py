"""stableins: on-system accelerometer calibration for space-stable inertial navigation systems.

The package is laid out as the pipeline it implements::

    conventions, errormodel, platform      physics (frames, error model, gimbals)
    simulator                              the independent truth world
    data, records                          file formats and calibration records
    estimators                             coarse, fine and system-level stages
    discovery                              compare, rank missing effects, refit
    procedures, drivers                    step-by-step execution on a platform
    reporting                              PDF calibration reports

Heavy dependencies (numpy, scipy, filterpy, matplotlib) are imported by the
submodules that need them, never here, so ``stableins --help`` stays fast.

``stableins.__version__`` names the code that runs, from git (setuptools-scm): in a checkout it
is computed when first asked for (``0.1.devN+gHASH``, ``.dDATE`` added for uncommitted
changes), so records and certificates made from a checkout name its commit; an installed
wheel carries the version its build computed (``stableins/_version.py``).
"""

from __future__ import annotations

from pathlib import Path

_ROOT = Path(__file__).resolve().parent.parent


def _code_version() -> str:
    """Return the version of the code that runs (see the module docstring)."""
    if (_ROOT / ".git").exists() and (_ROOT / "pyproject.toml").is_file():
        try:
            import warnings

            from setuptools_scm import get_version
        except ImportError:  # a checkout without the test extra: the version of its last install
            pass
        else:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    # the same scheme as the build (pyproject.toml [tool.setuptools_scm]: defaults)
                    return str(get_version(root=str(_ROOT)))
            except Exception:  # no git executable, a damaged repository ...: fall back to the stamp
                pass
    try:
        from stableins._version import version  # written by the build (wheel or editable install)

        return str(version)
    except ImportError:
        from importlib.metadata import PackageNotFoundError
        from importlib.metadata import version as installed_version

        try:
            return installed_version("stableins")
        except PackageNotFoundError:
            return "0+unknown"


def __getattr__(name: str) -> str:
    if name == "__version__":
        value = _code_version()
        globals()["__version__"] = value  # computed once per process
        return value
    raise AttributeError(f"module 'stableins' has no attribute {name!r}")
