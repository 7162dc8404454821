"""The command-line flag of each library parameter a user error may name.

Library functions name their own parameters in :class:`~stableins.errors.InputError` (``field="driver_spec"``);
the command line speaks of its flags.  :func:`as_flag` rewrites the one into the other before the error is printed,
so the library knows nothing of the CLI and the user reads the flag they typed.
"""

from __future__ import annotations

from stableins.errors import InputError, NotDeterminedError

#: Library parameter (``InputError.field``) → the flag that sets it.
FLAGS = {
    "driver_spec": "--driver",  # procedures.rundir.start_run/resume_run, drivers.select
    "prior_file": "--prior",  # procedures.rundir.start_run
    "unit": "--unit",  # procedures.rundir.start_run
    "re_estimate": "--re-estimate",  # procedures.rundir.resume_run
    "root": "--store",  # history_store.HistoryStore
    "date": "--at",  # history_store.HistoryStore.in_force
    "entries": "--set",  # records.parse_entries
    "add": "--add",  # discovery.diagnose.DiagnoseOptions, diagnose_data
}


def as_flag(error: InputError | NotDeterminedError) -> InputError | NotDeterminedError:
    """``error`` naming the command-line flag of the parameter it names (unchanged when it names no parameter)."""
    flag = FLAGS.get(error.field or "")
    if flag is not None:
        error.field = flag
        error.args = (error.describe(),)
    return error
