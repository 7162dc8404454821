"""One truth per unit (issue 12): the acceptance figures, printed with what they are compared against.

Runs, as a user would (through ``stableins.cli``), in a temporary directory:

1. the demo's three stages (simulate device → calibrate device → simulate one sidereal day at 10 Hz with the
   INS compensating by the device calibration → calibrate system): every parameter's σ before (the device
   record, the prior) and after the system stage, and how the stage saw it.  Compared against: posterior
   σ ≤ prior σ for every parameter;
2. the same system stage on records of 6, 9, 12 and 24 h: the exit status, whether a record was written, and how
   many of the seven separable combinations each determines.  Compared against: a 6-h record writes no
   record and exits 2 with the reason;
3. field recalibration on the simulated platform (run device-coarse, file, recal field-recal-device): the
   records in the run directory, the record in force, values on the certificate against the record, and the
   change flags of ``recal``, ``history`` and the certificate.  Compared against: exactly one new record, in
   force, its certificate shows its values, the three agree;
4. ``diagnose``: χ²_ν of its text against its ``--json``.  Compared against: the same number.

Usage::

    python benchmarks/bench_truth.py [--seed 2018] [--keep DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import subprocess
import tempfile
from pathlib import Path


def cli(*argv: str) -> tuple[int, str, str]:
    from stableins import cli as entry

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = entry.main(list(argv))
    return status, out.getvalue(), err.getvalue()


def must(*argv: str) -> str:
    status, out, err = cli(*argv)
    if status != 0:
        raise SystemExit(f"stableins {' '.join(argv)} exited {status}:\n{err}")
    return out


def pdf_text(path: Path) -> str:
    return subprocess.run(["pdftotext", "-layout", str(path), "-"], check=True, capture_output=True, text=True).stdout


def three_stages(root: Path, seed: int) -> None:
    from stableins.commands.demo import _datasheet
    from stableins.errormodel import known_terms
    from stableins.records import CalibrationRecord

    print("1. demo: the system stage as a Bayesian update of the device record (one sidereal day at 10 Hz)")
    must("simulate", "device", "--seed", str(seed), "--out", str(root))
    datasheet = _datasheet(root / "truth.json")
    must(
        "calibrate",
        "device",
        str(root / "device-coarse.csv"),
        str(root / "device-fine.h5"),
        "--out",
        str(root / "cal-device.json"),
        *datasheet,
    )
    must("simulate", "system", "--truth", str(root / "truth.json"), "--seed", str(seed), "--installed", str(root / "cal-device.json"),
         "--duration", "86164.0905s", "--rate", "10", "--out", str(root))  # fmt: skip
    must("calibrate", "system", str(root / "system.h5"), "--prior", str(root / "cal-device.json"), "--out", str(root / "calibration.json"))
    prior, post = CalibrationRecord.load(root / "cal-device.json"), CalibrationRecord.load(root / "calibration.json")
    terms = known_terms()
    print(f"   {'parameter':<10} {'prior σ':>10} {'posterior σ':>12} {'ratio':>7}  unit      status     last determined by")
    worst = 0.0
    for p in prior.parameters:
        q = post[p.id]
        if not p.sigma > 0:
            print(f"   {p.id:<10} {'—':>10} {'—':>12} {'—':>7}  {terms[p.id].unit:<9} {q.status.value:<10} {post.source_text(p.id)}")
            continue
        ratio = q.sigma / p.sigma
        worst = max(worst, ratio)
        a, b = terms[p.id].sigma_to_engineering(p.sigma), terms[p.id].sigma_to_engineering(q.sigma)
        print(f"   {p.id:<10} {a:>10.3f} {b:>12.3f} {ratio:>7.3f}  {terms[p.id].unit:<9} {q.status.value:<10} {post.source_text(p.id)}")
    verdict = "ok" if worst <= 1.0 + 1e-9 else "VIOLATED"
    print(f"   largest posterior/prior σ = {worst:.4f} (must be ≤ 1: {verdict}); stages run: {', '.join(post.provenance.stages)}; "
          f"procedure: {post.calibration.procedure}")  # fmt: skip


def short_records(root: Path, seed: int) -> None:
    from stableins.records import CalibrationRecord

    print("\n2. the system stage on shorter records (the demo's instrument, 1 Hz)")
    for hours in (6, 9, 12, 24):
        folder = root / f"sys{hours}"
        must("simulate", "system", "--truth", str(root / "truth.json"), "--seed", str(seed + hours), "--installed",
             str(root / "cal-device.json"), "--duration", f"{hours}h", "--rate", "1", "--out", str(folder))  # fmt: skip
        out = folder / "cal.json"
        status, stdout, err = cli("calibrate", "system", str(folder / "system.h5"), "--prior", str(root / "cal-device.json"),
                                  "--out", str(out), "--json")  # fmt: skip
        if status == 0:
            document = json.loads(stdout)
            determined = sum(d["determined"] for d in document["determined"])
            record = CalibrationRecord.load(out)
            prior = CalibrationRecord.load(root / "cal-device.json")
            worst = max(record[p.id].sigma / p.sigma for p in prior.parameters if p.sigma > 0)
            print(f"   {hours:>2} h: exit 0, record written, {determined} of 7 combinations determined, rank {document['rank']}, "
                  f"ν = {document['dof']}, χ²_ν = {document['chi2_red']:.2f}, largest σ ratio {worst:.4f}")  # fmt: skip
        else:
            reason = err.strip().split("': ", 1)[-1]
            print(f"   {hours:>2} h: exit {status}, record written: {out.exists()}; reason: {reason}")
    print("   compared against: a 6-h record exits 2, writes no record and names what the data lack")


def field_recalibration(root: Path) -> None:
    from stableins.errormodel import known_terms
    from stableins.history_store import HistoryStore
    from stableins.records import CalibrationRecord

    print("\n3. field recalibration on the simulated platform (SN042)")
    store = root / "store"
    must("run", "device-coarse", "--driver", "sim", "--unit", "SN042", "--seed", "4", "--out", str(root / "run1"), "--yes", "--quiet")
    must("history", "SN042", "--store", str(store), "--add", str(root / "run1" / "record.json"))
    out = root / "recal1"
    printed = must("recal", "field-recal-device", "--unit", "SN042", "--store", str(store), "--driver", "sim", "--seed", "4",
                   "--out", str(out), "--yes", "--quiet", "--set", "site_temperature=23.5", "--json")  # fmt: skip
    recal = json.loads(printed)
    found = []
    for path in sorted(out.glob("*.json")):
        try:
            found.append((path.name, CalibrationRecord.load(path)))
        except Exception:  # noqa: BLE001 - procedure.json is a plan, not a record
            continue
    prior_digest = HistoryStore(store).entries("SN042")[0].sha256
    new = [n for n, r in found if n != "prior.json"]
    print(f"   records in the run directory: {[n for n, _ in found]} (prior.json is the record in force it started from); new: {new}")
    entry = HistoryStore(store).in_force("SN042")
    same = (store / "SN042" / entry.file).read_bytes() == (out / "record.json").read_bytes()
    print(f"   record in force after recal: {entry.file}; byte-identical to recal1/record.json: {same}; prior digest {prior_digest[:12]}")
    record = dict(found)["record.json"]
    carried = ", ".join(s.name for s in record.stages if s not in record.stages_run)
    print(f"   stages run: {', '.join(record.provenance.stages)}; carried over: {carried}")
    from stableins.reporting.symbols import parts

    text = pdf_text(out / "report-technical.pdf")  # the results table with each value's status (issue 28)
    printed = {m.group(1): m.group(2) for m in re.finditer(r"^(\S+)\s+estimated\s+(\S+)\s", text, re.M)}
    rows = {p.id: printed["".join(parts(p.id))] for p in record.parameters if "".join(parts(p.id)) in printed}
    terms = known_terms()
    worst = 0.0
    for p in record.parameters:
        if p.id in rows:  # printed to the last digit of U (GUM 7.2.6): within half a unit of that digit
            shown = rows[p.id].replace("\u2212", "-")
            half_digit = 0.5 * 10.0 ** -(len(shown.partition(".")[2]))
            worst = max(worst, abs(float(shown) - float(terms[p.id].to_engineering(p.value))) / half_digit)
    verdict = "ok" if worst <= 1.0 + 1e-9 else "VIOLATED"
    print(
        f"   certificate vs record: {len(rows)} values, largest |shown − record| = {worst:.3f} of half the last printed digit "
        f"(must be ≤ 1: {verdict})"
    )
    history = json.loads(must("history", "SN042", "--store", str(store), "--json"))
    begin = re.search(r"^\d+\s+Change since the previous calibration", text, re.M)  # the technical report's too
    end = re.search(r"^\d+\s+Statement of conformity", text, re.M)
    if begin is None or end is None:
        raise SystemExit(f"{out / 'report-technical.pdf'}: no 'Change since the previous calibration' section before the conformity")
    section = text[begin.start() : end.start()]
    certificate = sorted({m.group(1) for m in re.finditer(r"^\s*(\w+)\s+\S+\s+\S+\s+\S+\s+\S+\s+\S+\s+yes\s", section, re.M)})
    flags = f"recal {recal['significant']}, history {history['changes'][-1]['significant']}, certificate {certificate}"
    print(f"   change flags (|z| ≥ 3): {flags}; compared: {len(recal['changes'])} parameters, not compared: {len(recal['not_compared'])}")
    flat = " ".join(text.split())
    print(f"   on the certificate: site temperature entry {'site temperature 23.5 °C' in flat}, data times "
          f"{record.provenance.data_start in flat and record.provenance.data_end in flat}, sample rate {'100 Hz' in flat}")  # fmt: skip


def chi2(root: Path) -> None:
    from stableins.commands.demo import _datasheet

    print("\n4. one χ²_ν per fit: diagnose text against --json (fine dwells, slow-noise model of the datasheet)")
    argv = ["diagnose", str(root / "device-coarse.csv"), str(root / "device-fine.h5"), "--record", str(root / "cal-device.json"),
            *_datasheet(root / "truth.json")]  # fmt: skip
    text = must(*argv)
    document = json.loads(must(*argv, "--json"))
    shown = float(re.search(r"χ²_ν = ([\d.]+)", text).group(1))
    print(f"   text χ²_ν = {shown:.3f}, --json chi2_red = {document['chi2_red']:.3f} (must agree to the printed digits)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=2018)
    parser.add_argument("--keep", type=Path, help="work in this directory and keep it")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as temporary:
        root = args.keep or Path(temporary)
        root.mkdir(parents=True, exist_ok=True)
        three_stages(root, args.seed)
        short_records(root, args.seed)
        field_recalibration(root)
        chi2(root)


if __name__ == "__main__":
    main()
