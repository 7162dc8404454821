"""How commands report results: text for people, or one JSON document with ``--json``.

Results go to stdout, everything else (progress, notes, warnings) to stderr, so
``stableins ... --json | jq`` always receives exactly one valid JSON document.
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Mapping
from typing import Any


def jsonable(value: Any) -> Any:
    """Plain-JSON version of ``value`` (numpy scalars/arrays, paths, tuples; NaN/inf → null)."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if hasattr(value, "tolist"):  # numpy arrays and scalars, without importing numpy
        return jsonable(value.tolist())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, str | int | bool) or value is None:
        return value
    return str(value)


def emit(args: Any, data: Mapping[str, object], text: str | None = None) -> None:
    """Print a command's result: ``data`` as JSON if ``args.json``, else ``text``.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments (``args.json`` set by the CLI for every command).
    data : mapping
        Machine-readable result (any values :func:`jsonable` turns into JSON) (SI units; keys documented by the command).
    text : str, optional
        Human-readable result; defaults to ``key: value`` lines of ``data``.
    """
    if getattr(args, "json", False):
        json.dump(jsonable(data), sys.stdout, indent=1, allow_nan=False)
        sys.stdout.write("\n")
    else:
        if text is None:
            text = "\n".join(f"{k}: {v}" for k, v in data.items())
        print(text)
    sys.stdout.flush()


def note(message: str) -> None:
    """Print a message for the person at the terminal (stderr; above a progress bar being drawn)."""
    from stableins.progress import write

    write(message)
