"""The format tag of a stableins data file (``.csv`` or ``.h5``), read from its header without reading the data."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from stableins.data.csvformat import open_text, read_header_block, read_line
from stableins.data.hdf5format import open_h5, read_header_attribute


def read_format_tag(path: Any) -> str:
    """Return the ``format`` entry of a stableins data file's header (``.csv`` or ``.h5``), without reading the data.

    Returns ``"stableins-device"``, ``"stableins-system"`` or whatever the file says.
    """
    path = Path(path)
    if path.suffix.lower() in (".h5", ".hdf5", ".hdf"):
        with open_h5(path) as f:
            document = read_header_attribute(f, path)
    else:
        with open_text(str(path)) as handle:
            count = iter(range(1, 1 << 62))
            document, _ = read_header_block(lambda: read_line(handle, str(path), next(count)), str(path))
    return str(document.get("format")) if isinstance(document, dict) else "unknown"
