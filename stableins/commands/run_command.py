"""The ``stableins run`` command: a procedure run (:mod:`stableins.commands.run`), or the resume of a recalibration.

The procedure run is :mod:`stableins.commands.run` (its module docstring gives the usage and the exit
statuses); a field recalibration's run (``stableins recal``) resumes as one, through
:mod:`stableins.commands.recal`, which files its record.  The hand-over lives here, above both, so that
``recal`` (which builds on the procedure run) and the procedure run import each other in one direction only.
"""

from __future__ import annotations

import argparse

from stableins.commands import run as procedure_run


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins run`` to ``parser``."""
    procedure_run.configure(parser)


def run(args: argparse.Namespace) -> int:
    """Run ``stableins run``: start or resume a procedure on a platform; return the exit code."""
    if args.resume and procedure_run.recal_settings(args.resume) is not None:
        from stableins.commands import recal

        return recal.run(recal.resume_arguments(args))  # a field recalibration resumes as one: it files its record
    return procedure_run.run(args)
