"""Bad input never gives a silently wrong calibration: a clear error, or a flagged position left out."""

import numpy as np
import pytest
from device_world import GRAVITY, device_columns, draw_truth

from stableins.errors import InputError
from stableins.estimators.coarse import calibrate_coarse
from stableins.estimators.dwell import DwellChecks, dwells_from_columns, summarize_dwell
from stableins.estimators.setting import DeviceSetting
from stableins.procedures.definition import load_procedure

PROCEDURE = load_procedure("device-coarse")
CHECKS = PROCEDURE.checks
TRUTH = draw_truth(np.random.default_rng(31), quadratic=False)


def _columns(**kw):
    return device_columns(TRUTH, PROCEDURE, sigma=1e-3, seed=kw.pop("seed", 1), **kw)


def _calibrate(cols, **kw):
    dwells = dwells_from_columns(cols, settle=5.0, checks=CHECKS, source="run.csv")
    return calibrate_coarse(dwells, setting=DeviceSetting(GRAVITY), expected_positions=PROCEDURE.positions, source="run.csv", **kw)


def _rows(cols, mask):
    return {k: v[mask] for k, v in cols.items()}


def test_clean_data_pass():
    fit = _calibrate(_columns())
    assert fit.details.left_out == {} and fit.rank == 14
    assert not any(n.startswith("warning:") for n in fit.notes)


def test_a_position_off_within_the_orientation_tolerance_is_not_silent():
    # 0.01 m/s^2 (about 1 mg) is far inside the 0.196 m/s^2 orientation check but 30σ of a dwell mean
    cols = _columns()
    cols["f_x"][cols["position"] == 4] += 0.01
    fit = _calibrate(cols)
    warnings = [n for n in fit.notes if n.startswith("warning:")]
    assert len(warnings) == 1 and "exceeds its 99.9 % quantile" in warnings[0]
    assert "largest normalized residuals: pos 4 f_x" in warnings[0]


def test_missing_position_is_an_error_naming_it():
    cols = _columns()
    with pytest.raises(InputError, match=r"positions \[7\] are missing") as info:
        _calibrate(_rows(cols, cols["position"] != 7))
    assert "run.csv" in str(info.value)
    fit = _calibrate(_rows(cols, cols["position"] != 7), allow_missing=True)
    assert "missing" in fit.details.left_out[7] and any("position 7 left out" in n for n in fit.notes)


def test_duplicated_position_is_an_error():
    cols = _columns()
    again = _rows(cols, cols["position"] == 3)
    doubled = {k: np.concatenate([cols[k], again[k]]) for k in cols}
    with pytest.raises(InputError, match="position 3 appears twice"):
        _calibrate(doubled)
    # position 3 commanded twice in a row (time_since_command restarts)
    idx = np.flatnonzero(cols["position"] == 3)
    inserted = {k: np.insert(cols[k], idx[-1] + 1, cols[k][idx]) for k in cols}
    with pytest.raises(InputError, match="commanded twice"):
        _calibrate(inserted)


def test_dwell_too_short_to_measure_noise_is_left_out():
    cols = _columns()
    keep = (cols["position"] != 4) | (cols["time_since_command"] < 5.1)  # 0.1 s of dwell: 10 samples
    fit = _calibrate(_rows(cols, keep))
    assert "too short to measure noise" in fit.details.left_out[4]
    assert 4 not in fit.positions()


def test_saturated_samples_are_left_out_and_a_histogram_is_not_a_rail():
    cols = _columns()
    sel = (cols["position"] == 11) & (cols["time_since_command"] >= 5.0)  # x up, about +g
    rail = np.quantile(cols["f_x"][sel], 0.7)
    cols["f_x"][sel] = np.minimum(cols["f_x"][sel], rail)  # piled up at one value, far inside the 3 g range
    sel2 = (cols["position"] == 2) & (cols["time_since_command"] >= 8.0) & (cols["time_since_command"] < 8.05)
    cols["f_y"][sel2] = 40.0  # beyond the range
    fit = _calibrate(cols)
    assert 11 not in fit.details.left_out  # clipping is read from the range only (issue 26), never from the histogram's shape
    assert "saturated" in fit.details.left_out[2]


def test_slew_inside_a_dwell_is_left_out():
    cols = _columns()
    sel = (cols["position"] == 13) & (cols["time_since_command"] >= 15.0)
    cols["angle_inner"][sel] += np.radians(0.5)
    cols["f_x"][sel] += 0.05
    fit = _calibrate(cols)
    assert "slew inside the dwell" in fit.details.left_out[13]


def test_non_finite_samples_are_left_out():
    cols = _columns()
    cols["f_z"][(cols["position"] == 5) & (cols["time_since_command"] > 10)] = np.nan
    assert "non-finite" in _calibrate(cols).details.left_out[5]


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda c: c.update(f_x=-c["f_x"]), "the x axis sign inverted"),
        (lambda c: c.update(f_y=-c["f_y"]), "the y axis sign inverted"),
        (lambda c: c.update(f_x=c["f_y"], f_y=c["f_x"]), "the x and y axes swapped"),
        (lambda c: c.update(f_y=c["f_z"], f_z=c["f_y"]), "the y and z axes swapped"),
    ],
)
def test_axis_wiring_errors_are_diagnosed(change, message):
    cols = _columns()
    change(cols)
    with pytest.raises(InputError, match=message):
        _calibrate(cols)


def test_other_gimbal_handedness_is_diagnosed():
    cols = device_columns(TRUTH, PROCEDURE, sigma=1e-3, seed=2, senses=(1, -1, 1, 1))
    with pytest.raises(InputError, match="other gimbal handedness"):
        _calibrate(cols)


def test_a_single_wrong_position_is_flagged_not_fitted():
    cols = _columns()
    sel = cols["position"] == 9
    cols["f_y"][sel] *= -1.0
    fit = _calibrate(cols)
    assert "does not match the commanded orientation" in fit.details.left_out[9]


def test_too_many_positions_left_out_is_an_error():
    cols = _columns()
    for p in (1, 7, 3, 9, 5, 11, 2, 4, 6, 8, 10, 12, 13):
        cols["f_x"][cols["position"] == p] = np.nan
    with pytest.raises(InputError, match="usable positions") as info:
        _calibrate(cols)
    assert "non-finite samples (NaN or inf) (positions 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13)" in str(info.value)


def test_missing_column_names_the_field():
    cols = _columns()
    del cols["f_y"]
    with pytest.raises(InputError) as info:
        dwells_from_columns(cols, source="run.csv")
    assert info.value.field == "f_y"


def test_block_noise_estimate_is_honest_for_correlated_noise():
    rng = np.random.default_rng(5)
    n, trials, rho = 2000, 300, 0.98  # AR(1) noise: correlation time 50 samples
    e = rng.normal(size=(trials, n))
    x = np.empty_like(e)
    x[:, 0] = e[:, 0] / np.sqrt(1 - rho**2)
    for i in range(1, n):
        x[:, i] = rho * x[:, i - 1] + e[:, i]
    sems = []
    for t in range(trials):
        f = np.stack([x[t], x[t], x[t]], axis=1) * 1e-4
        d = summarize_dwell(np.arange(n) / 100.0, f, np.zeros((n, 3)), np.zeros(3), position=1, checks=DwellChecks(noise_blocks=10))
        sems.append(d.sem[0])
        assert any("correlated noise" in k for k in d.notes)
    actual = x.mean(axis=1).std() * 1e-4
    assert np.median(sems) == pytest.approx(actual, rel=0.2)
    white = x.std(axis=1).mean() * 1e-4 / np.sqrt(n)
    assert white < 0.3 * actual  # the white estimate would overstate precision by >3x


def test_white_noise_uses_the_sample_scatter():
    rng = np.random.default_rng(6)
    f = 1e-3 * rng.normal(size=(2000, 3))
    d = summarize_dwell(np.arange(2000) / 100.0, f, np.zeros((2000, 3)), np.zeros(3), position=1)
    np.testing.assert_allclose(d.sem, f.std(axis=0, ddof=1) / np.sqrt(2000))
    assert d.notes == () and d.flags == ()
    assert d.sem.min() > 0


FINE = load_procedure("device-fine")
LAYOUTS = {"coarse": PROCEDURE.layout, "fine": FINE.layout}


def _fine_session(change=None, keep=None):
    """Coarse and fine dwells of one unit (fine dwells shortened to 60 s to keep the test fast)."""
    from device_world import ExactPlatform

    site = ExactPlatform(TRUTH).metadata
    coarse = dwells_from_columns(_columns(), settle=5.0, checks=CHECKS, source="coarse.csv")
    cols = device_columns(TRUTH, FINE, sigma=1e-3, seed=7, stage="fine", dwell=60.0)
    if change is not None:
        change(cols)
    if keep is not None:
        cols = _rows(cols, keep(cols))
    fine = dwells_from_columns(cols, settle=5.0, checks=FINE.checks, source="fine.csv")
    return coarse + fine, site


def test_fine_position_off_its_orientation_is_flagged_and_left_out():
    from stableins.estimators.device import calibrate_device

    def flip(cols):
        cols["f_y"][cols["position"] == 9] *= -1.0  # y up reads as y down: same |f|, wrong orientation

    dwells, site = _fine_session(flip)
    result = calibrate_device(dwells, site, layouts=LAYOUTS, source="fine.csv")
    assert "does not match the commanded orientation" in result.fine.details.left_out[9]
    assert 9 not in result.fine.positions() and len(result.fine.positions()) == 17


def test_fine_positions_missing_are_an_error_unless_allowed():
    from stableins.estimators.device import calibrate_device

    dwells, site = _fine_session(keep=lambda c: ~np.isin(c["position"], (4, 14)))
    with pytest.raises(InputError, match=r"fine-stage positions \[4, 14\] are missing"):
        calibrate_device(dwells, site, layouts=LAYOUTS, source="fine.csv")
    result = calibrate_device(dwells, site, layouts=LAYOUTS, allow_missing=True, source="fine.csv")
    assert result.fine.details.left_out == {4: "missing from the data", 14: "missing from the data"}
    assert result.fine.rank == 12


def test_too_few_usable_fine_positions_is_an_error_saying_why():
    from stableins.estimators.device import calibrate_device

    def clip(cols):
        for p in range(1, 7):
            cols["f_z"][(cols["position"] == p) & (cols["time_since_command"] > 10)] = np.nan

    dwells, site = _fine_session(clip)
    with pytest.raises(InputError, match="only 12 usable fine-stage positions") as info:
        calibrate_device(dwells, site, layouts=LAYOUTS, source="fine.csv")
    assert "non-finite samples (NaN or inf) (positions 1, 2, 3, 4, 5, 6)" in str(info.value)


def test_procedure_of_the_wrong_stage_is_an_error():
    from stableins.estimators.device import calibrate_device

    dwells, site = _fine_session()
    with pytest.raises(InputError, match="is a 'fine' procedure, given for the coarse stage") as info:
        calibrate_device(dwells, site, layouts={"coarse": FINE.layout, "fine": FINE.layout})
    assert info.value.field == "procedure.stage" and "device-fine.toml" in str(info.value)


def test_unit_of_the_other_handedness_is_warned_about_and_its_weak_terms_named():
    from device_world import ExactPlatform

    from stableins.estimators.device import calibrate_device

    senses = (1, -1, 1, 1)  # handedness −1, correctly described by the metadata: y never points down
    site = ExactPlatform(TRUTH, senses=senses).metadata
    coarse = dwells_from_columns(device_columns(TRUTH, PROCEDURE, sigma=1e-3, seed=1, senses=senses), settle=5.0, checks=CHECKS)
    cols = device_columns(TRUTH, FINE, sigma=1e-3, seed=7, stage="fine", dwell=60.0, senses=senses)
    fine = dwells_from_columns(cols, settle=5.0, checks=FINE.checks)
    result = calibrate_device(coarse + fine, site, layouts=LAYOUTS)
    for fit in (result.coarse, result.fine):
        assert any("designed for gimbal handedness +1" in n and "give -1" in n for n in fit.notes)
    weak = [n for n in result.fine.notes if n.startswith("warning: weakly determined")]
    assert len(weak) == 1 and all(k in weak[0] for k in ("sf_y", "bias_y", "K2_y"))
    # the default handedness gets neither warning
    dwells, site = _fine_session()
    clean = calibrate_device(dwells, site, layouts=LAYOUTS)
    assert not any("handedness" in n or "weakly determined" in n for fit in (clean.coarse, clean.fine) for n in fit.notes)


def test_procedure_settle_and_duplicate_checks_of_the_one_dwell_path():
    # The CLI path: dwells_from_columns(procedures=...) takes each step's settle time and the acceptance checks.
    cols = _columns()
    dwells = dwells_from_columns(cols, layouts={"coarse": PROCEDURE.layout}, source="run.csv")
    for d in dwells:
        rows = (cols["position"] == d.position) & (cols["time_since_command"] >= PROCEDURE.step(d.position).settle)
        assert d.samples == int(rows.sum())
    again = _rows(cols, cols["position"] == 3)
    doubled = {k: np.concatenate([cols[k], again[k]]) for k in cols}
    with pytest.raises(InputError, match="position 3 appears twice in coarse pass 1") as info:
        dwells_from_columns(doubled, layouts={"coarse": PROCEDURE.layout}, source="run.csv")
    assert info.value.field == "position" and info.value.row == cols["position"].size + 1 and "run.csv" in str(info.value)
    idx = np.flatnonzero(cols["position"] == 3)
    inserted = {k: np.insert(cols[k], idx[-1] + 1, cols[k][idx]) for k in cols}
    with pytest.raises(InputError, match="commanded twice") as info:
        dwells_from_columns(inserted, layouts={"coarse": PROCEDURE.layout}, source="run.csv")
    assert info.value.field == "time_since_command"


def test_cli_rejects_a_position_commanded_twice(tmp_path, capsys):
    from device_world import ExactPlatform

    from stableins.cli import main
    from stableins.data.device import save_device

    cols = _columns()
    idx = np.flatnonzero(cols["position"] == 3)
    inserted = {k: np.insert(cols[k], idx[-1] + 1, cols[k][idx]) for k in cols}
    inserted["time"] = np.arange(inserted["time"].size) * 0.01
    path = save_device(tmp_path / "coarse.csv", inserted, ExactPlatform(TRUTH).metadata)  # the file format allows it
    out = tmp_path / "record.json"
    assert main(["calibrate", "device", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "position 3 was commanded twice" in err and "coarse.csv" in err and "time_since_command" in err and "Traceback" not in err
    assert not out.exists()


def test_fine_stage_rejects_positions_not_in_its_procedure():
    from stableins.estimators.device import calibrate_device

    def renumber(cols):
        cols["position"][cols["position"] == 18] = 19

    dwells, site = _fine_session(renumber)
    with pytest.raises(InputError, match=r"fine-stage positions \[19\] are not in the procedure") as info:
        calibrate_device(dwells, site, layouts=LAYOUTS, allow_missing=True, source="fine.csv")
    assert info.value.field == "position"


def _quantized(rng, mean, sigma, step, n=2000):
    return np.round((mean + sigma * rng.normal(size=n)) / step) * step


def test_coarsely_quantized_healthy_dwell_is_not_called_clipped():
    rng = np.random.default_rng(12)
    sigma = 1e-3
    for offset in (0.0, 0.3, 0.45, 0.5):  # mean between two levels: two levels hold most samples
        for step in (3e-3, 5e-3, 1e-2):
            x = _quantized(rng, 9.8 + offset * step, sigma, step)
            f = np.stack([x, _quantized(rng, 0.01, sigma, step), _quantized(rng, -0.02, sigma, step)], axis=1)
            d = summarize_dwell(np.arange(2000) * 0.01, f, np.zeros((2000, 3)), np.zeros(3), position=1, checks=CHECKS)
            assert d.usable, (offset, step, d.flags)
    # finely quantized healthy noise is not clipped either
    f = np.stack([_quantized(rng, 9.8, sigma, 1e-4) for _ in range(3)], axis=1)
    assert summarize_dwell(np.arange(2000) * 0.01, f, np.zeros((2000, 3)), np.zeros(3), position=1, checks=CHECKS).usable


def test_integer_counts_far_from_the_range_are_not_clipped():
    # issue 26: real dwells of integer counts 400-1300 from zero on a 16-bit converter were taken for rails
    rng = np.random.default_rng(14)
    counts = np.stack([np.round(rng.normal(m, 0.6, 3000) + 0.3 * rng.standard_t(2, 3000)) for m in (412.0, -1297.0, 860.0)], axis=1)
    checks = DwellChecks(saturation=32767.0)
    d = summarize_dwell(np.arange(3000) * 0.01, counts, np.zeros((3000, 3)), np.zeros(3), position=1, checks=checks)
    assert d.usable, d.flags
    at_rail = counts.copy()
    at_rail[:5, 0] = 32767.0
    d = summarize_dwell(np.arange(3000) * 0.01, at_rail, np.zeros((3000, 3)), np.zeros(3), position=1, checks=checks)
    assert not d.usable


def test_truly_clipped_dwells_are_flagged():
    rng = np.random.default_rng(13)
    sigma = 1e-3
    # samples piled up 0.5σ above the mean, far inside the range: the histogram's shape is not a rail (issue 26)
    x = np.minimum(_quantized(rng, 9.8, sigma, 1e-4), 9.8 + 0.5 * sigma)
    f = np.stack([x, _quantized(rng, 0.0, sigma, 1e-4), _quantized(rng, 0.0, sigma, 1e-4)], axis=1)
    d = summarize_dwell(np.arange(2000) * 0.01, f, np.zeros((2000, 3)), np.zeros(3), position=1, checks=CHECKS)
    assert d.usable, d.flags
    # coarse quantization: samples at the stated full-scale range (one step below it, the top code)
    step = 4e-3
    full_scale = DwellChecks(saturation=9.8 + 0.5 * step)
    x = np.minimum(_quantized(rng, 9.8, sigma, step), 9.8)
    f = np.stack([x, _quantized(rng, 0.0, sigma, step), _quantized(rng, 0.0, sigma, step)], axis=1)
    d = summarize_dwell(np.arange(2000) * 0.01, f, np.zeros((2000, 3)), np.zeros(3), position=1, checks=full_scale)
    assert any("clipped samples on axis x" in flag for flag in d.flags)
    healthy = DwellChecks(saturation=3 * 9.80665)  # the same samples with the range far away are not called clipped
    assert summarize_dwell(np.arange(2000) * 0.01, f, np.zeros((2000, 3)), np.zeros(3), position=1, checks=healthy).usable


def test_cli_report_failure_leaves_no_record(tmp_path, capsys):
    from device_world import ExactPlatform

    from stableins.cli import main
    from stableins.data.device import save_device

    path = save_device(tmp_path / "coarse.csv", _columns(), ExactPlatform(TRUTH).metadata)
    out = tmp_path / "record.json"
    report = tmp_path / "report.txt"
    report.mkdir()  # the report cannot be written: a directory is in the way
    status = main(["calibrate", "device", str(path), "--out", str(out), "--report", str(report)])
    err = capsys.readouterr().err
    # refused when the arguments are parsed, before anything is computed or written
    assert status == 2 and "argument --report" in err and "is a directory (expected a file to write)" in err and "Traceback" not in err
    assert not out.exists() and not list(tmp_path.glob(".record.json.*"))
    # and with a writable report both are written
    assert main(["calibrate", "device", str(path), "--out", str(out), "--report", str(tmp_path / "ok.txt")]) == 0
    assert out.exists() and "coarse stage" in (tmp_path / "ok.txt").read_text()


def test_clipped_without_sorting_answers_as_the_levels_do():
    """Issue 30: the range test that skips the sort gives the answer of the levels and counts, near the rail too."""
    from stableins.estimators.dwell import _clipped

    def by_levels(x, full_scale):
        levels, counts = np.unique(x[np.isfinite(x)], return_counts=True)
        step = float(np.min(np.diff(levels))) if levels.size > 1 else 0.0
        return any(c >= 3 and abs(e) >= full_scale - step for e, c in ((levels[-1], counts[-1]), (levels[0], counts[0])))

    rng = np.random.default_rng(30)
    answers = set()
    for _ in range(400):
        step = 10.0 ** rng.uniform(-5, -1)
        x = np.round(rng.normal(rng.uniform(-10, 10), rng.uniform(0.2, 3) * step, int(rng.integers(3, 200))) / step) * step
        for full_scale in (float(np.max(np.abs(x))) + k * step for k in (-1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 40.0)):
            expected = by_levels(x, full_scale)
            assert _clipped(x, full_scale) == expected
            answers.add(expected)
    assert answers == {True, False}
