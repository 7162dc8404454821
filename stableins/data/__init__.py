"""File formats, metadata and input validation (see ``docs/formats.md``).

The readers and writers are importable from here; their modules (and numpy, h5py) are
imported on first use, so ``import stableins.data`` stays light::

    from stableins.data import load_device, save_device, open_system_record, SystemRecordWriter
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "DeviceDataset": "stableins.data.device",
    "Dwell": "stableins.data.device",
    "load_device": "stableins.data.device",
    "save_device": "stableins.data.device",
    "SystemRecord": "stableins.data.system",
    "SystemRecordWriter": "stableins.data.system",
    "open_system_record": "stableins.data.system",
    "SamplingWarning": "stableins.data.sampling",
    "SamplingReport": "stableins.data.sampling",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'stableins.data' has no attribute {name!r}")
