"""The truth file of a simulated world (``truth.json``, schema_version 1; see ``docs/simulator.md``).

:class:`stableins.simulator.truth.Truth` is the world; this module is its file: written atomically (a reader
sees the old file or the whole new one), read by the one safe JSON reader, every problem an
:class:`~stableins.errors.InputError` naming the file and the field.
"""

from __future__ import annotations

import json
import os

from stableins.data.atomic import atomic_write
from stableins.data.jsonio import load_json_file
from stableins.simulator.truth import Truth


def save_truth(truth: Truth, path: str | os.PathLike[str]) -> None:
    """Write ``truth`` as JSON, atomically."""
    with atomic_write(path) as handle:
        json.dump(truth.to_dict(), handle, indent=2, sort_keys=True)
        handle.write("\n")


def load_truth(path: str | os.PathLike[str]) -> Truth:
    """Read a truth file; :class:`~stableins.errors.InputError` (naming the file and field) on any problem."""
    data = load_json_file(path, what="a truth file (truth.json) written by 'stableins simulate'")
    return Truth.from_dict(data, source=str(path))
