"""``stableins check FILE...``: validate any file stableins writes, print what it holds.

Each file is recognized by its content (its first bytes, its ``format`` or ``kind`` field) and read with
exactly the validation of the code that consumes it, so that ``check`` and those commands never disagree:

===========================================  =====================================================================
file                                         validated by
===========================================  =====================================================================
device data (``.csv``, ``.h5``)               ``load_device`` (what ``calibrate device`` and ``diagnose`` read)
system record (``.h5``)                       ``SystemRecord.validate`` (what ``calibrate system`` and ``diagnose`` run)
calibration record (``.json``)                ``CalibrationRecord.load`` (records, ``prior.json``, the history store's copies)
simulator truth (``truth.json``)              ``load_truth`` (what ``simulate --truth`` reads)
plan (``procedure.json``)                     ``Plan.from_dict`` (what ``run`` reads as PROCEDURE)
procedure definition (``.toml``)              ``load_procedure`` (what ``run``, ``simulate``, ``calibrate device`` read)
run journal (``journal.bin``)                 the journal reader of ``run --resume`` (records, CRC-32, start record, plan)
diagnosis (``diagnose --json``)               the reader of ``report --discovery``
demo verdict (``verdict.json``)               every row's fields and types
history store index (``history.sqlite``)      ``HistoryStore.verify`` (the index and every filed record's SHA-256)
certificate (``.pdf``), plots (PNG, SVG)      the file's structure (header, trailer, page count; image size)
holds table (``calibrate poses``)             ``read_holds_table`` (what ``calibrate poses --holds`` reads)
text reports (``.txt``)                       UTF-8 text
===========================================  =====================================================================

Exit status 0 if all files pass, 2 at the first file that does not.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, NotRequired, TypeAlias, TypedDict

if TYPE_CHECKING:  # pragma: no cover
    from stableins.documents import JSONObject


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins check`` to ``parser``."""
    parser.add_argument("files", nargs="+", metavar="FILE", help="any file stableins writes: data, records, truth, plans, journals, ...")
    parser.add_argument("--allow-gaps", action="store_true", help="report gaps in system records as warnings instead of errors")
    parser.add_argument(
        "--trust", nargs="+", default=[], metavar="CERT.pem", help="trust anchors: a signed certificate's signer must chain to one"
    )


#: First bytes of binary files stableins writes.
PDF_MAGIC, PNG_MAGIC, HDF5_MAGIC, SQLITE_MAGIC = b"%PDF-", b"\x89PNG\r\n\x1a\n", b"\x89HDF\r\n\x1a\n", b"SQLite format 3\x00"
#: Largest text or PDF file ``check`` reads whole (a certificate is about 1 MB).
MAX_WHOLE_FILE = 256 << 20


class _Summary(TypedDict):
    """What every file's summary says: the file and its kind, and any warnings (the console prints the other fields as ``key value``)."""

    file: str
    kind: str
    warnings: NotRequired[list[str]]


class DeviceSummary(_Summary):
    """Device data: the unit, its rows, stages, dwells and (stage, pass) pairs."""

    serial_number: str
    rows: int
    stages: list[str]
    dwells: int
    passes: list[tuple[str, int]]


class SystemSummary(_Summary):
    """A system record: as ``SystemRecord.validate`` found it, with the sampling warnings it gave."""

    serial_number: str
    samples: int
    sample_rate_hz: float
    mean_rate_hz: float
    duration_s: float
    gaps: int
    jitter_steps: int
    overview_step: int
    time_grid_segments: int


class TruthSummary(_Summary):
    """A simulator truth file."""

    serial_number: str
    seed: int
    parameters: int
    hidden_effects: list[str]


class PlanSummary(_Summary):
    """A procedure plan (``procedure.json``)."""

    name: str
    level: str
    steps: int


class DiagnosisSummary(_Summary):
    """The output of ``stableins diagnose --json``."""

    stage: str
    steps: int
    flagged: list[str]


class RecordSummary(_Summary):
    """A calibration record: its stages and parameters by status."""

    serial_number: str
    schema_version: int
    stages: list[str]
    stages_carried_over: list[str]
    parameters: int
    statuses: dict[str, int]


class VerdictSummary(_Summary):
    """The demo's ``verdict.json``."""

    parameters: int
    largest_abs_z: float


class ProcedureSummary(_Summary):
    """A procedure definition (``.toml``)."""

    name: str
    stage: str
    positions: int
    tolerances: bool


class JournalSummary(_Summary):
    """A run journal; ``warnings`` when its last record is torn."""

    procedure: str
    unit: str | None
    records: int
    state: str
    records_by_kind: dict[str, int]


class StoreSummary(_Summary):
    """A history store index, verified."""

    units: int
    records: int


#: The inputs a certificate names, compared with the files beside it (``not beside it``: those absent); empty when it
#: names none.
NamedInputs = TypedDict("NamedInputs", {"inputs": str, "not beside it": NotRequired[str]}, total=False)
#: A PDF: pages, a stableins report's title and subject, the inputs it names (:data:`NamedInputs`), its signature.
PdfSummary = TypedDict(
    "PdfSummary",
    {
        "file": str,
        "kind": str,
        "warnings": NotRequired[list[str]],
        "pages": int,
        "title": NotRequired[str],
        "subject": NotRequired[str],
        "inputs": NotRequired[str],
        "not beside it": NotRequired[str],
        "signature": NotRequired[str],
    },
)


class HoldsSummary(_Summary):
    """A holds table (``calibrate poses --write-holds``)."""

    holds: int
    labelled: int


class PngSummary(_Summary):
    """A PNG plot."""

    width: int
    height: int


class TextSummary(_Summary):
    """A text file (report, SVG plot)."""

    lines: int


#: What ``check`` says of one file: one summary per kind of file.
FileSummary: TypeAlias = (
    DeviceSummary
    | SystemSummary
    | TruthSummary
    | PlanSummary
    | DiagnosisSummary
    | RecordSummary
    | VerdictSummary
    | ProcedureSummary
    | JournalSummary
    | StoreSummary
    | PdfSummary
    | HoldsSummary
    | PngSummary
    | TextSummary
)


def describe_file(path: str, *, allow_gaps: bool = False, trust: tuple[str, ...] = ()) -> FileSummary:
    """Recognize and validate one file and describe it (raises InputError naming the file, the field and what was expected)."""
    from stableins.procedures.journal import FILE_MAGIC

    file = Path(path)
    head = _head(file)
    suffix = file.suffix.lower()
    if head.startswith(HDF5_MAGIC) or suffix in (".h5", ".hdf5", ".hdf"):
        return _data(path, allow_gaps=allow_gaps)
    if head.startswith(FILE_MAGIC[:8]) or suffix == ".bin":
        return _journal(path)
    if head.startswith(SQLITE_MAGIC):
        return _store(path)
    if head.startswith(PDF_MAGIC):
        return _pdf(path, trust)
    if head.startswith(PNG_MAGIC):
        return _png(path, head)
    if suffix == ".csv" or head.startswith(b"# stableins-device"):
        return _data(path, allow_gaps=allow_gaps)
    if suffix == ".toml":
        return _procedure(path)
    if suffix == ".json" or head.lstrip()[:1] in (b"{", b"["):
        return _json(path)
    if suffix == ".svg" or head.lstrip().startswith((b"<?xml", b"<svg")):
        return _text(path, "plot (SVG)")
    return _text(path, "text report")


def _head(file: Path) -> bytes:
    from stableins.data.jsonio import read_input_bytes

    if not file.exists():
        from stableins.errors import InputError

        raise InputError("no such file", path=file)  # as the data readers say it
    if not file.is_file():  # a directory: the reader's one message; a device or a pipe: this one
        read_input_bytes(file, max_bytes=MAX_WHOLE_FILE, what="a file written by stableins")
        from stableins.errors import InputError

        raise InputError("not a regular file (a device, a pipe or a socket)", path=file, expected="a file written by stableins")
    with open(file, "rb") as handle:
        head = handle.read(64)
    if not head:
        from stableins.errors import InputError

        raise InputError("the file is empty", path=file, expected="a file written by stableins (none is empty)")
    return head


def _data(path: str, *, allow_gaps: bool) -> DeviceSummary | SystemSummary | HoldsSummary:
    """Check device data or a system record (or a holds table: a CSV file too)."""
    import warnings

    if _head(Path(path)).startswith(b"hold,start,end"):
        return _holds(path)

    from stableins.data.format_tag import read_format_tag
    from stableins.data.validation import FORMAT_TAGS
    from stableins.errors import InputError

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
        from stableins.data.sampling import SamplingWarning
        from stableins.data.system import open_system_record

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
    raise InputError(f"unknown format {tag!r}", path=path, field="format", expected="'stableins-device' or 'stableins-system'")


def _json(path: str) -> RecordSummary | TruthSummary | PlanSummary | DiagnosisSummary | VerdictSummary:
    from stableins.data.jsonio import load_json_file
    from stableins.errors import InputError
    from stableins.records import RECORD_FORMAT

    document = load_json_file(path, what="a JSON file written by stableins")
    if isinstance(document, dict) and (document.get("format") == RECORD_FORMAT or "parameters" in document and "covariance" in document):
        return _record(path)
    if isinstance(document, dict) and (document.get("kind") == "stableins.truth" or {"parameters", "site", "noise"} <= set(document)):
        from stableins.data.truth import load_truth

        truth = load_truth(path)
        return {
            "file": path,
            "kind": "simulator truth",
            "serial_number": truth.site.serial_number,
            "seed": truth.seed,
            "parameters": len(truth.parameters),
            "hidden_effects": sorted(truth.effects),
        }
    if isinstance(document, dict) and {"name", "level", "steps"} <= set(document):
        from stableins.procedures.plan import Plan

        plan = Plan.from_dict(document, path)
        return {"file": path, "kind": "procedure plan", "name": plan.name, "level": plan.level, "steps": len(plan.steps)}
    if isinstance(document, dict) and {"candidates", "history"} <= set(document):
        from stableins.reporting.builder import read_discovery

        diagnosis = read_discovery(path)
        flagged = [c.id for c in diagnosis.flagged]
        return {"file": path, "kind": "diagnosis", "stage": str(diagnosis.stage), "steps": len(diagnosis.history), "flagged": flagged}
    if isinstance(document, list) and document and all(isinstance(r, dict) and "estimate" in r and "truth" in r for r in document):
        return _verdict(path, document)
    raise InputError(
        "a JSON document stableins does not write",
        path=path,
        expected="a calibration record, truth.json, procedure.json, the output of 'stableins diagnose --json' or the demo's verdict.json",
    )


def _record(path: str) -> RecordSummary:
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


#: Fields of a row of the demo's ``verdict.json`` and their types.
_VERDICT_FIELDS = {"id": str, "unit": str, "truth": float, "estimate": float, "sigma": float, "error": float, "z": float}


def _verdict(path: str, rows: list[JSONObject]) -> VerdictSummary:
    from stableins.data.jsonio import expect_number
    from stableins.errors import InputError

    for k, row in enumerate(rows):
        for key, kind in _VERDICT_FIELDS.items():
            where = f"[{k}].{key}"
            if key not in row:
                raise InputError("missing", path=path, field=where, expected=f"the fields {', '.join(_VERDICT_FIELDS)}")
            if kind is str and not isinstance(row[key], str):
                raise InputError(f"{row[key]!r} is not a string", path=path, field=where, expected="a string")
            if kind is float and not (key == "z" and row[key] is None):
                expect_number(row[key], path, where)
    worst = max((abs(z) for r in rows if isinstance(z := r["z"], int | float)), default=float("nan"))  # a number or null, checked above
    return {"file": path, "kind": "demo verdict", "parameters": len(rows), "largest_abs_z": worst}


def _procedure(path: str) -> ProcedureSummary:
    from stableins.procedures.definition import load_procedure

    definition = load_procedure(path)
    return {
        "file": path,
        "kind": "procedure definition",
        "name": definition.name,
        "stage": definition.stage,
        "positions": len(definition.steps),
        "tolerances": definition.tolerances is not None,
    }


def _journal(path: str) -> JournalSummary:
    from collections import Counter

    from stableins.errors import InputError
    from stableins.procedures.journal import scan
    from stableins.procedures.plan import Plan

    result = scan(path)  # the reader of --resume: CRC-32 of every record, damage before the last record refused
    if not result.records or result.records[0].kind != "start":
        raise InputError("the journal holds no start record", path=path, field="start", expected="a journal written by 'stableins run'")
    start = result.records[0]
    plan = Plan.from_dict(start["plan"], f"{path}, start record, plan")
    kinds = Counter(r.kind for r in result.records)
    state = "finished" if kinds["complete"] else ("stopped" if kinds["stop"] else "interrupted or running")
    summary: JournalSummary = {
        "file": path,
        "kind": "run journal",
        "procedure": plan.name,
        "unit": start.get("unit"),
        "records": len(result.records),
        "state": state,
        "records_by_kind": dict(sorted(kinds.items())),
    }
    if result.torn_bytes:
        summary["warnings"] = [f"a torn last record ({result.torn_bytes} bytes, {result.torn_reason}): 'stableins run --resume' drops it"]
    return summary


def _store(path: str) -> StoreSummary:
    from stableins.errors import InputError
    from stableins.history_store import STORE_NAME, HistoryStore

    file = Path(path)
    if file.name != STORE_NAME:
        raise InputError("an SQLite file that is not a history store index", path=path, expected=f"{STORE_NAME} in a history store")
    store = HistoryStore(file.parent)
    problems = store.verify()
    if problems:
        raise InputError(f"{len(problems)} problem(s); the first: {problems[0]}", path=path, expected="a consistent history store")
    serials = store.serials()
    return {
        "file": path,
        "kind": "history store index",
        "units": len(serials),
        "records": sum(len(store.entries(s)) for s in serials),
    }


def _pdf(path: str, trust: tuple[str, ...] = ()) -> PdfSummary:
    import re

    from stableins.data.jsonio import read_input_bytes
    from stableins.errors import InputError

    data = read_input_bytes(path, max_bytes=MAX_WHOLE_FILE, what="a PDF written by stableins")
    if b"%%EOF" not in data[-1024:]:
        raise InputError("the PDF has no end-of-file marker (cut short?)", path=path, field="%%EOF", expected="a complete PDF")
    # page objects by number: an incremental update (a signature) rewrites a page under the same number
    pages = len(set(re.findall(rb"(\d+) \d+ obj\s*<<(?:(?!endobj).)*?/Type\s*/Page(?![s\w])", data, re.S)))

    def info(key: str) -> str:
        match = re.search(rb"/" + key.encode() + rb" \(((?:[^()\\]|\\.)*)\)", data)
        return match.group(1).decode("latin-1").replace("\\(", "(").replace("\\)", ")") if match else ""

    summary = PdfSummary(file=path, kind="PDF document", pages=pages)
    if info("Author") == "stableins" and info("Title"):
        kind = "technical report (PDF)" if info("Title").startswith("Technical report") else "calibration certificate (PDF)"
        summary["kind"], summary["title"], summary["subject"] = kind, info("Title"), info("Subject")
    if pages == 0:
        raise InputError("the PDF has no pages", path=path, field="pages", expected="a PDF with at least one page")
    named = _named_inputs(path, data)
    if "inputs" in named:
        summary["inputs"] = named["inputs"]
    if "not beside it" in named:
        summary["not beside it"] = named["not beside it"]
    from stableins.reporting import signing

    if signing.is_signed(data):
        found = signing.verify(data, path, trust)
        summary["signature"] = f"intact and valid, signed by {found.signer}" + (
            ", signer trusted" if found.trusted else " (no trust anchor given: the signer is not vouched for)"
        )
    return summary


def _holds(path: str) -> HoldsSummary:
    """Check a holds table (``calibrate poses --write-holds``) as ``--holds`` reads it."""
    from stableins.data.holds import read_holds_table

    rows = read_holds_table(path)
    return {"file": path, "kind": "holds table", "holds": len(rows), "labelled": sum(1 for *_, o in rows if o)}


def _named_inputs(path: str, data: bytes) -> NamedInputs:
    """Compare the SHA-256 of every input a certificate names with the file of that name beside it (a mismatch is an error)."""
    from stableins.errors import InputError
    from stableins.records import file_sha256
    from stableins.reporting.signing import read_manifest

    rows = read_manifest(data)
    if not rows:
        return {}
    folder = Path(path).parent
    by_name: dict[str, list[dict[str, str]]] = {}
    for row in rows:
        by_name.setdefault(row["name"], []).append(row)
    verified, absent = 0, []
    for name, named in by_name.items():  # two inputs may share a file name (device.h5 of two calibrations): one must match
        candidate = folder / name
        if not candidate.is_file():
            absent.append(name)
            continue
        actual = file_sha256(candidate)
        matching = [r for r in named if r["sha256"] == actual]
        if not matching:
            raise InputError(
                f"{name} ({named[0]['role']}) has SHA-256 {actual}, the certificate names {named[0]['sha256']}: it is not the file "
                "the certificate was made from",
                path=path,
                field="inputs",
            )
        verified += len(matching)
        absent += [f"{name} ({r['role']}, another file of that name)" for r in named if r["sha256"] != actual]
    out = NamedInputs(inputs=f"{verified} of {len(rows)} verified by SHA-256")
    if absent:
        out["not beside it"] = ", ".join(sorted(set(absent)))
    return out


def _png(path: str, head: bytes) -> PngSummary:
    import struct

    from stableins.errors import InputError

    if len(head) < 24 or head[12:16] != b"IHDR":
        raise InputError("a PNG without its image header", path=path, field="IHDR", expected="a complete PNG image")
    width, height = struct.unpack(">II", head[16:24])
    with open(path, "rb") as handle:
        handle.seek(-12, 2)
        if handle.read(12)[4:8] != b"IEND":
            raise InputError("the PNG has no end chunk (cut short?)", path=path, field="IEND", expected="a complete PNG image")
    return {"file": path, "kind": "plot (PNG)", "width": width, "height": height}


def _text(path: str, kind: str) -> TextSummary:
    from stableins.data.jsonio import read_input_bytes
    from stableins.errors import InputError

    data = read_input_bytes(path, max_bytes=MAX_WHOLE_FILE, what="a text file written by stableins")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise InputError(f"not UTF-8 text (byte {error.start})", path=path, expected="a file written by stableins") from None
    if "\x00" in text:
        raise InputError("binary content in a text file", path=path, expected="a file written by stableins")
    return {"file": path, "kind": kind, "lines": text.count("\n") + (not text.endswith("\n") and bool(text))}


def run(args: argparse.Namespace) -> int:
    """Run ``stableins check``: validate every file and print what each holds; exit 2 when one is not valid."""
    from stableins.output import emit

    summaries = [describe_file(path, allow_gaps=args.allow_gaps, trust=tuple(args.trust)) for path in args.files]
    lines = []
    for s in summaries:
        details = ", ".join(f"{k} {v}" for k, v in s.items() if k not in ("file", "kind", "warnings"))
        lines.append(f"{s['file']}: ok ({s['kind']}; {details})")
        lines += [f"  warning: {w}" for w in s.get("warnings", [])]
    emit(args, {"files": summaries}, "\n".join(lines))
    return 0
