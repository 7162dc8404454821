"""The library behind ``stableins diagnose``: its typed document round-trips, bad documents are refused naming the
field, and the command prints exactly what :func:`stableins.discovery.diagnose.diagnose_data` finds."""

import json
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from stableins.cli import main
from stableins.conventions import ARCSEC
from stableins.data.device import load_device, save_device
from stableins.discovery.diagnose import DiagnoseOptions, NoiseOrigin, SlowNoiseGiven, diagnose_data
from stableins.discovery.diagnose_report import DiagnoseReport, DiagnoseStage, NextAction
from stableins.discovery.diagnostics import CONSISTENT_P_VALUES
from stableins.errors import InputError
from stableins.procedures.definition import device_layouts, load_procedure
from stableins.records import CalibrationRecord
from stableins.simulator.device import simulate_dwells
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.truth import Truth

sys.path.insert(0, str(Path(__file__).parent))
from fuzzing import _discovery_document  # noqa: E402

WHITE = NoiseSettings(velocity_random_walk=4.5e-4, quantization=1e-5, angle_noise=0.2 * ARCSEC)


@pytest.fixture(scope="module")
def device(tmp_path_factory):
    """A fine session with a hidden cubic (a carried effect is flagged) and a record from calibrate device."""
    tmp = tmp_path_factory.mktemp("diagnose-library")
    truth = Truth.draw(31, noise=WHITE, effects={"K3_x": 3e-6})
    files = []
    for name, dwell, rate, seed in (("coarse", 10.0, 20.0, 31), ("fine", 60.0, 10.0, 32)):
        procedure = load_procedure(f"device-{name}")
        columns = simulate_dwells(truth, [s.command for s in procedure.steps], dwell=dwell, settle=5.0, rate=rate, seed=seed, stage=name)
        files.append(str(save_device(tmp / f"device-{name}.csv", columns, replace(truth.site, extra={"procedure": name}))))
    record = tmp / "record.json"
    assert main(["calibrate", "device", *files, "--out", str(record), "--bias-instability", "0"]) == 0
    return files, str(record)


def test_library_result_is_what_the_command_prints(device, capsys):
    files, record = device
    capsys.readouterr()
    argv = ["diagnose", *files, "--record", record, "--bias-instability", "2", "--random-walk", "1e-6", "--json"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    from stableins.conventions import MICRO_G

    options = DiagnoseOptions(noise=SlowNoiseGiven(2 * MICRO_G, 1e-6, "bias instability and random walk given on the command line"))
    result = diagnose_data([load_device(f) for f in files], CalibrationRecord.load(record), options=options, layouts=device_layouts())
    report = result.report
    assert result.noise_origin is NoiseOrigin.DATASHEET and report.stage is DiagnoseStage.FINE
    document = json.loads(printed)
    assert report.next == () and document["next"]  # the command words the next step
    ours = replace(report, next=tuple(document["next"])).to_json()
    assert json.dumps(ours, indent=1) + "\n" == printed
    # the hidden cubic is flagged and carried into the calibration: the next step as data
    step = report.next_step
    assert step.action is NextAction.CARRY and step.effect == report.flagged[0].id and step.keep == ()
    assert "K3_x" in (step.effect, *step.confused_with)  # with these data the cubic and Koq_x may be indistinguishable
    assert f"--add {step.effect} --out" in document["next"][1] and document["next"][1].startswith("  stableins calibrate device")
    assert report.alarm and not report.consistent


def test_device_document_round_trips(device, capsys, tmp_path):
    files, record = device
    capsys.readouterr()
    assert main(["diagnose", files[0], "--record", record, "--add", "K3_x", "--json"]) == 0
    printed = capsys.readouterr().out
    report = DiagnoseReport.from_json(json.loads(printed))
    assert report.stage is DiagnoseStage.COARSE and report.drift is not None and report.system is None
    assert [s.label for s in report.history] == ["standard model", "+ K3_x"]
    assert json.dumps(report.to_json(), indent=1) + "\n" == printed
    (tmp_path / "d.json").write_text(printed)
    assert main(["check", str(tmp_path / "d.json"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)["files"][0]
    assert summary == {"file": str(tmp_path / "d.json"), "kind": "diagnosis", "stage": "coarse", "steps": 2,
                       "flagged": [c.id for c in report.flagged]}  # fmt: skip


def test_system_document_round_trips_and_its_verdict_is_derived():
    document = _discovery_document()
    report = DiagnoseReport.from_json(document)
    assert report.system is not None and report.system.bin_seconds == 60.0 and len(report.spectra) == 2
    assert json.dumps(report.to_json()) == json.dumps(document)
    assert report.consistent and not report.alarm and report.next_step.action is NextAction.CERTIFY
    flagged = json.loads(json.dumps(document))
    flagged["candidates"][1]["flagged"] = True
    flagged["alarm"] = True
    step = DiagnoseReport.from_json(flagged).next_step  # the system stage does not estimate added effects
    assert step.action is NextAction.INSPECT and step.effect == "K3_y" and "system stage" in step.reason


@pytest.mark.parametrize(
    ("path", "value", "field"),
    [
        (("candidates", 1, "p_value"), "small", "candidates[1].p_value"),
        (("candidates", 0, "predicted", "unit"), 3, "candidates[0].predicted.unit"),
        (("candidates", 0, "aliases", 0, "shift_per_unit"), "x", "candidates[0].aliases[0].shift_per_unit"),
        (("history", 1, "added"), 5, "history[1].added"),
        (("history", 0, "residual_rms_unit"), "ug", "history[0].residual_rms_unit"),
        (("spectra", "f_x", "harmonics", 0), -1, "spectra.f_x.harmonics[0]"),
        (("spectra", "f_y", "flagged"), [True], "spectra.f_y.flagged"),
        (("noise_model", "confidence"), "high", "noise_model.confidence"),
        (("stage",), "orbit", "stage"),
        (("dof",), 2.5, "dof"),
        (("alarm",), True, "alarm"),
        (("next", 1), 7, "next[1]"),
        (("bin_seconds",), 0, "bin_seconds"),
    ],
)
def test_bad_document_names_the_field(path, value, field, tmp_path):
    document = json.loads(json.dumps(_discovery_document()))  # no shared lists
    node = document
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(InputError) as error:
        DiagnoseReport.from_json(document, tmp_path / "diag.json")
    assert error.value.field == field and error.value.path == str(tmp_path / "diag.json")
    document = _discovery_document()
    del document["history"]
    with pytest.raises(InputError, match="missing") as error:
        DiagnoseReport.from_json(document)
    assert error.value.field == "history"


def test_options_name_the_parameter():
    with pytest.raises(InputError) as error:
        DiagnoseOptions(add=("nope",))
    assert error.value.field == "add"
    with pytest.raises(InputError) as error:
        DiagnoseOptions(add=("K3_x", "K3_x"))
    assert error.value.field == "add"
    with pytest.raises(InputError) as error:
        DiagnoseOptions(alpha=1.5)
    assert error.value.field == "alpha"


def test_consistent_is_the_rule_of_the_diagnosis():
    """The document's verdict and :attr:`Diagnosis.consistent` are one rule (a deliberate twin, pinned)."""
    from stableins.discovery.diagnostics import Diagnosis

    base = replace(DiagnoseReport.from_json(_discovery_document()), stage=DiagnoseStage.FINE, system=None, spectra=())
    low, high = CONSISTENT_P_VALUES
    for p in (0.0, low, np.nextafter(low, 1), 0.3, np.nextafter(high, 0), high, 1.0, math.nan):
        diagnosis = Diagnosis.__new__(Diagnosis)
        object.__setattr__(diagnosis, "p_value", p)
        object.__setattr__(diagnosis, "p_range", None)
        report = replace(base, p_value=float(p))
        assert report.consistent == diagnosis.consistent == (low < p < high)
        assert report.verdict is diagnosis.fit_verdict


@pytest.fixture(scope="module")
def outside(tmp_path_factory):
    """A session with a bias along the magnetic north (a world hook on the samples: no library effect has its form)."""
    from stableins.simulator.device import SimulatedPlatform

    tmp = tmp_path_factory.mktemp("diagnose-outside")
    truth = Truth.draw(41, noise=WHITE)
    platform = SimulatedPlatform(truth).platform
    files = []
    for name, dwell, rate, seed in (("coarse", 10.0, 20.0, 41), ("fine", 60.0, 10.0, 42)):
        procedure = load_procedure(f"device-{name}")
        columns = simulate_dwells(truth, [s.command for s in procedure.steps], dwell=dwell, settle=5.0, rate=rate, seed=seed, stage=name)
        readings = np.stack([columns["angle_platform"], columns["angle_inner"], columns["angle_middle"]], -1)
        north = platform.dcm_nav_to_platform(readings)[..., :, 0]  # C_n^p e_N: the field's direction in the platform frame
        for a, sensitivity in zip("xyz", (1.0, -0.6, 0.3), strict=True):  # each accelerometer sees the field differently
            columns[f"f_{a}"] = columns[f"f_{a}"] + 3e-4 * sensitivity * north[:, "xyz".index(a)]
        files.append(str(save_device(tmp / f"device-{name}.csv", columns, replace(truth.site, extra={"procedure": name}))))
    record = tmp / "record.json"
    assert main(["calibrate", "device", *files, "--out", str(record), "--bias-instability", "0"]) == 0
    return files, str(record)


def test_effect_outside_the_library_is_said_with_its_signature_and_no_name(outside, capsys):
    """Issue 25: χ² rejects the model, no candidate brings it into its band: "outside the library", no name, no certificate."""
    from stableins.discovery.signature import ResidualSignature

    files, record = outside
    capsys.readouterr()
    assert main(["diagnose", *files, "--record", record, "--json"]) == 0
    printed = capsys.readouterr()
    document = json.loads(printed.out)
    report = DiagnoseReport.from_json(document)
    assert report.verdict.name == "ABOVE" and report.outside_library and document["outside_library"] is True
    assert not report.flagged and not any(c["flagged"] for c in document["candidates"])
    best = next(c for c in report.candidates if c.identifiable)
    assert not best.explains and best.chi2_red_with > report.chi2_red / 2  # the best candidate does not explain it
    step = report.next_step
    assert step.action is NextAction.OUTSIDE and step.effect is None
    assert document["next"][0].startswith("next: outside the library: χ²_ν =") and "No certificate" in document["next"][0]
    assert "stableins report" not in printed.out + printed.err and "certificate:" not in printed.out + printed.err
    assert document["next"][1].startswith("  stableins diagnose") and "--plots" in document["next"][1]
    # the signature: z, the least sensitive, carries the least of the excess; named positions; round trip
    signature = report.signature
    assert isinstance(signature, ResidualSignature) and ResidualSignature.from_json(signature.to_json()) == signature
    shares = {o.output: o.share for o in signature.outputs}
    assert shares["f_z"] == min(shares.values()) < 0.2 and sum(shares.values()) == pytest.approx(1.0)
    assert signature.positions and all(p.position.startswith("f1/") for p in signature.positions)
    assert json.dumps(report.to_json(), indent=1) + "\n" == printed.out
    # the text: the headline and the next step agree
    assert main(["diagnose", *files, "--record", record]) == 0
    text = capsys.readouterr().out
    assert "NOT consistent with the noise floor: something is missing" in text and "outside the library:" in text
    assert "the residual's signature:" in text and "reaches the noise floor" not in text


def test_a_chi2_below_its_range_is_not_something_missing():
    """Issue 25: χ²_ν 0.933 with P = 0.999 was "NOT consistent …: something is missing" (the wrong tail)."""
    from scipy.stats import chi2

    from stableins.discovery.diagnostics import FitVerdict

    assert FitVerdict.of(0.999, 0.999) is FitVerdict.BELOW and FitVerdict.of(0.001, 0.001) is FitVerdict.ABOVE
    assert FitVerdict.of(0.999, 0.001) is FitVerdict.CONSISTENT  # the noise models allowed disagree: no verdict against it
    assert "something is missing" not in FitVerdict.BELOW.words() and "something is missing" in FitVerdict.ABOVE.words()
    document = _discovery_document()  # a system record: dof 30
    low = dict(document, chi2_red=0.35, chi2_red_range=[0.3, 0.4], p_value=float(chi2.sf(0.35 * 30, 30)), consistent=False)
    low["verdict"] = "below the noise floor"
    report = DiagnoseReport.from_json(low)
    assert report.p_value_range == pytest.approx((float(chi2.sf(9.0, 30)), float(chi2.sf(12.0, 30))))
    assert report.verdict is FitVerdict.BELOW and not report.consistent and not report.alarm and not report.outside_library
    step = report.next_step
    assert step.action is NextAction.CERTIFY and "below the noise floor" in step.reason
    written = report.to_json()
    assert written["verdict"] == "below the noise floor" and written["alarm"] is False and written["outside_library"] is False
    with pytest.raises(InputError, match="alarm"):
        DiagnoseReport.from_json(dict(low, alarm=True))
    with pytest.raises(InputError, match="verdict"):
        DiagnoseReport.from_json(dict(written, verdict="consistent"))
    # the slow terms at their upper limits still reject it from above: something is missing
    high = dict(document, chi2_red=3.0, chi2_red_range=[2.5, 3.5], p_value=float(chi2.sf(90.0, 30)), consistent=False, alarm=True)
    high |= {"verdict": "above the noise floor", "outside_library": True}
    report = DiagnoseReport.from_json(high)
    assert report.verdict is FitVerdict.ABOVE and report.alarm and report.outside_library
    assert report.next_step.action is NextAction.OUTSIDE and "χ²_ν = 2.5 (ν = 30" in report.next_step.reason
