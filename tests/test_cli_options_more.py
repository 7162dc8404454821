"""``diagnose``, ``simulate`` and ``run`` options in successful runs, each effect asserted (issue 31).

The fuzz workspace's files (a device-coarse session, a record) and a three-dwell plan on the simulated platform keep
every run to a second or two.  tests/test_cli_options.py maps the options to these tests.
"""

from __future__ import annotations

import json
import re
from dataclasses import replace

import numpy as np
import pytest
from inprocess import run_cli

from stableins.procedures.journal import scan


@pytest.fixture(scope="module")
def ws(fuzz_workspace):
    return fuzz_workspace  # tests/conftest.py: built once per process


# --------------------------------------------------------------------------- diagnose
def test_diagnose_alpha_top_and_noise(ws, tmp_path):
    """--alpha sets the family-wise flag level, --top the candidates shown, --noise the noise model of a record."""
    from fuzzing import _record

    from stableins.noise import NoiseModel

    status, default, err = run_cli(["diagnose", ws.device_csv, "--record", ws.record])
    assert status == 0, err[-1000:]
    status, text, err = run_cli(["diagnose", ws.device_csv, "--record", ws.record, "--alpha", "0.2", "--top", "3"])
    assert status == 0, err[-1000:]
    assert "flag level α = 0.025 family-wise" in default and "flag level α = 0.2 family-wise" in text  # --alpha

    def shown(report: str) -> int:
        return len(re.findall(r"^ +\d+ \S+ +[-\d.]+ +[\d.e-]+ ", report, re.M))

    assert shown(text) == 3 and shown(default) == 10  # --top 3; ten by default
    model = NoiseModel.given(2e-3, 1e-4, 1e-6, provenance="noise record for the diagnose options test")
    noisy = tmp_path / "noise.json"
    replace(_record(ws.serial), noise_model=model).save(noisy)
    status, out, err = run_cli(["diagnose", ws.device_csv, "--record", ws.record, "--noise", noisy, "--json"])
    assert status == 0, err[-1000:]
    document = json.loads(out)
    assert "noise record for the diagnose options test" in document["noise_model"]["provenance"]  # --noise: that model
    status, out, _ = run_cli(["diagnose", ws.device_csv, "--record", ws.record, "--json"])
    assert document["chi2_red"] < 0.8 * json.loads(out)["chi2_red"]  # its slow noise under the σ: χ²_ν falls


# --------------------------------------------------------------------------- simulate
def test_simulate_format_and_installed(ws, tmp_path):
    """--format h5 writes HDF5 where a small device file is CSV by default; --installed loads the INS with a record."""
    from stableins.data.truth import load_truth
    from stableins.records import CalibrationRecord

    base = ["simulate", "device", "--procedure", "device-coarse", "--dwell", "2", "--rate", "5", "--no-iteration", "--seed", "1"]
    assert run_cli([*base, "--out", tmp_path / "csv"])[0] == 0
    assert run_cli([*base, "--out", tmp_path / "h5", "--format", "h5"])[0] == 0
    assert [p.suffix for p in (tmp_path / "csv").glob("device*")] == [".csv"]
    assert [p.suffix for p in (tmp_path / "h5").glob("device*")] == [".h5"]  # --format h5
    system = ["simulate", "system", "--duration", "600", "--rate", "1", "--seed", "2"]
    assert run_cli([*system, "--out", tmp_path / "own"])[0] == 0
    status, _, err = run_cli([*system, "--out", tmp_path / "installed", "--installed", ws.record])
    assert status == 0, err[-1000:]
    record = CalibrationRecord.load(ws.record)
    own, installed = (load_truth(tmp_path / d / "truth.json").installed_calibration for d in ("own", "installed"))
    assert installed["bias_x"] == record["bias_x"].value != own["bias_x"]  # --installed: the record's values
    import h5py

    with h5py.File(tmp_path / "own" / "system.h5", "r") as a, h5py.File(tmp_path / "installed" / "system.h5", "r") as b:
        assert not np.allclose(a["columns/pitch"][...], b["columns/pitch"][...], rtol=0, atol=1e-12)  # and what the INS outputs


# --------------------------------------------------------------------------- run
def _plan(path):
    from stableins.procedures.plan import DwellStep, Plan
    from tests.runner_fixtures import SIM_CHECKS, SMALL_MOVES

    steps = [
        DwellStep(f"position {k}", "coarse", 1, k, r, settle=0.5, dwell=1.0, checks=SIM_CHECKS) for k, r in enumerate(SMALL_MOVES[:3], 1)
    ]
    path.write_text(json.dumps(Plan("short", "device", tuple(steps), chunk=0.5).to_dict()), encoding="utf-8")
    return path


def _piece_spans(run) -> list[float]:
    pieces = [r for r in scan(run / "journal.bin").records if r.kind == "op" and r.get("phase") == "dwell"]
    return [float(p.arrays["time"][-1] - p.arrays["time"][0]) for p in pieces]


def test_run_chunk_retries_timeout_and_store(ws, tmp_path):
    """--chunk and --retries change the plan the run executes (and resumes); --store takes the unit's record in force;
    --timeout is for a network platform and refused with the simulated one (it would be ignored)."""
    plan = _plan(tmp_path / "plan.json")
    common = ["run", plan, "--driver", "sim", "--seed", "8", "--unit", ws.serial, "--yes", "--quiet"]
    assert run_cli([*common, "--out", tmp_path / "default"])[0] == 0
    status, _, err = run_cli([*common, "--out", tmp_path / "chunked", "--chunk", "0.2", "--retries", "4"])
    assert status == 0, err[-1000:]
    executed = json.loads((tmp_path / "chunked" / "procedure.json").read_text(encoding="utf-8"))
    assert (executed["chunk"], executed["retries"]) == (0.2, 4)  # --chunk, --retries: the plan the run keeps and resumes
    assert max(_piece_spans(tmp_path / "chunked")) <= 0.2 < max(_piece_spans(tmp_path / "default")) <= 0.5  # sample time stamps
    assert len(_piece_spans(tmp_path / "chunked")) > len(_piece_spans(tmp_path / "default"))
    store = tmp_path / "store"
    assert run_cli(["history", ws.serial, "--store", store, "--add", ws.record])[0] == 0
    status, _, err = run_cli([*common, "--out", tmp_path / "stored", "--store", store])
    assert status == 0, err[-1000:]
    assert (tmp_path / "stored" / "prior.json").read_bytes() == ws.record.read_bytes()  # --store: the record in force is the prior
    assert not (tmp_path / "default" / "prior.json").exists()
    status, _, err = run_cli([*common, "--out", tmp_path / "timeout", "--timeout", "5"])
    assert status == 2 and "--timeout" in err and "tcp://HOST:PORT" in err and not (tmp_path / "timeout").exists()


@pytest.mark.slow
def test_recal_options(ws, tmp_path):
    """recal with --prior, --truth and --hidden, --chunk, --retries, --new-calibration; then --resume --re-estimate;
    --timeout refused with the simulated platform (about 15 s of CPU: two field recalibrations and a re-estimate)."""
    from stableins.data.truth import load_truth, save_truth
    from stableins.records import CalibrationRecord
    from stableins.simulator.truth import Truth

    truth = Truth.draw(4)
    truth = truth.with_changes(site=replace(truth.site, serial_number=ws.serial))
    save_truth(truth, tmp_path / "truth.json")
    out = tmp_path / "recal"
    argv = ["recal", "field-recal-device", "--unit", ws.serial, "--prior", ws.record, "--driver", "sim", "--out", out, "--yes", "--quiet",
            "--truth", tmp_path / "truth.json", "--hidden", "K3_x=100ug/g3", "--chunk", "0.5", "--retries", "3", "--new-calibration",
            "--json"]  # fmt: skip
    status, stdout, err = run_cli(argv)
    assert status == 0, err[-1000:]
    assert json.loads(stdout)["prior"] == str(ws.record)
    assert (out / "prior.json").read_bytes() == ws.record.read_bytes()  # --prior: the record it starts from
    kept = load_truth(out / "truth.json")
    assert kept.seed == truth.seed and kept.parameters == truth.parameters  # --truth: that world
    assert kept.effects["K3_x"] == pytest.approx(100e-6 / 9.80665**2, rel=1e-9) and "K3_x" not in truth.effects  # --hidden
    executed = json.loads((out / "procedure.json").read_text(encoding="utf-8"))
    assert (executed["chunk"], executed["retries"]) == (0.5, 3)  # --chunk, --retries
    record, prior = CalibrationRecord.load(out / "record.json"), CalibrationRecord.load(ws.record)
    assert record.calibration.id != prior.calibration.id and record.calibration.prior is not None  # --new-calibration
    before = record.values()
    (out / "record.json").unlink()
    status, stdout, err = run_cli(["recal", "--resume", out, "--re-estimate", "--json"])
    assert status == 0 and "again from its journal" in err, err[-1000:]  # --re-estimate: from the journal alone
    assert CalibrationRecord.load(out / "record.json").values() == pytest.approx(before, rel=0, abs=1e-15)
    status, _, err = run_cli([*argv[:9], tmp_path / "no", "--yes", "--timeout", "5"])
    assert status == 2 and "--timeout" in err and not (tmp_path / "no").exists()  # --timeout: for a network platform only


def test_run_link_failures_and_timeout_over_tcp(tmp_path):
    """--link-failures: one cut link is survived with 2 allowed and stops the run with 1; --timeout: a stalled link is
    given up after that many seconds of silence (then repeated on a new connection)."""
    from tests.tcp_fixtures import FaultyRelay, ServerProcess

    plan = _plan(tmp_path / "plan.json")
    statuses = {}
    with ServerProcess(seed=3, simulator=True, unit="LINK-1") as server:
        for name, fault, options in (("cut1", "cut", ["--link-failures", "1"]), ("cut2", "cut", ["--link-failures", "2"]),
                                     ("stall", "stall", ["--link-failures", "2", "--timeout", "1"])):  # fmt: skip
            with FaultyRelay(server.port, fault=(fault, 20_000)) as relay:
                argv = ["run", plan, "--driver", f"tcp://127.0.0.1:{relay.port}", "--out", tmp_path / name, "--yes", "--quiet", *options]
                statuses[name] = run_cli(argv)[0]
    assert statuses["cut1"] == 3  # --link-failures 1: stopped (resumable) at the first cut
    assert statuses["cut2"] == 0 and statuses["stall"] == 0  # --link-failures 2: the step repeated on a new link, finished
    errors = {}
    for name in statuses:
        failed = [r for r in scan(tmp_path / name / "journal.bin").records if r.kind == "op" and r.get("error")]
        assert len(failed) == 1, name  # the one fault, in each run
        errors[name] = str(failed[0]["error"])
    assert "did not answer within 1 s" in errors["stall"]  # --timeout 1: the silence given up after 1 s (default 10 s)


@pytest.mark.slow
def test_run_new_calibration_starts_its_own(ws, tmp_path):
    """run --prior REC --new-calibration: a field recalibration that starts a calibration of its own from REC.

    Without the option the run continues REC's calibration, whose fine stage needs that calibration's coarse dwells:
    it is refused (after the run; see the report of issue 31), so the option is what makes this run succeed.
    """
    import hashlib

    from stableins.records import CalibrationRecord

    argv = ["run", "field-recal-device", "--driver", "sim", "--seed", "4", "--unit", ws.serial, "--prior", ws.record, "--yes", "--quiet"]
    status, _, err = run_cli([*argv, "--out", tmp_path / "new", "--new-calibration"])
    assert status == 0, err[-1000:]
    prior, new = CalibrationRecord.load(ws.record), CalibrationRecord.load(tmp_path / "new" / "record.json")
    assert new.calibration.id != prior.calibration.id  # --new-calibration: its own calibration ...
    assert new.calibration.prior is not None and new.calibration.prior.sha256 == hashlib.sha256(ws.record.read_bytes()).hexdigest()
    assert new.provenance.stages == ("fine",)  # ... of the one stage this run measured, from the prior REC


@pytest.mark.slow
def test_recal_link_failures_and_timeout_over_tcp(ws, tmp_path):
    """recal over TCP: a stalled link is given up after --timeout 1 s and repeated with --link-failures 2 (the field
    recalibration finishes); with --link-failures 1 the same stall stops it, resumable (about 15 s of CPU)."""
    from tests.tcp_fixtures import FaultyRelay, ServerProcess

    statuses, errors = {}, {}
    with ServerProcess(seed=4, simulator=True, unit=ws.serial) as server:
        for allowed in ("1", "2"):
            with FaultyRelay(server.port, fault=("stall", 50_000)) as relay:
                argv = ["recal", "field-recal-device", "--unit", ws.serial, "--prior", ws.record, "--driver", f"tcp://127.0.0.1:{relay.port}",
                        "--out", tmp_path / allowed, "--yes", "--quiet", "--timeout", "1", "--link-failures", allowed]  # fmt: skip
                statuses[allowed] = run_cli(argv)[0]
            failed = [r for r in scan(tmp_path / allowed / "journal.bin").records if r.kind == "op" and r.get("error")]
            errors[allowed] = [str(r["error"]) for r in failed]
    assert statuses["1"] == 3 and not (tmp_path / "1" / "record.json").exists()  # --link-failures 1: stopped at the stall
    assert statuses["2"] == 0 and (tmp_path / "2" / "record.json").exists()  # --link-failures 2: repeated, finished
    assert all(len(e) == 1 and "did not answer within 1 s" in e[0] for e in errors.values()), errors  # --timeout 1
