"""Mutation fuzzing of every input stableins reads: shared by ``tests/test_fuzz.py`` (short, fixed seed) and
``benchmarks/bench_fuzz.py`` (thousands of cases).

A :class:`Workspace` holds one valid file of every kind (device CSV and HDF5, a system HDF5 record, a calibration
record, a procedure, a plan, a ``diagnose --json`` document).  Each case mutates one of them with an operator drawn
by hypothesis (bytes or structure), runs the command that consumes it through :func:`stableins.cli.main` in this
process, and classifies the outcome:

* **traceback**: an exception other than the CLI's own left ``main`` (a bug);
* **bad exit**: an exit status other than 0 or 2 for an input problem (e.g. 1 with raw errno text);
* **accepted bad input**: exit 0 although the mutation made the input invalid by the documented format
  (operators say whether their result must be refused; byte flips in places that may be harmless say "maybe");
* **files left**: a refused command changed its output directory (new, changed or temporary files).

Protocol replies are fuzzed against :class:`stableins.drivers.tcp.TcpDriver` through a scripted server, procedures
and plans through the loader ``stableins run`` calls before the platform moves, option values through the
command-line parser.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import math
import random
import shutil
import socket
import threading
import zlib
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

#: Values that no field of any stableins document may hold (the JSON text inserted for a value).
BAD_JSON_VALUES = (
    "[" * 200 + "]" * 200,  # nested too deep
    "9" * 5000,  # integer beyond every type
    "1e999",  # overflows a double
    "NaN",  # not JSON
    "-Infinity",
)
#: Values of the wrong type for a field that holds a number / a string.
WRONG_FOR_NUMBER = ('"12"', "true", "[1, 2]", '{"value": 1}', "null")
WRONG_FOR_TEXT = ("12", "true", "[1]", '{"a": 1}', "null")
#: Tokens that are not numbers of the CSV format (Python's float() accepts the first three).
BAD_NUMBER_TOKENS = ("1_0", "\uff11.5", "\u0661\u0662", "nan", "inf", "-inf", "abc", "", "0x10", "1e999", "1.5.2", "--1")


@dataclass
class Tally:
    """Counts over a fuzz run."""

    cases: int = 0
    tracebacks: int = 0
    bad_exits: int = 0
    accepted_bad: int = 0
    files_left: int = 0
    refused: int = 0
    accepted: int = 0
    by_kind: Counter = field(default_factory=Counter)
    examples: list[str] = field(default_factory=list)

    def add(self, kind: str, result: Result) -> None:
        self.cases += 1
        self.by_kind[kind] += 1
        self.refused += result.status == 2
        self.accepted += result.status == 0
        for name, bad in (
            ("tracebacks", result.traceback is not None),
            ("bad_exits", result.bad_exit),
            ("accepted_bad", result.accepted_bad),
            ("files_left", bool(result.left)),
        ):
            if bad:
                setattr(self, name, getattr(self, name) + 1)
                if len(self.examples) < 20:
                    self.examples.append(f"{name}: {kind}: {result.describe()}")

    @property
    def failures(self) -> int:
        return self.tracebacks + self.bad_exits + self.accepted_bad + self.files_left


@dataclass
class Result:
    what: str
    status: int | None
    must_refuse: bool | None
    traceback: str | None = None
    stderr: str = ""
    left: tuple[str, ...] = ()

    @property
    def bad_exit(self) -> bool:
        return self.traceback is None and self.status not in (0, 2)

    @property
    def accepted_bad(self) -> bool:
        return self.status == 0 and self.must_refuse is True

    def describe(self) -> str:
        detail = self.traceback or self.stderr.strip().splitlines()[-1:] or ""
        return f"{self.what} -> status {self.status}; {detail}; left {list(self.left)}"


# --------------------------------------------------------------------------- the valid files
class Workspace:
    """One valid file of every kind, built once; cases copy and mutate them."""

    def __init__(self, root: Path) -> None:
        import system_synthetic
        from device_world import ExactPlatform, device_columns, draw_truth

        from stableins.data.device import save_device
        from stableins.data.system import SystemRecordWriter
        from stableins.procedures.definition import load_procedure
        from stableins.procedures.planning import plan_from_definition

        self.root = root
        root.mkdir(parents=True, exist_ok=True)
        truth = draw_truth(np.random.default_rng(5), quadratic=False)
        procedure = load_procedure("device-coarse")
        columns = device_columns(truth, procedure, sigma=1e-3, seed=3, dwell=3.0, rate=20.0)
        metadata = ExactPlatform(truth).metadata
        self.device_csv = save_device(root / "device.csv", columns, metadata)
        self.device_h5 = save_device(root / "device.h5", columns, metadata)
        true, installed = system_synthetic.paper_residuals()
        cols, meta = system_synthetic.record(true, installed, rate=1.0, seed=4)
        self.system_h5 = root / "system.h5"
        with SystemRecordWriter(self.system_h5, meta, chunk_samples=2048) as writer:
            writer.append(cols)
        self.record = root / "record.json"
        _record(meta.serial_number).save(self.record)
        self.serial = meta.serial_number
        self.procedure = root / "procedure.toml"
        self.procedure.write_text((Path(procedure.path).parent / "device-fine.toml").read_text(encoding="utf-8"), encoding="utf-8")
        self.plan = root / "plan.json"
        self.plan.write_text(json.dumps(plan_from_definition(load_procedure("device-fine")).to_dict(), indent=1), encoding="utf-8")
        self.discovery = root / "diagnosis.json"
        self.discovery.write_text(json.dumps(_discovery_document(), indent=1), encoding="utf-8")
        self.counter = 0

    def case_directory(self) -> Path:
        self.counter += 1
        path = self.root / f"case{self.counter}"
        if path.exists():
            shutil.rmtree(path)
        path.mkdir()
        return path


def make_record(
    serial: str,
    created: str,
    values: dict[str, float],
    sigmas: dict[str, float],
    *,
    stage: str = "fine",
    procedure: str = "device-fine",
    inputs: tuple = (),
) -> Any:
    """A first calibration (no prior) of one stage run whose data end at ``created``: every parameter estimated alone."""
    from stableins.errormodel import known_terms
    from stableins.records import Calibration, CalibrationRecord, DeterminedBy, InputFile, Parameter, StageRun
    from stableins.status import Determination

    tag = hashlib.sha256(f"{serial} {created} {sorted(values.items())}".encode()).hexdigest()[:8]
    calibration = Calibration(f"cal-{created[:10]}-{tag}", procedure, "stableins test", created)
    files = tuple(InputFile(name, digest) for name, digest in inputs)
    run = StageRun(f"{stage}-{tag}", stage, calibration.id, procedure, "stableins test", created, created, created, inputs=files)
    terms = known_terms()
    parameters = tuple(
        Parameter(pid, float(v), terms[pid].si_unit, float(sigmas[pid]), "estimated", (DeterminedBy(run.id, Determination.ALONE),))
        for pid, v in values.items()
    )
    return CalibrationRecord(serial, parameters, np.diag([sigmas[pid] ** 2 for pid in values]), calibration, (run,))


def _record(serial: str) -> Any:
    from stableins.errormodel import CORE_TERMS

    values = {t.id: float(t.reference) for t in CORE_TERMS}
    sigmas = {t.id: float(t.nominal) for t in CORE_TERMS}
    return make_record(serial, "2026-03-01T09:30:00+00:00", values, sigmas, inputs=(("device.csv", "0" * 64),))


def _discovery_document() -> dict[str, Any]:
    """A complete ``diagnose --json`` document of a system record (every kind of field the reader checks)."""
    from scipy.stats import chi2

    from stableins.discovery.diagnose_report import OBSERVATION_UNIT
    from stableins.noise import NoiseModel

    noise = NoiseModel.given(4.5e-4, 2e-5, 1e-7, provenance="datasheet").to_document()
    step = {"label": "standard model", "model": ["bias_x", "sf_x"], "channels": ["f_x", "f_y", "f_z"],
            "residual_rms": [2e-5, 2e-5, 3e-5], "residual_rms_unit": "m/s^2", "noise_floor": [1e-5, 1e-5, 1e-5],
            "chi2_red": 1.1, "dof": 30, "bic": 40.5, "added": [], "shifts": {}}  # fmt: skip
    added = dict(step, label="+ K3_x", model=["bias_x", "sf_x", "K3_x"],
                 added=[{"id": "K3_x", "estimate": 1.0, "sigma": 2.0, "unit": "ug/g^3"}],
                 shifts={"sf_x": {"shift": 0.5, "unit": "ppm", "in_sigma": 0.1}})  # fmt: skip
    candidate = {"id": "Kcc_xxy", "statistic": 0.5, "p_value": 0.5, "delta_bic": 2.5,
                 "predicted": {"estimate": 1.5, "sigma": 2.0, "unit": "ug/g^2", "max_output_change": 1e-6,
                               "max_output_change_unit": OBSERVATION_UNIT},
                 "identifiable": True, "excited": True, "separability": 0.4, "aliases": [{"id": "bias_x", "shift_per_unit": 0.3}],
                 "confused_with": ["Kcc_xxz"], "refit": False, "flagged": False, "chi2_red_with": 1.12, "explains": True,
                 "leaves": [], "signature_p": None, "advice": "confirm with 45° positions"}  # fmt: skip
    spectrum = {"harmonics": [1, 2], "amplitude": [1e-6, 2e-6], "sigma": [1e-6, 1e-6], "chi2": [1.0, 4.0], "dof": [2.0, 2.0],
                "p_value": [0.6, 0.14], "flagged": [False, False], "unit": "m/s^2"}  # fmt: skip
    return {
        "stage": "system", "noise_model": noise, "chi2_red": 1.1, "chi2_red_range": [1.05, 1.2], "dof": 30, "expected_spread": 0.26,
        "p_value": 0.3, "p_value_range": [float(chi2.sf(31.5, 30)), float(chi2.sf(36.0, 30))], "consistent": True, "alarm": False,
        "bin_seconds": 60.0, "verdict": "consistent", "outside_library": False, "signature": None, "model": ["bias_x", "sf_x", "K3_x"],
        "residual_rms": [2e-5, 2e-5, 3e-5], "noise_floor": [1e-5, 1e-5, 1e-5], "candidates": [candidate, dict(candidate, id="K3_y")],
        "history": [step, added], "left_out": [], "next": ["next: nothing is flagged", "  stableins report cal.json"], "drift": None,
        "notes": ["bins of 60 s"], "spectra": {"f_x": spectrum, "f_y": spectrum},
    }  # fmt: skip


# --------------------------------------------------------------------------- running a command
def _snapshot(directory: Path | None) -> dict[str, str]:
    if directory is None or not directory.exists():
        return {}
    out = {}
    for path in sorted(directory.rglob("*")):
        if path.is_file():
            out[str(path.relative_to(directory))] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def run_cli(argv: list[str], what: str, must_refuse: bool | None, watch: Path | None = None) -> Result:
    """``stableins ARGV`` in this process; the outcome, with what changed in ``watch`` when the command failed."""
    from stableins import cli

    before = _snapshot(watch)
    out, err = io.StringIO(), io.StringIO()
    trace = None
    status: int | None = None
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            status = cli.main(argv)
    except BaseException as error:  # noqa: BLE001 - anything escaping main is what this counts
        trace = f"{type(error).__name__}: {str(error)[:200]}"
    if "Traceback (most recent call last)" in err.getvalue():
        trace = trace or err.getvalue().strip().splitlines()[-1][:200]
    left: tuple[str, ...] = ()
    if status != 0 and watch is not None:
        after = _snapshot(watch)
        left = tuple(sorted(k for k in after if before.get(k) != after[k]))
    return Result(what, status, must_refuse, trace, err.getvalue(), left)


def run_call(call: Any, what: str, must_refuse: bool | None, expected: tuple[type[BaseException], ...]) -> Result:
    """A library call that must either succeed (status 0) or raise one of ``expected`` (status 2)."""
    try:
        call()
    except expected as error:
        return Result(what, 2, must_refuse, stderr=str(error))
    except BaseException as error:  # noqa: BLE001
        return Result(what, None, must_refuse, traceback=f"{type(error).__name__}: {str(error)[:200]}")
    return Result(what, 0, must_refuse)


# --------------------------------------------------------------------------- JSON mutations
def _paths(tree: Any, prefix: tuple = ()) -> list[tuple[tuple, Any]]:
    out = [(prefix, tree)]
    if isinstance(tree, dict):
        for k, v in tree.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            out += _paths(v, prefix + (i,))
    return out


_MARK = "\u0000MARK\u0000"


def _replace(tree: Any, path: tuple, value: Any) -> Any:
    if not path:
        return value
    tree = json.loads(json.dumps(tree))
    node = tree
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return tree


@dataclass(frozen=True)
class _JsonSite:
    """A JSON document to mutate and the node drawn for the mutation."""

    text: str
    tree: Any
    nodes: list
    path: tuple
    value: Any
    free: bool

    @property
    def where(self) -> str:
        return "/".join(map(str, self.path))


def mutate_json(text: str, rng: random.Random, op: str, free_paths: tuple[tuple, ...] = ()) -> tuple[bytes, str, bool | None]:
    """One mutation of a JSON document: (new bytes, what was done, must it be refused?).

    ``free_paths``: prefixes under which any value is allowed (e.g. a metadata ``extra`` object): there only the
    loader's own limits make a document invalid.
    """
    tree = json.loads(text)
    nodes = _paths(tree)[1:]
    path, value = rng.choice(nodes)
    free = any(path[: len(p)] == p for p in free_paths)
    if op not in _JSON_MUTATIONS:
        raise ValueError(op)
    return _JSON_MUTATIONS[op](_JsonSite(text, tree, nodes, path, value, free), rng)


def _json_bad_value(site: _JsonSite, rng: random.Random) -> tuple[bytes, str, bool | None]:
    """The loader's limits: always refused."""
    token = rng.choice(BAD_JSON_VALUES)
    marked = json.dumps(_replace(site.tree, site.path, _MARK))
    return marked.replace(json.dumps(_MARK), token).encode(), f"{site.where} = {token[:20]}", True


def _json_wrong_type(site: _JsonSite, rng: random.Random) -> tuple[bytes, str, bool | None]:
    value = site.value
    must: bool | None
    if isinstance(value, bool) or value is None or site.free or isinstance(value, dict | list):
        token = rng.choice(WRONG_FOR_NUMBER)
        must = None
    elif isinstance(value, int | float):
        token = rng.choice(WRONG_FOR_NUMBER[:4])
        must = True
    else:
        token = rng.choice(WRONG_FOR_TEXT[:4])
        must = True
    marked = json.dumps(_replace(site.tree, site.path, _MARK))
    return marked.replace(json.dumps(_MARK), token).encode(), f"{site.where} = {token[:20]}", must


def _json_delete_key(site: _JsonSite, rng: random.Random) -> tuple[bytes, str, bool | None]:
    parent_path, key = site.path[:-1], site.path[-1]
    if not isinstance(key, str):
        return json.dumps(site.tree).encode(), "no-op", False
    mutated = json.loads(json.dumps(site.tree))
    node = mutated
    for k in parent_path:
        node = node[k]
    del node[key]
    return json.dumps(mutated).encode(), f"deleted {site.where}", None


def _json_duplicate_key(site: _JsonSite, rng: random.Random) -> tuple[bytes, str, bool | None]:
    raw = json.dumps(site.tree)
    keys = [k for p, _ in _paths(site.tree) for k in p[-1:] if isinstance(k, str)]
    key = rng.choice(keys) if keys else "format"
    needle = json.dumps(key) + ": "
    at = raw.find(needle)
    if at < 0:
        return raw.encode(), "no-op", False
    end = raw.find(",", at)
    if end < 0:
        return raw.encode(), "no-op", False
    return (raw[:end] + ", " + raw[at:end] + raw[end:]).encode(), f"key {key} twice", True


def _json_truncate(site: _JsonSite, rng: random.Random) -> tuple[bytes, str, bool | None]:
    data = site.text.encode()
    cut = rng.randrange(1, len(data))
    piece = data[:cut]
    try:
        json.loads(piece)
        must: bool | None = None
    except ValueError:
        must = True
    return piece, f"cut at byte {cut}", must


def _json_bytes(site: _JsonSite, rng: random.Random) -> tuple[bytes, str, bool | None]:
    data = bytearray(site.text.encode())
    for _ in range(rng.randint(1, 4)):
        data[rng.randrange(len(data))] = rng.randrange(256)
    return bytes(data), "byte flips", None


def _json_non_utf8(site: _JsonSite, rng: random.Random) -> tuple[bytes, str, bool | None]:
    data = bytearray(site.text.encode())
    at = rng.randrange(len(data))
    data[at:at] = b"\xff\xfe"
    return bytes(data), f"bytes ff fe at {at}", True


def _json_bom(site: _JsonSite, rng: random.Random) -> tuple[bytes, str, bool | None]:
    return b"\xef\xbb\xbf" + site.text.encode(), "UTF-8 byte-order mark", False


def _json_numbers(site: _JsonSite, rng: random.Random) -> tuple[bytes, str, bool | None]:
    """A number field to another number: negative, zero, huge."""
    numeric = [(p, v) for p, v in site.nodes if isinstance(v, int | float) and not isinstance(v, bool)]
    if not numeric:
        return site.text.encode(), "no-op", False
    path, value = rng.choice(numeric)
    new = rng.choice([0, -1, -1e308, 1e308, 1e-320, 2**62, value * -1])
    return json.dumps(_replace(site.tree, path, new)).encode(), f"{'/'.join(map(str, path))} = {new!r}", None


_JSON_MUTATIONS: dict[str, Callable[[_JsonSite, random.Random], tuple[bytes, str, bool | None]]] = {
    "bad_value": _json_bad_value,
    "wrong_type": _json_wrong_type,
    "delete_key": _json_delete_key,
    "duplicate_key": _json_duplicate_key,
    "truncate": _json_truncate,
    "bytes": _json_bytes,
    "non_utf8": _json_non_utf8,
    "bom": _json_bom,
    "numbers": _json_numbers,
}


JSON_OPS = ("bad_value", "wrong_type", "delete_key", "duplicate_key", "truncate", "bytes", "non_utf8", "bom", "numbers")


# --------------------------------------------------------------------------- CSV mutations
def mutate_csv(text: str, rng: random.Random, op: str) -> tuple[bytes, str, bool | None]:
    lines = text.splitlines(keepends=True)
    header_end = next(k for k, line in enumerate(lines) if not line.startswith("#"))
    data_rows = [k for k in range(header_end + 1, len(lines)) if not lines[k].startswith("#")]
    columns = lines[header_end].rstrip("\n").split(",")
    if op in ("bad_number", "non_integer"):
        return _csv_field(lines, rng, op, data_rows, columns)
    if op in ("delete_row", "duplicate_row"):
        k = rng.choice(data_rows)
        if op == "delete_row":
            del lines[k]
            return "".join(lines).encode(), f"deleted line {k + 1}", True
        lines.insert(k, lines[k])
        return "".join(lines).encode(), f"line {k + 1} twice", True
    if op in ("truncate", "bom", "bytes"):
        return _csv_bytes("".join(lines).encode(), rng, op)
    if op == "long_line":
        k = rng.choice(data_rows)
        extra = rng.choice([10, 70000, 2_000_000])
        lines[k] = lines[k].rstrip("\n") + "1" * extra + "\n"  # more digits of the last number: too long only beyond MAX_LINE
        return "".join(lines).encode(), f"line {k + 1} made {len(lines[k])} characters long", len(lines[k]) > (1 << 20)
    if op == "header":
        return _csv_header(lines, rng)
    if op == "empty":
        return "".join(lines[: header_end + 1]).encode() + b"# END OF DATA: 0 rows\n", "no data rows", True
    raise ValueError(op)


def _csv_bytes(data: bytes, rng: random.Random, op: str) -> tuple[bytes, str, bool | None]:
    """A byte-level mutation of a CSV file: cut short, a byte-order mark, or flipped bytes."""
    if op == "truncate":
        cut = rng.randrange(len(data) // 4, len(data) - 2)
        return data[:cut], f"cut at byte {cut}", True
    if op == "bom":
        return b"\xef\xbb\xbf" + data, "byte-order mark", False
    flipped = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        flipped[rng.randrange(len(flipped))] = rng.randrange(256)
    return bytes(flipped), "byte flips", None


def _csv_field(lines: list[str], rng: random.Random, op: str, data_rows: list[int], columns: list[str]) -> tuple[bytes, str, bool | None]:
    """A bad number in a numeric field, or a non-integer pass or position, of one data row."""
    k = rng.choice(data_rows)
    fields = lines[k].rstrip("\n").split(",")
    if op == "bad_number":
        numeric = [j for j, name in enumerate(columns) if not name.startswith("stage")]
        j = rng.choice(numeric)
        token = rng.choice(BAD_NUMBER_TOKENS)
        fields[j] = token
        lines[k] = ",".join(fields) + "\n"
        return "".join(lines).encode(), f"row line {k + 1} {columns[j]} = {token!r}", True
    j = columns.index(rng.choice(["pass", "position"]))
    fields[j] = rng.choice(["1.5", "-3", "0", "1e300", "2147483648"])
    lines[k] = ",".join(fields) + "\n"
    return "".join(lines).encode(), f"line {k + 1} {columns[j]} = {fields[j]}", True


def _csv_header(lines: list[str], rng: random.Random) -> tuple[bytes, str, bool | None]:
    """A mutation of the JSON header of a CSV file (:func:`mutate_json`)."""
    start = next(k for k, line in enumerate(lines) if line.strip() == "# BEGIN HEADER")
    stop = next(k for k, line in enumerate(lines) if line.strip() == "# END HEADER")
    document = "".join(line[1:] for line in lines[start + 1 : stop])
    sub_op = rng.choice(("bad_value", "wrong_type", "delete_key", "duplicate_key", "numbers"))
    mutated, what, must = mutate_json(document, rng, sub_op, free_paths=(("metadata", "extra"),))
    try:
        body = mutated.decode()
    except UnicodeDecodeError:
        return "".join(lines).encode(), "no-op", False
    lines[start + 1 : stop] = ["# " + body + "\n"]
    return "".join(lines).encode(), f"header {what}", must


CSV_OPS = ("bad_number", "non_integer", "delete_row", "duplicate_row", "truncate", "long_line", "header", "bom", "bytes", "empty")


# --------------------------------------------------------------------------- HDF5 mutations
def mutate_h5(path: Path, rng: random.Random, op: str, kind: str) -> tuple[str, bool | None]:
    """Mutate the HDF5 file at ``path`` in place; (what, must refuse)."""
    import h5py

    if op == "truncate":
        size = path.stat().st_size
        cut = rng.randrange(size // 8, size - 1)
        with open(path, "r+b") as handle:
            handle.truncate(cut)
        return f"cut at byte {cut} of {size}", True
    if op == "bytes":
        data = bytearray(path.read_bytes())
        for _ in range(rng.randint(1, 8)):
            data[rng.randrange(len(data))] = rng.randrange(256)
        path.write_bytes(bytes(data))
        return "byte flips", None
    with h5py.File(path, "r+") as f:
        if op in ("header", "rows", "incomplete", "sparse"):
            return _h5_attributes(f, rng, op)
        return _h5_columns(f, rng, op, kind)


def _h5_attributes(f: Any, rng: random.Random, op: str) -> tuple[str, bool | None]:
    """A mutation of the attributes of an open HDF5 data file."""
    if op == "header":
        sub_op = rng.choice(("bad_value", "wrong_type", "delete_key", "duplicate_key", "truncate", "numbers"))
        mutated, what, must = mutate_json(f.attrs["header"], rng, sub_op, free_paths=(("metadata", "extra"),))
        try:
            f.attrs["header"] = mutated.decode()
        except UnicodeDecodeError:
            f.attrs["header"] = np.void(mutated)
            must = True
        return f"header {what}", must
    if op == "rows":
        value = rng.choice([10**9, -1, f.attrs["rows"] + 1, "12", 1.5])
        f.attrs["rows"] = value
        return f"rows = {value!r}", True
    if op == "incomplete":
        f.attrs["complete"] = False
        return "complete = false", True
    # sparse: declare millions of rows without storing them
    for name in f["columns"]:
        f["columns"][name].resize((300_000_000,))
    f.attrs["rows"] = 300_000_000
    return "300 M rows declared", True


def _h5_columns(f: Any, rng: random.Random, op: str, kind: str) -> tuple[str, bool | None]:
    """A mutation of the columns (or the time grid) of an open HDF5 data file."""
    if op == "float_position" and kind == "device":
        old = f["columns/position"][()]
        del f["columns/position"]
        values = old.astype(float)
        values[rng.randrange(values.size)] = 1.5
        d = f["columns"].create_dataset("position", data=values)
        d.attrs["meaning"] = "position"
        return "position stored as float with 1.5", True
    if op == "nan":
        names = [n for n in f["columns"] if f["columns"][n].dtype.kind == "f"]
        name = rng.choice(names)
        d = f["columns"][name]
        d[rng.randrange(d.shape[0])] = np.nan
        return f"NaN in {name}", True
    if op == "time_back":
        d = f["columns/time"]
        k = rng.randrange(1, d.shape[0])
        d[k] = d[k - 1] - 0.5
        return f"time runs back at row {k + 1}", True
    if op == "unit":
        names = [n for n in f["columns"] if "unit" in f["columns"][n].attrs]
        name = rng.choice(names)
        f["columns"][name].attrs["unit"] = rng.choice(["g", "deg", "", "m/s^2 "])
        return f"unit of {name} changed", True
    if op == "grid" and "time_grid" in f:
        grid = f["time_grid"]
        values = grid[()]
        column, value = rng.choice([(1, 1e300), (1, -5.0), (1, 7.0), (2, -5.0), (2, 1e-12), (2, 7.0), (2, 1e300), (2, 0.0)])
        values[0, column] = value
        grid[...] = values
        return "garbage /time_grid", True
    if op == "drop_dataset":
        names = list(f["columns"])
        name = rng.choice(names)
        del f["columns"][name]
        return f"column {name} removed", True
    return "no-op", False


H5_OPS = (
    "truncate",
    "bytes",
    "header",
    "rows",
    "incomplete",
    "sparse",
    "float_position",
    "nan",
    "time_back",
    "unit",
    "grid",
    "drop_dataset",
)


# --------------------------------------------------------------------------- TOML mutations
_TOML_BAD = ('"ten"', "-5.0", "0.5", "nan", "inf", "1e300", "[1, 2]", "true", "0")


def mutate_toml(text: str, rng: random.Random, op: str) -> tuple[bytes, str, bool | None]:
    lines = text.splitlines(keepends=True)
    assignments = [k for k, line in enumerate(lines) if "=" in line and not line.lstrip().startswith("#")]
    if op == "value":
        k = rng.choice(assignments)
        key = lines[k].split("=", 1)[0]
        token = rng.choice(_TOML_BAD)
        lines[k] = f"{key}= {token}\n"
        return "".join(lines).encode(), f"line {k + 1}: {key.strip()} = {token}", None
    if op == "non_utf8":
        data = bytearray("".join(lines).encode())
        at = rng.randrange(len(data))
        data[at:at] = b"\xff"
        return bytes(data), f"byte ff at {at}", True
    if op == "delete":
        k = rng.choice(assignments)
        del lines[k]
        return "".join(lines).encode(), f"deleted line {k + 1}", None
    if op == "truncate":
        data = "".join(lines).encode()
        cut = rng.randrange(1, len(data))
        return data[:cut], f"cut at byte {cut}", None
    if op == "person_default":
        lines.append('\n[[person]]\nbefore = 1\naction = "enter"\nprompt = "Lab temperature"\nkey = "t"\nunit = "degC"\n')
        default = rng.choice(["5", "45", "nan", '"warm"'])
        lines.append(f"minimum = 10\nmaximum = 30\ndefault = {default}\n")
        return "".join(lines).encode(), "person default out of range", True
    if op == "noise_blocks":
        text2 = "".join(lines).replace("noise_blocks = 10", f"noise_blocks = {rng.choice(['0.5', '1', '2.5', '-3'])}")
        return text2.encode(), "noise_blocks not a whole number of at least 2", True
    if op == "tolerances":
        rule = rng.choice(['"lenient"', "3"])
        lines.append(f"\n[tolerances]\ndecision_rule = {rule}\n")
        return "".join(lines).encode(), "bad [tolerances]", True
    if op == "chunk":
        lines.append(f"\n[runner]\nchunk = {rng.choice(['1e-300', '0', '-1', '1e9'])}\n")
        return "".join(lines).encode(), "runner chunk out of range", True
    if op == "duplicate_position":
        text2 = "".join(lines).replace("position = 5\n", "position = 4\n", 1)
        return text2.encode(), "position 4 twice", True
    raise ValueError(op)


TOML_OPS = ("value", "non_utf8", "delete", "truncate", "person_default", "noise_blocks", "tolerances", "chunk", "duplicate_position")


# --------------------------------------------------------------------------- cases
def _write(directory: Path, name: str, data: bytes) -> Path:
    path = directory / name
    path.write_bytes(data)
    return path


def case_device_csv(ws: Workspace, rng: random.Random, op: str, consumer: str = "check") -> Result:
    directory = ws.case_directory()
    data, what, must = mutate_csv(ws.device_csv.read_text(encoding="utf-8"), rng, op)
    path = _write(directory, "device.csv", data)
    if consumer == "calibrate":
        out = directory / "out"
        out.mkdir()
        return run_cli(["calibrate", "device", str(path), "--out", str(out / "cal.json")], f"device csv {what}", must, out)
    return run_cli(["check", str(path)], f"device csv {what}", must)


def case_h5(ws: Workspace, rng: random.Random, op: str, kind: str) -> Result:
    directory = ws.case_directory()
    source = ws.device_h5 if kind == "device" else ws.system_h5
    path = directory / source.name
    shutil.copyfile(source, path)
    what, must = mutate_h5(path, rng, op, kind)
    if kind == "device" and op == "grid":
        must = False
    return run_cli(["check", str(path)], f"{kind} h5 {what}", must)


def case_record(ws: Workspace, rng: random.Random, op: str, consumer: str) -> Result:
    directory = ws.case_directory()
    data, what, must = mutate_json(ws.record.read_text(encoding="utf-8"), rng, op, free_paths=(("site", "extra"),))
    path = _write(directory, "record.json", data)
    if consumer == "history":
        store = directory / "store"
        store.mkdir()
        return run_cli(["history", ws.serial, "--store", str(store), "--add", str(path)], f"record {what}", must, store)
    if consumer == "prior":
        out = directory / "out"
        out.mkdir()
        argv = ["calibrate", "system", str(ws.system_h5), "--prior", str(path), "--out", str(out / "cal.json")]
        return run_cli(argv, f"prior record {what}", must, out)
    return run_cli(["check", str(path)], f"record {what}", must)


def case_plan(ws: Workspace, rng: random.Random, op: str) -> Result:
    from stableins.commands.run import load_plan
    from stableins.errors import InputError

    directory = ws.case_directory()
    data, what, must = mutate_json(ws.plan.read_text(encoding="utf-8"), rng, op)
    path = _write(directory, "plan.json", data)
    return run_call(lambda: load_plan(str(path), None, None), f"plan {what}", must, (InputError,))


def case_procedure(ws: Workspace, rng: random.Random, op: str) -> Result:
    from stableins.commands.run import load_plan
    from stableins.errors import InputError

    directory = ws.case_directory()
    data, what, must = mutate_toml(ws.procedure.read_text(encoding="utf-8"), rng, op)
    path = _write(directory, "procedure.toml", data)
    return run_call(lambda: load_plan(str(path), None, None), f"procedure {what}", must, (InputError,))


def case_discovery(ws: Workspace, rng: random.Random, op: str) -> Result:
    from stableins.errors import InputError
    from stableins.reporting.builder import read_discovery

    directory = ws.case_directory()
    data, what, must = mutate_json(ws.discovery.read_text(encoding="utf-8"), rng, op)
    path = _write(directory, "diagnosis.json", data)
    if must is None and op == "wrong_type":
        must = None
    return run_call(lambda: read_discovery(path), f"discovery {what}", must, (InputError,))


# --------------------------------------------------------------------------- option values
#: (argv before the option, option, lowest, highest, whole numbers only, lowest excluded, 0 allowed as well)
OPTIONS = (
    (["history", "SN"], "--max-age", 0.0, 36525.0, False, False, False),
    (["calibrate", "system", "r.h5", "--prior", "p.json", "--out", "o.json"], "--case-rotation-period", 60.0, 3600.0, False, False, True),
    (["calibrate", "system", "r.h5", "--prior", "p.json", "--out", "o.json"], "--chunk-rows", 1024, 1 << 26, True, False, False),
    (["calibrate", "device", "d.csv", "--out", "o.json"], "--bias-instability", 0.0, 1e5, False, False, False),
    (["calibrate", "device", "d.csv", "--out", "o.json"], "--random-walk", 0.0, 1.0, False, False, False),
    (["run", "device-fine", "--driver", "sim"], "--timeout", 0.1, 3600.0, False, False, False),
    (["run", "device-fine", "--driver", "sim"], "--chunk", 0.1, 3600.0, False, False, False),
    (["run", "device-fine", "--driver", "sim"], "--retries", 0, 100, True, False, False),
    (["run", "device-fine", "--driver", "sim"], "--link-failures", 1, 100, True, False, False),
    (["run", "device-fine", "--driver", "sim"], "--seed", 0, 2**63 - 1, True, False, False),
    (["diagnose", "d.csv", "--record", "r.json"], "--bin", 1.0, 86400.0, False, False, False),
    (["diagnose", "d.csv", "--record", "r.json"], "--alpha", 0.0, 0.5, False, True, False),
    (["diagnose", "d.csv", "--record", "r.json"], "--top", 1, 10000, True, False, False),
    (["simulate", "device"], "--dwell", 0.0, 86400.0, False, True, False),
    (["simulate", "device"], "--settle", 0.0, 86400.0, False, False, False),
    (["simulate", "device"], "--rate", 0.0, 10000.0, False, True, False),
    (["serve-sim", "--port", "0"], "--realtime", 0.0, 1000.0, False, False, False),
    (["serve-sim"], "--port", 0, 65535, True, False, False),
    (["demo"], "--rate", 0.0, 10000.0, False, True, False),
    (["calibrate", "system", "r.h5", "--prior", "p.json", "--out", "o.json"], "--gyro-drift", -100.0, 100.0, False, False, False),
)
#: Values to try (besides random numbers): not numbers, not finite, out of every range, Python-only spellings.
TRICKY_OPTION_VALUES = ("nan", "inf", "-inf", "1e400", "-1", "1e-300", "1e20", "abc", "", "0x10", "1_0", "\uff15", "0", "1", "2.5", "-0")


def option_accepts(index: int, text: str) -> bool:
    """Whether the documented range of option ``index`` contains ``text`` (the oracle of :func:`case_option`)."""
    _, _, low, high, whole, above, or_zero = OPTIONS[index]
    try:
        if whole:
            stripped = text.strip()
            digits = stripped[1:] if stripped[:1] in "+-" else stripped
            if not (digits.isascii() and digits.isdigit()):
                return False
            value: float = int(stripped)
        else:
            if "_" in text or not text.strip().isascii():
                return False
            value = float(text)
    except ValueError:
        return False
    if not math.isfinite(value):
        return False
    if or_zero and value == 0:
        return True
    return (value > low if above else value >= low) and value <= high


def case_option(index: int, value: str) -> Result:
    """Parse ``stableins ... OPTION VALUE``: accepted exactly when the value lies in the option's documented range."""
    from stableins import cli

    argv, option = OPTIONS[index][:2]
    tokens = [*argv, option, value] + (["0", "0"] if option == "--gyro-drift" else [])
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            cli.build_parser(tokens).parse_args(tokens)
        status = 0
    except SystemExit as exit_:
        status = int(exit_.code or 0)
    except BaseException as error:  # noqa: BLE001
        return Result(f"{option} {value!r}", None, True, traceback=f"{type(error).__name__}: {error}")
    accepts = option_accepts(index, value)
    result = Result(f"{option} {value!r}", status, not accepts, stderr=err.getvalue())
    if accepts and status != 0:  # a valid value refused: the range documented is not the one checked
        result.traceback = f"valid value refused: {err.getvalue().strip()[-160:]}"
    return result


# --------------------------------------------------------------------------- protocol replies
class ScriptedPlatform:
    """A TCP server answering the driver's requests with replies a test chooses (one connection at a time)."""

    def __init__(self, reply: Any) -> None:
        self.reply = reply
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        self.listener.settimeout(0.2)
        while not self._stop.is_set():
            try:
                connection, _ = self.listener.accept()
            except OSError:
                continue
            with connection:
                connection.settimeout(5)
                try:
                    connection.sendall(b"STABLEINS-PLATFORM 1\n")
                    buffer = b""
                    while not self._stop.is_set():
                        chunk = connection.recv(4096)
                        if not chunk:
                            break
                        buffer += chunk
                        while b"\n" in buffer:
                            line, _, buffer = buffer.partition(b"\n")
                            words = line.decode().split()
                            connection.sendall(self.reply(words[0], words[1], words[2:]))
                except OSError:
                    pass

    def close(self) -> None:
        self._stop.set()
        self.listener.close()
        self.thread.join(timeout=5)


def _meta_payload() -> str:
    from stableins.site import SiteMetadata

    metadata = SiteMetadata("NET-1", math.radians(34.0), 400.0, 9.7966, "test", 10.0, (1, -1, -1, 1))
    return json.dumps(metadata.to_dict())


def _acq_lines(request: str, count: int) -> list[str]:
    return [f"S {0.1 * k!r} 0.001 -9.8 0.002 0.0 1.5 0.0 25.0\n" for k in range(1, count + 1)]


def _valid_meta(key: str, value: Any) -> bool:
    """Whether SiteMetadata accepts ``value`` for ``key`` in a META reply (SI, docs/formats.md ranges)."""
    number = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    check = _META_CHECKS.get(key)
    return check is not None and check(value, number)


def _numbers(values: Any) -> bool:
    return all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)


#: What SiteMetadata accepts for each key of a META reply: ``check(value, value is a finite number)``.
_META_CHECKS: dict[str, Callable[[Any, bool], bool]] = {
    "serial_number": lambda value, number: isinstance(value, str) and bool(value),
    "gravity_source": lambda value, number: isinstance(value, str),
    "latitude": lambda value, number: number and abs(value) <= math.pi / 2,
    "height": lambda value, number: number,
    "reference_temperature": lambda value, number: number,
    "gravity": lambda value, number: number and 9.7 < value < 9.9,
    "sample_rate": lambda value, number: number and value > 0,
    "gimbal_senses": lambda value, number: (
        isinstance(value, list) and len(value) == 4 and all(v in (1, -1) and not isinstance(v, bool) for v in value)
    ),
    "base_attitude": lambda value, number: isinstance(value, list) and len(value) == 3 and _numbers(value),
    "damping": lambda value, number: isinstance(value, dict) and _numbers(value.values()),
    "extra": lambda value, number: isinstance(value, dict),
}

Reply = Callable[[str, str, list[str]], bytes]


def _crc(lines: list[str]) -> str:
    value = 0
    for line in lines:
        value = zlib.crc32(line.encode(), value)
    return f"{value:08x}"


def _good_reply(meta: str) -> Reply:
    """The replies of a healthy platform."""

    def good(request: str, verb: str, arguments: list[str]) -> bytes:
        if verb == "META":
            return f"{request} OK {meta}\n".encode()
        if verb == "CMD":
            return f"{request} OK 1.0\n".encode()
        if verb == "ANG":
            return f"{request} OK 0.0 1.5 0.0\n".encode()
        if verb == "ACQ":
            lines = _acq_lines(request, 10)
            return f"{request} OK 10\n{''.join(lines)}{request} END 10 {_crc(lines)}\n".encode()
        return f"{request} OK\n".encode()

    return good


def _acq_reply(good: Reply, acquire: Callable[[str], bytes]) -> Reply:
    """The healthy replies, with ``acquire(request)`` answering ACQ."""

    def reply(request: str, verb: str, arguments: list[str]) -> bytes:
        return acquire(request) if verb == "ACQ" else good(request, verb, arguments)

    return reply


def _fault_meta(rng: random.Random, good: Reply, meta: str) -> tuple[Reply, str, bool]:
    document = json.loads(meta)
    key = rng.choice(list(document))
    value = rng.choice(["x", "", -1e300, None, [1, 2], {"a": 1}, 1e6, [1, -1, 1, 1], 0.5])
    document[key] = value
    text = json.dumps(document)
    cut = rng.random() < 0.3
    if cut:
        text = text.replace("}", "", 1)

    def reply(request: str, verb: str, arguments: list[str]) -> bytes:
        return f"{request} OK {text}\n".encode() if verb == "META" else good(request, verb, arguments)

    return reply, f"META {key} = {value!r}{' (cut)' if cut else ''}", cut or not _valid_meta(key, value)


def _fault_count(rng: random.Random, good: Reply, meta: str) -> tuple[Reply, str, bool]:
    count = rng.choice(["1000000000000", "-5", "1.5", "1e3", "abc", "", "10 10", "99999999999999999999"])
    return _acq_reply(good, lambda request: f"{request} OK {count}\n".encode()), f"ACQ count {count!r}", True


def _fault_sample(rng: random.Random, good: Reply, meta: str) -> tuple[Reply, str, bool]:
    token = rng.choice(BAD_NUMBER_TOKENS)

    def acquire(request: str) -> bytes:
        lines = _acq_lines(request, 10)
        k = rng.randrange(10)
        fields = lines[k].split(" ")
        fields[rng.randrange(1, 9)] = token
        lines[k] = " ".join(fields).rstrip("\n") + "\n"
        return f"{request} OK 10\n{''.join(lines)}{request} END 10 {_crc(lines)}\n".encode()

    return _acq_reply(good, acquire), f"sample value {token!r}", True


def _fault_backwards(rng: random.Random, good: Reply, meta: str) -> tuple[Reply, str, bool]:
    def acquire(request: str) -> bytes:
        lines = _acq_lines(request, 10)
        lines[5], lines[6] = lines[6], lines[5]
        return f"{request} OK 10\n{''.join(lines)}{request} END 10 {_crc(lines)}\n".encode()

    return _acq_reply(good, acquire), "sample times run back", True


def _fault_trailer(rng: random.Random, good: Reply, meta: str) -> tuple[Reply, str, bool]:
    def acquire(request: str) -> bytes:
        lines = _acq_lines(request, 10)
        return f"{request} OK 10\n{''.join(lines)}{request} END 9 {_crc(lines)}\n".encode()

    return _acq_reply(good, acquire), "END count wrong", True


def _fault_garbage(rng: random.Random, good: Reply, meta: str) -> tuple[Reply, str, bool]:
    junk = bytes(rng.randrange(256) for _ in range(rng.randint(1, 60)))

    def reply(request: str, verb: str, arguments: list[str]) -> bytes:
        return junk + b"\n" if verb in ("CMD", "ACQ") else good(request, verb, arguments)

    return reply, f"garbage {junk[:12]!r}", True


_PROTOCOL_FAULTS: dict[str, Callable[[random.Random, Reply, str], tuple[Reply, str, bool]]] = {
    "meta": _fault_meta,
    "count": _fault_count,
    "sample": _fault_sample,
    "backwards": _fault_backwards,
    "trailer": _fault_trailer,
    "garbage": _fault_garbage,
}


def protocol_reply(rng: random.Random, op: str) -> tuple[Any, str, bool]:
    """A server reply function with one fault of kind ``op``; (reply, what, is the fault one the driver must refuse)."""
    meta = _meta_payload()
    if op not in _PROTOCOL_FAULTS:
        raise ValueError(op)
    return _PROTOCOL_FAULTS[op](rng, _good_reply(meta), meta)


PROTOCOL_OPS = ("meta", "count", "sample", "backwards", "trailer", "garbage")


def case_protocol(rng: random.Random, op: str) -> Result:
    """One faulty reply to a TcpDriver session (META, CMD, ACQ): it must end in a DriverError, nothing else."""
    from stableins.drivers.errors import DriverError
    from stableins.drivers.tcp import TcpDriver

    reply, what, must = protocol_reply(rng, op)
    server = ScriptedPlatform(reply)
    try:

        def session() -> None:
            driver = TcpDriver("127.0.0.1", server.port, timeout=1.0, reconnect_attempts=1, reconnect_delay=0.01)
            try:
                driver.metadata  # noqa: B018
                driver.command((0.0, 1.5, 0.0))
                driver.acquire(1.0)
            finally:
                driver._drop()

        return run_call(session, f"protocol {what}", must, (DriverError,))
    finally:
        server.close()


__all__ = [
    "CSV_OPS",
    "H5_OPS",
    "JSON_OPS",
    "OPTIONS",
    "TRICKY_OPTION_VALUES",
    "PROTOCOL_OPS",
    "TOML_OPS",
    "Result",
    "Tally",
    "Workspace",
    "case_device_csv",
    "case_discovery",
    "case_h5",
    "case_option",
    "case_plan",
    "case_procedure",
    "case_protocol",
    "case_record",
]
