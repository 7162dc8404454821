"""``stableins run`` of an indexed procedure that ends with the systematic stage, end to end (issue 18).

The documented sequence (docs/systematic-calibration.md) on the simulated platform:
``run DEFINITION --driver sim --prior cal.json`` (the platform polar-aligned, indexed by torquing at ``at`` with the
simulator's own kinematics and time-domain error dynamics, journaled and resumable), then
``calibrate system RUN/system.h5 --prior cal.json --systematic --json`` and ``report``: the record, the JSON and the
certificate carry the same numbers.  A short definition (two holds of 1 h at 2 Hz, 60° about the middle gimbal axis)
stands for the shipped day-long ``system-indexed``; definitions the platform cannot carry out are refused before it
moves, with the file and the field named (exit 2).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from inprocess import run_cli
from systematic_world import prior_record

from stableins.console import Console
from stableins.conventions import DEG_PER_HOUR, DEG_PER_HOUR_PER_G
from stableins.data.system import open_system_record
from stableins.drivers.select import simulated_platform
from stableins.errors import InputError
from stableins.procedures.definition import load_procedure
from stableins.procedures.plan import Plan, StaticRecordStep, SystemEstimation
from stableins.procedures.planning import plan_from_definition
from stableins.records import CalibrationRecord
from stableins.runs import RunSetup, start_run
from stableins.simulator.system import indexed_record_chunks
from stableins.status import Status
from tests import certificate_checks
from tests.tcp_fixtures import ROOT

SEED, UNIT, RATE = 5, "SYS-IDX-5", 2.0
#: Two holds of an hour at 2 Hz, indexed 60° about the middle gimbal axis in between (system-indexed, shortened).
SHORT = """
[procedure]
name = "system-indexed-2h"
stage = "system"
source = "system-indexed with two holds of 1 h (a test)"

[record]
duration = 7200.0
sample_rate = 2.0
estimation = "systematic"

[[record.index]]
at = 3600.0
axis = "middle"
angle = 60.0
rate = 10.0

[runner]
chunk = 300.0

[[person]]
before = 0
action = "confirm"
prompt = "The INS navigates on a static base"
"""
POPPLER = shutil.which("pdftotext") and shutil.which("pdftoppm")


def _process(*argv: str) -> subprocess.CompletedProcess[str]:
    """``stableins ARGV`` in a fresh interpreter: a resume after the crash of the process that started the run."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    return subprocess.run([sys.executable, "-m", "stableins.cli", *argv], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)


def _pdf_text(pdf: Path) -> str:
    return " ".join(subprocess.run(["pdftotext", "-layout", str(pdf), "-"], check=True, capture_output=True, text=True).stdout.split())


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """The definition and the unit's record: a device calibration of the simulated instrument (its own draw of the
    residuals, not the simulator's default installed calibration), which the run loads into the simulated INS."""
    folder = tmp_path_factory.mktemp("indexed")
    (folder / "short.toml").write_text(SHORT)
    truth = simulated_platform(SEED, UNIT, RATE).truth
    rng = np.random.default_rng(SEED)
    sigma = np.sqrt(np.diag(prior_record(truth).covariance))
    calibrated = {pid: truth.parameters[pid] - s * rng.standard_normal() for pid, s in zip(prior_record(truth).ids, sigma, strict=True)}
    record = prior_record(truth.with_changes(installed_calibration={**truth.installed_calibration, **calibrated}))
    assert all(record[pid].value != truth.installed_calibration[pid] for pid in record.ids)
    record.save(folder / "cal.json")
    return folder, truth


@pytest.fixture(scope="module")
def reference(inputs):
    """The run, uninterrupted, through the command line."""
    folder, _ = inputs
    run = folder / "run"
    args = ("run", str(folder / "short.toml"), "--driver", "sim", "--seed", str(SEED), "--unit", UNIT)
    result = run_cli([*args, "--prior", str(folder / "cal.json"), "--out", str(run), "--yes"])
    assert result.returncode == 0, result.stderr
    return run, result.stderr + result.stdout


@pytest.mark.slow
def test_run_ends_with_the_systematic_stage_and_the_record_json_and_certificate_agree(inputs, reference):
    folder, truth = inputs
    run, console = reference
    assert "systematic calibration over 2 orientations" in console
    data = open_system_record(run / "system.h5").read()
    assert len(data["time"]) == int(7200 * RATE)
    # the simulated INS navigated with --prior, as a real one is loaded with the calibration it runs with
    prior = CalibrationRecord.load(folder / "cal.json")
    turns = load_procedure(folder / "short.toml").record.turns
    world = indexed_record_chunks(truth.with_installed(prior.values()), 7200.0, turns, rate=RATE, seed=SEED, chunk_samples=600)
    first = next(world)
    for name in ("f_x", "velocity_north", "velocity_east", "pitch", "heading"):
        np.testing.assert_array_equal(data[name][:600], first[name], err_msg=name)
    record = CalibrationRecord.load(run / "record.json")
    assert record.stages_run[-1].name == "systematic"
    orientations = record.stages_run[-1].settings.orientations
    assert [round(o.polar_angle_deg) for o in orientations] == [0, 60]  # polar-aligned, then the index
    assert orientations[0].end_h <= 1.0 <= orientations[1].start_h
    # a Bayesian update of the prior: no σ grows, no parameter of the prior loses its σ; within 4σ of the simulator's truth
    for pid in prior.ids:
        assert record[pid].status is Status.ESTIMATED and record[pid].sigma <= prior[pid].sigma * (1 + 1e-9), pid
        assert abs(record[pid].value - truth.parameters[pid]) < 4 * record[pid].sigma, pid
    drift = [record[f"gyro_drift_{a}"] for a in "xyz"]
    assert all(p.status is Status.UNIDENTIFIABLE or abs(p.value) < 4 * p.sigma for p in drift)  # the truth drifts by 0

    # the same record through 'calibrate system --systematic --json': the same numbers and orientations
    out = folder / "cal2.json"
    result = run_cli(
        ["calibrate", "system", str(run / "system.h5"), "--prior", str(folder / "cal.json"), "--systematic", "--out", str(out), "--json"]
    )
    assert result.returncode == 0, result.stderr
    document = json.loads(result.stdout)
    by_id = {p["id"]: p for p in document["parameters"]}
    assert set(by_id) == set(record.ids)
    for pid in record.ids:
        p = record[pid]
        assert by_id[pid]["value"] == pytest.approx(p.value, rel=1e-12, abs=1e-300), pid
        assert (by_id[pid]["sigma"] is None) == (not math.isfinite(p.sigma)), pid
        if by_id[pid]["sigma"] is not None:
            assert by_id[pid]["sigma"] == pytest.approx(p.sigma, rel=1e-12), pid
    for pid, entry in document["gyro"].items():  # °/h and °/h/g, named: the record's numbers
        unit = DEG_PER_HOUR if pid.startswith("gyro_drift_") else DEG_PER_HOUR_PER_G
        assert entry["unit"] == ("°/h" if pid.startswith("gyro_drift_") else "°/h/g")
        assert entry["value"] * unit == pytest.approx(record[pid].value, rel=1e-12) and entry["sigma"] * unit == pytest.approx(
            record[pid].sigma, rel=1e-12
        )
    assert len(document["gyro"]) == 12
    for ours, theirs in zip(orientations, document["orientations"], strict=True):
        assert ours.start_h * 3600.0 == pytest.approx(theirs["start_s"]) and ours.end_h * 3600.0 == pytest.approx(theirs["end_s"])
        assert ours.polar_angle_deg == pytest.approx(math.degrees(theirs["polar_angle_rad"]))
        assert ours.specific_force_g == pytest.approx(theirs["specific_force_g"])

    # the certificates of both records show the section with these orientations
    pdf = folder / "cal2.pdf"
    result = run_cli(["report", str(out), "--out", str(pdf)])
    assert result.returncode == 0, result.stderr
    if not POPPLER:
        pytest.skip("pdftotext/pdftoppm (Debian package poppler-utils) are not installed: the certificates are written, not read back")
    for certificate in (run / "report.pdf", pdf):
        assert certificate_checks.review(certificate, folder) == []  # units, one GUM rounding in every table, no paths
        text = _pdf_text(certificate_checks.technical_of(certificate))  # the evidence: in the technical report
        assert "Systematic stage: orientations" in text
        for k, o in enumerate(orientations, start=1):
            assert f"{k} {o.start_h:.2f} – {o.end_h:.2f}" in text and f"{o.polar_angle_deg:.1f}°" in text


class Crash(Exception):
    """The process dying in the middle of the record."""


@pytest.mark.slow
def test_a_run_killed_in_the_record_resumes_to_the_same_record(inputs, reference, tmp_path):
    folder, _ = inputs
    run, _ = reference
    plan = plan_from_definition(load_procedure(folder / "short.toml"))
    driver = simulated_platform(SEED, UNIT, RATE)
    chunks = driver.static_record

    def crashing(duration, chunk, turns=()):
        for k, piece in enumerate(chunks(duration, chunk, turns)):
            if k == 15:  # after the index (3600 s = chunk 12 of 300 s)
                raise Crash("power lost in the middle of the record")
            yield piece

    driver.static_record = crashing
    setup = RunSetup(definition_file=folder / "short.toml", prior_file=folder / "cal.json")
    with pytest.raises(Crash):
        start_run(
            plan,
            tmp_path / "run",
            driver_spec="sim",
            seed=SEED,
            unit=UNIT,
            console=Console(yes=True, quiet=True),
            driver=driver,
            setup=setup,
        )
    result = _process("run", "--resume", str(tmp_path / "run"))
    assert result.returncode == 0, result.stderr
    resumed, first = open_system_record(tmp_path / "run" / "system.h5").read(), open_system_record(run / "system.h5").read()
    for name in first:
        np.testing.assert_array_equal(resumed[name], first[name], err_msg=name)
    again, once = CalibrationRecord.load(tmp_path / "run" / "record.json"), CalibrationRecord.load(run / "record.json")
    np.testing.assert_array_equal([again[i].value for i in once.ids], [once[i].value for i in once.ids])


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        # 90° about the middle axis: with the Earth's turn the inner gimbal locks within the day, hours after the index
        (
            (("duration = 7200.0\nsample_rate = 2.0", "duration = 86400.0\nsample_rate = 1.0"), ("angle = 60.0", "angle = 90.0")),
            "record.index[0]",
        ),
        ((("at = 3600.0", "at = 7200.0"),), "record.index"),  # at the record's end: the turn would end after it
        ((("rate = 10.0", "rate = 0.0"),), "record.index[0].rate"),
        ((('estimation = "systematic"', 'estimation = "kalman"'),), "record.estimation"),
    ],
)
def test_a_definition_the_platform_cannot_carry_out_is_refused_before_it_moves(tmp_path, inputs, changes, field):
    folder, _ = inputs
    text = SHORT
    for old, new in changes:
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / "bad.toml"
    path.write_text(text)
    out = tmp_path / "run"
    prior = str(folder / "cal.json")
    result = run_cli(
        ["run", str(path), "--driver", "sim", "--seed", str(SEED), "--unit", UNIT, "--prior", prior, "--out", str(out), "--yes"]
    )
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr and str(path) in result.stderr and f"field '{field}'" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert not (out / "journal.bin").exists() and not (out / "procedure.json").exists()


def test_the_estimation_is_declared_and_checked(tmp_path):
    assert load_procedure("system-indexed").record.estimation is SystemEstimation.SYSTEMATIC
    assert load_procedure("drift-two-position").record.estimation is SystemEstimation.DRIFT  # the default with an index
    assert load_procedure("system-static").record.estimation is SystemEstimation.SYSTEM
    path = tmp_path / "p.toml"
    path.write_text(SHORT.split("[[record.index]]")[0] + "[runner]\nchunk = 300.0\n")  # no index
    with pytest.raises(InputError, match="two orientations") as error:
        load_procedure(path)
    assert error.value.field == "record.estimation"
    # a plan written before the field (procedure.json, a journal's start record): an indexed record ends with the drift test
    document = json.loads(json.dumps(plan_from_definition(load_procedure("drift-two-position")).to_dict()))
    for step in document["steps"]:
        step.pop("estimation", None)
    (step,) = [s for s in Plan.from_dict(document).steps if isinstance(s, StaticRecordStep)]
    assert step.estimation is SystemEstimation.DRIFT
    (raw,) = [s for s in document["steps"] if s["kind"] == "static_record"]
    raw["estimation"], raw["turns"] = "systematic", []
    with pytest.raises(InputError, match="two orientations") as error:
        Plan.from_dict(document)
    assert error.value.field.endswith(".estimation")
