"""``stableins check FILE...``: validate data files and calibration records, print a summary.

Each file is read completely and every check of ``docs/formats.md`` is applied
(columns, units, NaN/inf, time order, dwell blocks, sampling, record consistency): the
same validation the commands that consume the file run (``load_device`` for device
data, :meth:`~stableins.data.system.SystemRecord.validate` for system records,
``CalibrationRecord.load`` for records), so ``check`` and they never disagree.
Exit status 0 if all files pass, 2 at the first file that does not.
"""

from __future__ import annotations

import argparse
from typing import Any


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("files", nargs="+", metavar="FILE", help="device/system data (.csv, .h5) or calibration record (.json)")
    parser.add_argument("--allow-gaps", action="store_true", help="report gaps in system records as warnings instead of errors")


def summarize(path: str, allow_gaps: bool = False) -> dict[str, Any]:
    """Validate one file and describe it (raises InputError)."""
    import warnings
    from pathlib import Path

    if Path(path).suffix.lower() == ".json":
        from stableins.records import CalibrationRecord

        record = CalibrationRecord.load(path)
        return {
            "file": path,
            "kind": "calibration record",
            "serial_number": record.serial_number,
            "schema_version": record.schema_version,
            "stages": list(record.provenance.stages),
            "stages_carried_over": [s.name for s in record.stages if s not in record.stages_run],
            "parameters": len(record.parameters),
            "statuses": {s.value: sum(p.status is s for p in record.parameters) for s in sorted({p.status for p in record.parameters})},
        }
    from stableins.data.validation import FORMAT_TAGS, read_format_tag

    tag = read_format_tag(path)
    if tag == FORMAT_TAGS["device"]:
        from stableins.data.device import load_device

        dataset = load_device(path)
        dwells = dataset.dwells()
        return {
            "file": path,
            "kind": "device",
            "serial_number": dataset.metadata.serial_number,
            "rows": len(dataset),
            "stages": list(dataset.stages),
            "dwells": len(dwells),
            "passes": sorted({(d.stage, d.pass_number) for d in dwells}),
        }
    if tag == FORMAT_TAGS["system"]:
        from stableins.data.system import SamplingWarning, open_system_record

        record = open_system_record(path)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", SamplingWarning)
            validation = record.validate(allow_gaps=allow_gaps)  # exactly what calibrate system and diagnose run
        report, overview, segments = validation.sampling, validation.overview_step, validation.time_grid_segments
        return {
            "file": path,
            "kind": "system",
            "serial_number": record.metadata.serial_number,
            "samples": record.n_samples,
            "sample_rate_hz": record.sample_rate,
            "mean_rate_hz": report.mean_rate,
            "duration_s": record.duration,
            "gaps": len(report.gaps),
            "jitter_steps": report.n_jitter,
            "overview_step": overview,
            "time_grid_segments": segments,
            "warnings": [str(w.message) for w in caught],
        }
    from stableins.data.errors import InputError

    raise InputError(f"unknown format {tag!r}", path=path, field="format", expected="'stableins-device' or 'stableins-system'")


def run(args: argparse.Namespace) -> int:
    from stableins.output import emit

    summaries = [summarize(path, args.allow_gaps) for path in args.files]
    lines = []
    for s in summaries:
        details = ", ".join(f"{k} {v}" for k, v in s.items() if k not in ("file", "kind", "warnings"))
        lines.append(f"{s['file']}: ok ({s['kind']}; {details})")
        lines += [f"  warning: {w}" for w in s.get("warnings", [])]
    emit(args, {"files": summaries}, "\n".join(lines))
    return 0
