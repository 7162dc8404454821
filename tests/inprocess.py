"""``stableins ARGV`` run in the test's own process: exit status, standard output and standard error (issue 31).

A fresh ``python -m stableins.cli`` pays about a second of CPU for its imports (numpy, scipy, matplotlib, h5py);
:func:`run_cli` calls :func:`stableins.cli.main` instead, with standard output and error captured and standard input
given (a closed one by default, as ``subprocess.DEVNULL`` gives a child).  A warning the command leaves unhandled is
written to the captured standard error under Python's default filters, as a fresh interpreter prints it; what a
child process would print as a traceback escapes here as the exception itself and fails the test.

Keep a real process (``subprocess``) where the test is about the process: its interpreter's exit status and
traceback, what it imports, kills, signals, locks, servers, or the environment it starts with.
"""

from __future__ import annotations

import contextlib
import io
import sys
import warnings
from collections.abc import Sequence
from typing import NamedTuple


class CliRun(NamedTuple):
    """The outcome of one command, named as :class:`subprocess.CompletedProcess` names it."""

    returncode: int
    stdout: str
    stderr: str


def run_cli(argv: Sequence[object], *, stdin: str = "") -> CliRun:
    """Run ``stableins ARGV`` in this process (paths and numbers as ``str``); ``stdin``: what a person types (lines ending in a newline)."""
    from stableins import cli

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings(record=True) as caught:
        _interpreter_warning_filters()
        saved, sys.stdin = sys.stdin, io.StringIO(stdin)
        try:
            status = cli.main([str(a) for a in argv])
        finally:
            sys.stdin = saved
            for w in caught:
                err.write(warnings.formatwarning(w.message, w.category, w.filename, w.lineno, w.line))
    return CliRun(status, out.getvalue(), err.getvalue())


def _interpreter_warning_filters() -> None:
    """Python's default warning filters (``python -W`` unset, no ``-X dev``): what a fresh interpreter shows once."""
    warnings.resetwarnings()
    warnings.filterwarnings("default", category=DeprecationWarning, module="__main__", append=True)
    for quiet in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
        warnings.filterwarnings("ignore", category=quiet, append=True)
    warnings.simplefilter("default", append=True)
