"""Calibration report: rendered to PNG (pdftoppm) and read back (pdftotext); decision rules; bad input."""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
import certificate_checks  # noqa: E402
import report_fixtures as rf  # noqa: E402

from stableins import cli  # noqa: E402
from stableins.conventions import MICRO_G  # noqa: E402
from stableins.errors import InputError  # noqa: E402
from stableins.history import compare  # noqa: E402
from stableins.records import CalibrationRecord, file_sha256  # noqa: E402
from stableins.reporting import content, rounding  # noqa: E402
from stableins.reporting.symbols import plain  # noqa: E402
from stableins.reporting.tolerances import Tolerances, decide  # noqa: E402

POPPLER = shutil.which("pdftoppm") and shutil.which("pdftotext")
needs_poppler = pytest.mark.skipif(not POPPLER, reason="pdftoppm/pdftotext (Debian package poppler-utils) are not installed")

PROCEDURE = rf.procedure_with(
    """[tolerances]
decision_rule = "guarded"
[tolerances.limits]
"bias_*" = 500.0
"sf_*" = 300.0
"beta_*" = 60.0
"K2_*" = 50.0
[tolerances.uncertainty]
"bias_*" = 20.0
[tolerances.stability]
"bias_*" = 30.0
[tolerances.fit]
interval = 0.95
"""
)
BIAS_STEP_UG = 60.0


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("report")
    data = folder / "device.csv"
    data.write_text("time[s],f_x[m/s^2]\n0.0,0.1\n")  # stands for the session data: only its digest is used
    result = rf.fit(1)
    (folder / "record.json").write_text(json.dumps(rf.record(result, inputs=(data,))))
    values = rf.truth(1)
    values["bias_x"] -= BIAS_STEP_UG * MICRO_G  # the unit's bias moved by +60 µg since the previous calibration
    (folder / "old.json").write_text(json.dumps(rf.record(rf.fit(2, values=values), started="2025-11-20T08:00:00Z")))
    (folder / "proc.toml").write_text(PROCEDURE)
    return folder


def _render(pdf: Path) -> tuple[list[Path], str]:
    subprocess.run(["pdftoppm", "-r", "40", "-png", str(pdf), str(pdf.with_suffix(""))], check=True, timeout=60)
    pages = sorted(pdf.parent.glob(pdf.stem + "-*.png"))
    text = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], check=True, capture_output=True, text=True, timeout=60).stdout
    return pages, text


@needs_poppler
def test_full_report_pages_and_required_fields(files, capsys):
    out = files / "full.pdf"
    status = cli.main(
        [
            "report",
            str(files / "record.json"),
            "--data",
            str(files / "device.csv"),
            "--previous",
            str(files / "old.json"),
            "--procedure",
            str(files / "proc.toml"),
            "--out",
            str(out),
        ]
    )
    assert status == 0
    printed = capsys.readouterr().out
    report_id = re.search(r"certificate (SI-\S+),", printed).group(1)
    technical = files / "full-technical.pdf"
    assert f"{technical}: technical report" in printed
    # the certificate: at most three pages, identification, results with U, verdict with its rule and specification
    pages, certificate = _render(out)
    assert len(pages) <= 3
    for i in range(1, len(pages) + 1):
        assert f"page {i} of {len(pages)}" in certificate
    assert certificate.count(report_id) >= len(pages)
    flat = " ".join(certificate.split())
    assert "Inertial Sensor Laboratory, Building 4" in flat and "Navigation Systems Division" in flat
    assert "Verdict: FAIL" in certificate and "Decision rule: Binary guarded acceptance" in flat and "proc.toml" in flat
    assert file_sha256(technical) in "".join(certificate.split())  # the technical report, named by its digest
    assert "End of certificate." in certificate
    # the technical report: the evidence behind it, the same report id on every page
    pages, text = _render(technical)
    n = len(pages)
    assert 4 <= n <= 12
    for i in range(1, n + 1):  # every page carries "page i of n" and the report id
        assert f"page {i} of {n}" in text
    assert text.count(report_id) >= n
    assert "ACC-0042" in text and "Unit S/N ACC-0042" in text
    for pid in ["sf_x", "bias_y", "beta_zy", "K2_z", "theta10", "theta20"]:
        assert pid in text
    assert "U (k = 2)" in text and "µg/g²" in text and "arcsec" in text and "ppm" in text
    assert file_sha256(files / "device.csv") in text.replace("\n", "") or file_sha256(files / "device.csv")[:40] in text
    assert "verified: device.csv" in text
    assert "9.8015000 m/s²" in text and "WGS-84 normal gravity" in text
    assert "Model discovery" in text and "Not performed" in text  # no discovery history in the record
    # what people entered and what the data carry appear on the certificate
    flat = " ".join(text.split())
    assert "Inertial Sensor Laboratory, Building 4" in flat and "Navigation Systems Division" in flat
    assert "lab temperature 21.5 °C Laboratory temperature at the start" in flat
    assert "mean 24.81 °C, range 24.62 to 25.07 °C (from the data)" in flat
    assert "2026-11-20T08:00:00Z to 2026-11-20T14:30:00Z" in flat and "200 Hz" in flat and "wu2018-18-position" in flat
    # The +60 µg bias step is found significant and fails the 30 µg stability limit.
    assert "Verdict: FAIL" in text
    assert certificate_checks.review(out, files) == []  # no near-empty page, path, flag; units and one rounding
    assert re.search(r"change since\s+δbx.*fail", text, re.S)


def test_change_recovers_the_injected_bias_step(files):
    now = CalibrationRecord.load(files / "record.json")
    before = CalibrationRecord.load(files / "old.json")
    comparison = compare(before, now)
    assert comparison.relation == "independent"
    by_id = {c.id: c for c in comparison.changes}
    step = by_id["bias_x"]
    assert abs(step.difference - BIAS_STEP_UG * MICRO_G) < 4 * step.sigma_difference
    assert step.significant and abs(step.significance) >= 3
    # Parameters that did not move: |z| ≥ 3 has probability 0.27 % each; allow one of the others.
    assert sum(c.significant for c in comparison.changes if c.id != "bias_x") <= 1
    assert any(s.startswith("theta20") for s in comparison.skipped)
    terms = content.known_terms()
    rows = {r.id: r for r in content.parameter_rows(now, terms)}
    assert math.isnan(rows["theta20"].value) and rows["theta20"].formatted()[0] == "not stated"  # prior value never shown
    shown = {c.id: c for c in content.change_rows(comparison, terms)}
    assert shown["bias_x"].significant and shown["bias_x"].significance == step.significance  # the same z, in µg


@needs_poppler
def test_sections_without_evidence_say_so(files, tmp_path):
    record = json.loads((files / "record.json").read_text())
    for stage in record["stages"]:
        stage.update(fits=[], environment={}, inputs=[], entries=[])
    record["calibration"]["entries"] = []
    record["site"]["extra"] = {}
    (tmp_path / "bare.json").write_text(json.dumps(record))
    out = tmp_path / "bare.pdf"
    assert cli.main(["report", str(tmp_path / "bare.json"), "--out", str(out)]) == 0
    _, certificate = _render(out)
    flat = " ".join(certificate.split())
    assert "DRAFT: the laboratory, customer, operator are not stated" in flat and "Laboratory not stated" in flat
    assert "No statement of conformity: no procedure of this calibration defines tolerances" in flat
    pages, text = _render(tmp_path / "bare-technical.pdf")
    flat = " ".join(text.split())
    assert f"page {len(pages)} of {len(pages)}" in text
    assert "Residual analysis: not performed" in flat
    assert "System-level stage Not performed" in flat
    assert "no previous calibration record was given" in flat
    assert "No statement of conformity" in flat
    assert "instrument temperature (fine) not recorded in the data" in flat
    assert "Laboratory not recorded" in flat and "None: no value was entered by a person" in flat


@pytest.mark.parametrize(
    ("value", "expanded", "rule", "verdict"),
    [
        (8.0, 1.0, "guarded", "pass"),  # 8 ≤ 10 − 1
        (9.5, 1.0, "guarded", "fail"),  # inside T, inside the guard band
        (9.5, 1.0, "simple", "pass"),
        (10.5, 1.0, "simple", "fail"),
        (-9.5, 1.0, "non-binary", "conditional pass"),
        (10.5, 1.0, "non-binary", "conditional fail"),
        (11.5, 1.0, "non-binary", "fail"),
        (math.nan, 1.0, "simple", "fail"),
    ],
)
def test_decision_rules(value, expanded, rule, verdict):
    assert decide(value, expanded, 10.0, rule) == verdict


def test_tolerance_patterns_and_bad_tables():
    t = Tolerances.from_mapping({"limits": {"bias_*": 500.0, "bias_z": 100.0, "*": 1.0}})
    from stableins.reporting.tolerances import limit_for

    assert limit_for(t.limits, "bias_z") == 100.0 and limit_for(t.limits, "bias_x") == 500.0 and limit_for(t.limits, "sf_x") == 1.0
    with pytest.raises(InputError, match="decision rule"):
        Tolerances.from_mapping({"decision_rule": "lenient"}, source="p.toml")
    with pytest.raises(InputError, match="positive"):
        Tolerances.from_mapping({"limits": {"bias_x": -3}}, source="p.toml")


def test_gum_rounding():
    assert rounding.round_to_uncertainty(-260.8049, 0.6512) == "\u2212260.80"
    assert rounding.round_to_uncertainty(12345.6, 23.0) == "12346"
    assert rounding.significant_digits(0.0123456, 2) == "0.012"
    # U just below a power of ten rounds up to it: two significant digits of U = 9.989 are "10", the value to the units
    assert rounding.gum(-22.3477, 4.9946) == rounding.Rounded("\u221222", "5.0", "10")
    assert rounding.significant_digits(9.996, 2) == "10" and rounding.significant_digits(0.0999, 2) == "0.10"
    assert rounding.round_to_uncertainty(1.2345, 0.0999) == "1.23" and rounding.decimals_of(0.0999) == 2
    assert rounding.gum(3.0e-8, 4.99e-4) == rounding.Rounded("0.0000", "0.00050", "0.0010")  # U = 0.000998: 0.0010


def test_gum_writes_tiny_uncertainties_with_a_power_of_ten():
    # a gyro drift of 3.6e-8 °/h: fixed point to the last digit of U would need eight decimals
    assert rounding.gum(-3.566e-8, 3.25e-8) == rounding.Rounded("\u22123.6×10⁻⁸", "3.2×10⁻⁸", "6.5×10⁻⁸")
    assert rounding.gum(1e-7, 0.6e-7).u == "6.0×10⁻⁸"  # u keeps two significant digits, at its own power
    # one style in a column: every mantissa in [1, 10), each number to U's last digit (GUM 7.2.6), 0 below it
    assert rounding.gum(0.7e-5, 0.65e-5) == rounding.Rounded("7×10⁻⁶", "6.5×10⁻⁶", "1.3×10⁻⁵")
    assert rounding.gum(9.96e-6, 0.5e-5) == rounding.Rounded("1.0×10⁻⁵", "5.0×10⁻⁶", "1.0×10⁻⁵")  # 9.96 rounds up a power
    assert rounding.gum(-4e-8, 1.6e-6).value == "0"
    assert rounding.gum(174.94, 1.25) == rounding.Rounded("174.9", "1.2", "2.5")  # above 1e-3: fixed point as before


def test_budget_contributions_are_written_as_the_results_table_writes_u():
    """One notation for a parameter's numbers: the budget's cells (like_uncertainty) as gum writes u, tiny or not."""
    for u in (3.25e-8, 0.6e-7, 2.4e-4, 0.0123, 1.25):
        assert rounding.like_uncertainty(u, u) == rounding.gum(0.0, u).u
    assert "×10" in rounding.like_uncertainty(2.4e-4, 2.4e-4) and "×10" not in rounding.like_uncertainty(6e-4, 6e-4)  # U < 1e-3
    assert rounding.like_uncertainty(1.04e-8, 3.25e-8) == "1.0×10⁻⁸"  # a contribution at U's power, never 1.0e-08
    assert rounding.like_uncertainty(-4e-12, 3.25e-8) == "0" == rounding.like_uncertainty(0.0, 3.25e-8)  # below u's last digit
    assert rounding.superscript(-12) == "⁻¹²" and rounding.scientific(5e-7) == "5.0 × 10⁻⁷"


def test_bad_input_exits_2_and_writes_nothing(files, tmp_path, capsys):
    out = tmp_path / "r.pdf"
    (tmp_path / "broken.json").write_text('{"schema_version": 2, "serial_number": "X", "parameters": [')
    assert cli.main(["report", str(tmp_path / "broken.json"), "--out", str(out)]) == 2
    assert "broken.json" in capsys.readouterr().err and not out.exists()

    record = json.loads((files / "record.json").read_text())
    record["parameters"][0]["status"] = "guessed"
    (tmp_path / "status.json").write_text(json.dumps(record))
    assert cli.main(["report", str(tmp_path / "status.json"), "--out", str(out)]) == 2
    assert "parameters[0].status" in capsys.readouterr().err

    # A data file the calibration did not use is refused, and an existing report is left untouched.
    out.write_bytes(b"old report")
    (tmp_path / "other.csv").write_text("time[s]\n1\n")
    assert cli.main(["report", str(files / "record.json"), "--data", str(tmp_path / "other.csv"), "--out", str(out)]) == 2
    assert "other.csv" in capsys.readouterr().err
    assert out.read_bytes() == b"old report"
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".partial")] == []


def test_the_one_reader_rejects_asymmetric_covariance(files):
    record = json.loads((files / "record.json").read_text())
    record["covariance"]["matrix"][0][12] *= 3.0  # sf_x, K2_x: correlated (ρ ≈ 0.1)
    with pytest.raises(InputError, match="symmetric"):
        CalibrationRecord.from_document(record, "r.json")


def test_correlation_matches_fit(files):
    result = rf.fit(1)
    ids, matrix = content.correlation(CalibrationRecord.load(files / "record.json"))
    assert ids == result.ids
    np.testing.assert_allclose(matrix, result.correlation(), atol=1e-12)


@needs_poppler
def test_pipeline_certificate_shows_the_fits_the_calibration_printed(tmp_path, capsys):
    """simulate → calibrate device --json → report: χ²_ν of every fit on the certificate is the one calibrate printed;
    a version-1 record of the same calibration has its evidence recomputed from --data, and the report says so."""
    assert cli.main(["simulate", "device", "--seed", "5", "--out", str(tmp_path)]) == 0
    coarse, fine = tmp_path / "device-coarse.csv", tmp_path / "device-fine.h5"
    capsys.readouterr()
    argv = ["calibrate", "device", str(coarse), str(fine), "--out", str(tmp_path / "cal.json"), "--bias-instability", "2", "--json"]
    assert cli.main(argv) == 0
    printed = json.loads(capsys.readouterr().out)
    # dates consistent end to end: the device session ends before the system day that would be simulated next (ending now)
    from datetime import UTC, datetime, timedelta

    from stableins.conventions import SIDEREAL_DAY

    data_end = datetime.fromisoformat(CalibrationRecord.load(tmp_path / "cal.json").provenance.data_end)
    assert datetime.now(UTC) - data_end > timedelta(seconds=float(SIDEREAL_DAY))
    assert cli.main(["diagnose", str(coarse), str(fine), "--record", str(tmp_path / "cal.json"), "--stage", "coarse", "--json"]) == 0
    (tmp_path / "diag.json").write_text(capsys.readouterr().out)
    out = tmp_path / "cal.pdf"
    argv = ["report", str(tmp_path / "cal.json"), "--data", str(coarse), str(fine), "--discovery", str(tmp_path / "diag.json")]
    assert cli.main([*argv, "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    pages, text = _render(out)
    flat = " ".join(text.split())
    assert summary["pages"] == len(pages) and f"page {len(pages)} of {len(pages)}" in text and len(pages) <= 3
    assert certificate_checks.review(out, tmp_path) == []
    assert summary["technical_report"]["sha256"] == file_sha256(tmp_path / "cal-technical.pdf")
    pages, text = _render(tmp_path / "cal-technical.pdf")  # the evidence is in the technical report
    flat = " ".join(text.split())
    chi2 = {
        m.group(1): float(m.group(2))
        for m in re.finditer(r"^\s*(coarse\+fine|coarse|fine)\s+coarse\+fine\s+\d+\s+\d+ / \d+\s+([\d.]+)", text, re.M)
    }
    assert chi2 == {
        k: pytest.approx(printed[s]["chi2_red"], abs=5e-4) for k, s in (("coarse", "coarse"), ("fine", "fine"), ("coarse+fine", "fused"))
    }
    assert "bias instability 2 µg" in flat  # the settings the calibration ran with
    assert "recomputed" not in flat
    assert text.count("verified:") == 4  # both data files match the record's SHA-256, for each stage that read them (coarse+fine, gyro)
    diagnosis = json.loads((tmp_path / "diag.json").read_text())
    assert "From diag.json (stableins diagnose)" in flat and "Refit history" in flat
    assert plain(diagnosis["candidates"][0]["id"]) in text  # typeset: Kh_x prints as K with subscript h,x
    # the same record as schema version 1 (no stage runs): the evidence is recomputed, and the certificate says how
    record = CalibrationRecord.load(tmp_path / "cal.json")
    v1 = {k: v for k, v in record.to_document().items() if k not in ("calibration", "stages")}
    v1["schema_version"] = 1
    for p in v1["parameters"]:
        p.pop("determined_by")
    prov = record.provenance
    v1["provenance"] = {"software": prov.software, "procedure": prov.procedure, "stages": ["coarse", "fine"],
                        "inputs": [{"path": f.path, "sha256": f.sha256} for f in prov.inputs], "created": prov.created,
                        "data_start": prov.data_start, "data_end": prov.data_end}  # fmt: skip
    (tmp_path / "v1.json").write_text(json.dumps(v1))
    assert cli.main(["report", str(tmp_path / "v1.json"), "--data", str(coarse), str(fine), "--out", str(tmp_path / "v1.pdf")]) == 0
    _, text1 = _render(tmp_path / "v1-technical.pdf")
    flat1 = " ".join(text1.split())
    assert "recomputed from" in flat1 and "defaults of 'stableins calibrate device'" in flat1
    assert "record migrated from schema version 1" in flat1


@needs_poppler
def test_every_word_inside_the_page_and_optional_sections_render(files, tmp_path):
    """A discovery history renders as a table and a figure; nothing runs off the page."""
    record = json.loads((files / "record.json").read_text())
    # a discovered term and the history that kept it (the record's discovery section, docs/formats.md)
    record["parameters"].append({"id": "K3_x", "value": 2.1e-7, "unit": "s^4/m^3", "sigma": 1e-8, "status": "estimated"})
    record["covariance"]["ids"].append("K3_x")
    record["covariance"]["matrix"] = [row + [0.0] for row in record["covariance"]["matrix"]]
    record["covariance"]["matrix"].append([0.0] * (len(record["covariance"]["ids"]) - 1) + [1e-16])
    ids = [p["id"] for p in record["parameters"]]

    def step(label, rms, chi2, decision, added=(), p=None, dbic=None, reason=""):
        return {
            "label": label, "model": ids, "channels": ["f_x", "f_y", "f_z", "|f|"], "residual_rms": [r * 9.80665e-6 for r in rms],
            "noise_floor": [3e-5, 3e-5, 3e-5, 1e-5], "chi2_red": chi2, "dof": 108, "bic": 200.0,
            "added": [{"id": a, "estimate": 21.0, "sigma": 1.0, "unit": "ug/g^3"} for a in added], "shifts": {},
            "decision": decision, "delta_chi2": None, "p_value": p, "delta_bic": dbic, "reason": reason,
        }  # fmt: skip

    record["discovery"] = {
        "stage": "coarse+fine",
        "alpha": 0.05,
        "steps": [
            step("standard model", [42.0, 12.0, 9.0, 7.0], 12.8, "baseline"),
            step("+ K3_x", [3.2, 3.1, 3.0, 1.0], 0.98, "kept", ["K3_x"], 1e-30, -310.0, "K3_x = +21 ± 1 ug/g^3; kept in the record"),
            step("+ Kh_y", [3.2, 3.1, 3.0, 1.0], 0.99, "not supported", ["Kh_y"], 0.41, 4.1, "Kh_y: the data do not show it; left out"),
        ],
    }
    (tmp_path / "rich.json").write_text(json.dumps(record))
    out = tmp_path / "rich.pdf"
    assert cli.main(["report", str(tmp_path / "rich.json"), "--procedure", str(files / "proc.toml"), "--out", str(out)]) == 0
    assert certificate_checks.review(out, tmp_path) == []
    _, certificate = _render(out)
    assert "µg/g³" in certificate  # the results' units as printed
    out = tmp_path / "rich-technical.pdf"
    pages, text = _render(out)
    flat = " ".join(text.split())
    assert plain("K3_x") in text and plain("Kh_y") in text and "not supported" in text and "Model in force" in text
    numbers = [int(n) for n in re.findall(r"Figure (\d+)\.", flat)]
    assert numbers == list(range(1, len(numbers) + 1)) and len(numbers) == 3  # correlation, residuals, discovery
    bbox = subprocess.run(["pdftotext", "-bbox", str(out), "-"], check=True, capture_output=True, text=True, timeout=60).stdout
    page = re.search(r'<page width="([\d.]+)" height="([\d.]+)"', bbox)
    width, height = float(page.group(1)), float(page.group(2))
    words = re.findall(r'<word xMin="([\d.]+)" yMin="([\d.]+)" xMax="([\d.]+)" yMax="([\d.]+)">', bbox)
    assert len(words) > 500
    side = 18 * 72 / 25.4 - 1.0  # text frame: 18 mm side margins; header and footer stay 7 mm from the edge
    for x0, y0, x1, y1 in ((float(a), float(b), float(c), float(d)) for a, b, c, d in words):
        assert side < x0 and x1 < width - side and y0 > 20.0 and y1 < height - 20.0


def _self_signed(folder: Path) -> tuple[Path, Path]:
    """A self-signed RSA key and certificate (PEM), as a laboratory's quality manager would hold."""
    import datetime as dt

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import NameOID

    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "Quality Manager, Test Laboratory")])
    now = dt.datetime.now(dt.UTC)
    usage = x509.KeyUsage(True, True, False, False, False, True, True, False, False)
    cert = (
        x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key()).serial_number(7)
        .not_valid_before(now - dt.timedelta(days=1)).not_valid_after(now + dt.timedelta(days=30))
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True).add_extension(usage, critical=True)
        .sign(key, hashes.SHA256())
    )  # fmt: skip
    key_path, cert_path = folder / "key.pem", folder / "cert.pem"
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()))
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return key_path, cert_path


def test_signed_certificate_verifies_and_one_changed_byte_fails_with_the_reason(files, tmp_path, capsys):
    """report --sign signs the certificate (PAdES); check verifies the signature and the SHA-256 of the inputs it names."""
    key, cert = _self_signed(tmp_path)
    for name in ("device.csv", "record.json", "proc.toml"):
        shutil.copy(files / name, tmp_path / name)
    data = tmp_path / "device.csv"
    out = tmp_path / "signed.pdf"
    argv = ["report", str(tmp_path / "record.json"), "--data", str(data), "--procedure", str(tmp_path / "proc.toml"), "--operator", "A. P."]
    assert cli.main([*argv, "--sign", str(key), "--sign-cert", str(cert), "--out", str(out)]) == 0
    capsys.readouterr()
    assert cli.main(["check", str(out), "--trust", str(cert), "--json"]) == 0
    found = json.loads(capsys.readouterr().out)["files"][0]
    signature = found["signature"]
    assert signature.startswith("intact and valid, signed by Common Name: Quality Manager") and "signer trusted" in signature
    assert found["inputs"] == "4 of 4 verified by SHA-256"  # record, data, procedure and the technical report beside it
    # one byte changed inside what the signature covers: check fails and says why
    changed = bytearray(out.read_bytes())
    at = changed.index(b"/Title (") + 10
    changed[at] ^= 0x01
    (tmp_path / "changed.pdf").write_bytes(bytes(changed))
    assert cli.main(["check", str(tmp_path / "changed.pdf")]) == 2
    assert "the signed bytes were changed after signing" in capsys.readouterr().err
    # an input it names changed: check names it
    data.write_text(data.read_text() + "0.1,0.2\n")
    assert cli.main(["check", str(out)]) == 2
    assert "device.csv (" in capsys.readouterr().err
    # a key that is not one: an input error naming the file, nothing written
    assert cli.main([*argv, "--sign", str(data), "--out", str(tmp_path / "bad.pdf")]) == 2
    assert not (tmp_path / "bad.pdf").exists() and not (tmp_path / "bad-technical.pdf").exists()
