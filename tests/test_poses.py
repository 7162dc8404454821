"""Real logs in (issue 26): readers, hold detection, the pose fits, and `stableins calibrate poses`."""

import json

import numpy as np
import pytest
from device_world import GRAVITY, draw_truth, outputs

from stableins.cli import main
from stableins.conventions import STANDARD_GRAVITY
from stableins.data.holds import detect_holds, read_holds, write_holds
from stableins.data.logmap import layout_from_options
from stableins.data.rawlog import LogLayout, UnitKind, parse_unit, read_raw_log
from stableins.errormodel import ErrorModel
from stableins.errors import InputError
from stableins.estimators.coarse import calibrate_coarse
from stableins.estimators.dwell import DwellSummary
from stableins.estimators.fine import calibrate_fine
from stableins.estimators.poses import PoseModel, calibrate_poses, six_position, start_values, summarize_holds
from stableins.estimators.setting import DeviceSetting
from stableins.procedures.definition import load_procedure

COUNTS_PER_G = 4096.0
ZERO = 32768.0
RATE = 50.0
TRUTH = {"sf_x": 1.002, "sf_y": 0.997, "sf_z": 1.001, "bias_x": 0.05, "bias_y": -0.03, "bias_z": 0.08, "beta_xz": 2e-3, "beta_zy": -1e-3}


def _directions(rng, n):
    v = rng.normal(size=(n, 3))
    v[:6] = np.vstack([np.eye(3), -np.eye(3)])  # every axis up and down
    return v / np.linalg.norm(v, axis=1)[:, None]


def _counts_log(rng, poses=32, hold=8.0, move=2.0, noise_g=4e-4, rail=None, hidden=None):
    """A continuous log in offset-binary counts: holds of random orientation joined by shaky hand motion."""
    model = ErrorModel.standard(nonlinear=True) + ((hidden[0],) if hidden else ())
    truth = {**TRUTH, **({hidden[0].id: hidden[1]} if hidden else {})}
    up = _directions(rng, poses)
    t_hold, t_move = int(hold * RATE), int(move * RATE)
    parts = []
    for k in range(poses):
        f = np.repeat(GRAVITY * up[k][None], t_hold, axis=0)
        parts.append(f)
        if k + 1 < poses:
            s = np.linspace(0, 1, t_move)[:, None]
            path = (1 - s) * up[k] + s * up[k + 1]
            path = GRAVITY * path / np.linalg.norm(path, axis=1)[:, None]
            parts.append(path + 0.3 * GRAVITY * np.sin(np.pi * s) * rng.normal(size=(t_move, 3)))
    f = np.vstack(parts)
    out = model.forward(f, truth) + noise_g * STANDARD_GRAVITY * rng.normal(size=f.shape)
    counts = np.round(out / STANDARD_GRAVITY * COUNTS_PER_G + ZERO)
    if rail is not None:
        counts = np.minimum(counts, rail)
    return np.arange(len(counts)) / RATE, counts, up


def _write_csv(path, time, counts, header="t,ax,ay,az"):
    with open(path, "w") as handle:
        handle.write(header + "\n")
        for t, c in zip(time, counts, strict=True):
            handle.write(f"{t:.4f},{int(c[0])},{int(c[1])},{int(c[2])}\n")


LAYOUT = dict(columns="time=t,f_x=ax,f_y=ay,f_z=az", units=f"counts:{COUNTS_PER_G:g}/g", zero=f"{ZERO:g}", full_scale="0:65535")


def test_units_are_parsed_and_ambiguous_or_unknown_ones_refused():
    assert parse_unit("m/s^2").kind is UnitKind.SPECIFIC_FORCE
    assert parse_unit("g").scale == STANDARD_GRAVITY
    assert parse_unit("counts:4096/g").scale == pytest.approx(STANDARD_GRAVITY / 4096)
    assert parse_unit("counts:200/(m/s2)").scale == pytest.approx(1 / 200)
    assert parse_unit("dv:0.001").kind is UnitKind.PULSES
    with pytest.raises(InputError, match="ambiguous") as info:
        parse_unit("counts:4096", field_name="--units f_y")
    assert info.value.field == "--units f_y"
    with pytest.raises(InputError, match="unknown unit"):
        parse_unit("mg")
    with pytest.raises(InputError, match="no unit given for f_z"):
        LogLayout(columns={"time": "t", "f_x": "a", "f_y": "b", "f_z": "c"}, units={a: parse_unit("g") for a in ("f_x", "f_y")})


def test_reader_converts_counts_iso_time_headerless_and_refuses_a_backward_clock(tmp_path):
    path = tmp_path / "iso.csv"
    path.write_text(
        "time;x;y;z\n2024-05-01T12:00:00.00;10;-20;4096\n2024-05-01T12:00:00.50;11;-21;4095\n2024-05-01T12:00:01.00;12;-22;4097\n"
    )
    log = read_raw_log(path, layout_from_options("time=time,f_x=x,f_y=y,f_z=z", "counts:4096/g", time_unit="iso"))
    np.testing.assert_allclose(log.time, [0.0, 0.5, 1.0])
    np.testing.assert_allclose(log.specific_force[0], np.array([10, -20, 4096]) * STANDARD_GRAVITY / 4096)
    assert log.start_time.startswith("2024-05-01T12:00:00")
    bare = tmp_path / "bare.txt"
    bare.write_text("0.0 1 2 3\n0.1 1 2 3\n0.05 1 2 3\n")
    with pytest.raises(InputError, match="clock goes backwards") as info:
        read_raw_log(bare, layout_from_options("time=1,f_x=2,f_y=3,f_z=4", "g"))
    assert info.value.row == 3 and info.value.field == "1"
    with pytest.raises(InputError, match="no column 'acc_q'") as info:
        read_raw_log(path, layout_from_options("time=time,f_x=acc_q,f_y=y,f_z=z", "g", time_unit="iso"))
    assert info.value.field == "f_x"
    pulses = tmp_path / "dv.csv"
    pulses.write_text("t,a,b,c\n0,0,0,0\n0.01,2,-1,981\n0.02,2,-1,981\n")
    log = read_raw_log(pulses, layout_from_options("time=t,f_x=a,f_y=b,f_z=c", "dv:1e-4"))
    np.testing.assert_allclose(log.specific_force[0], [0.02, -0.01, 9.81])


def test_holds_are_detected_without_false_splits_and_the_table_round_trips(tmp_path):
    time, counts, up = _counts_log(np.random.default_rng(3))
    path = tmp_path / "log.csv"
    _write_csv(path, time, counts)
    log = read_raw_log(path, layout_from_options(**LAYOUT))
    detection = detect_holds(log.time, log.specific_force, resolution=log.resolution)
    assert len(detection.holds) == len(up)  # every hold found, none split
    for hold, direction in zip(detection.holds, up, strict=True):
        mean = log.specific_force[hold.first : hold.stop].mean(axis=0)
        assert mean @ direction > 0.97 * GRAVITY  # the right hold (biases and scale factors aside)
    table = tmp_path / "holds.csv"
    write_holds(table, log.time, log.specific_force, detection.holds)
    assert read_holds(table, log.time) == detection.holds


def test_poses_from_raw_counts_recover_the_truth_within_their_sigma(tmp_path):
    time, counts, _ = _counts_log(np.random.default_rng(4))
    path = tmp_path / "log.csv"
    _write_csv(path, time, counts)
    log = read_raw_log(path, layout_from_options(**LAYOUT))
    holds = detect_holds(log.time, log.specific_force, resolution=log.resolution).holds
    fit = calibrate_poses(summarize_holds(log.time, log.specific_force, log.railed, [(h.first, h.stop) for h in holds]), gravity=GRAVITY)
    assert fit.settings.model is PoseModel.TWELVE and not fit.details.left_out
    for k in ("sf_x", "sf_y", "sf_z", "bias_x", "bias_y", "bias_z"):
        value, sigma, _ = fit[k]
        assert abs(value - TRUTH[k]) < 5 * sigma, k
    assert fit.chi2_red < 2.0


READINGS = np.array([s.command for s in load_procedure("device-fine").steps])


def _dwells(means, sigma, stage):
    return [
        DwellSummary(p + 1, stage, 1, r, r, m, np.full(3, sigma), np.full(3, 1e-3), 1000, 600.0)
        for p, (r, m) in enumerate(zip(READINGS, means))
    ]


def test_poses_on_simulated_fine_dwells_equal_the_fine_stage():
    truth = draw_truth(np.random.default_rng(21))
    rng = np.random.default_rng(5)
    coarse = calibrate_coarse(
        _dwells(outputs(truth, READINGS) + 3e-5 * rng.normal(size=(18, 3)), 3e-5, "coarse"), setting=DeviceSetting(GRAVITY)
    )
    fine_dwells = _dwells(outputs(truth, READINGS) + 5e-6 * rng.normal(size=(18, 3)), 5e-6, "fine")
    fine = calibrate_fine(fine_dwells, coarse, gravity=GRAVITY)
    same_start = calibrate_poses(fine_dwells, gravity=GRAVITY, start=coarse)
    np.testing.assert_array_equal(same_start.values, fine.values)
    np.testing.assert_array_equal(same_start.covariance, fine.covariance)
    # from the holds' own start (no coarse stage): the same solution; the carried angle sums (0 instead of the
    # coarse values) move it only at second order in them
    own = calibrate_poses(fine_dwells, gravity=GRAVITY)
    assert own.chi2 == pytest.approx(fine.chi2, rel=1e-3)
    for k in ("sf_x", "sf_y", "sf_z", "bias_x", "bias_y", "bias_z", "K2_x", "K2_y", "K2_z"):
        assert abs(own[k][0] - fine[k][0]) < fine[k][1], k  # second order in the coarse angle sums (~1e-4 rad)
    for name, (value, sigma) in fine.combinations.items():
        assert abs(own.combinations[name][0] - value) < sigma, name


def test_six_positions_equal_the_half_sum_and_half_difference():
    rng = np.random.default_rng(6)
    labels = ["+x", "-x", "+y", "-y", "+z", "-z"]
    means = rng.normal(0, 0.01, size=(6, 3))
    sems = rng.uniform(1e-5, 5e-5, size=(6, 3))
    for k, lab in enumerate(labels):
        i = "xyz".index(lab[1])
        means[k, i] += (1.0 if lab[0] == "+" else -1.0) * GRAVITY * (1 + 0.01 * i) + 0.02 * (i + 1)
    dwells = [DwellSummary(k + 1, "poses", 1, np.zeros(3), np.zeros(3), means[k], sems[k], sems[k] * 30, 3000, 30.0) for k in range(6)]
    fit = six_position(dwells, labels, gravity=GRAVITY)
    for i, a in enumerate("xyz"):
        p, m = 2 * i, 2 * i + 1
        bias = 0.5 * (means[p, i] + means[m, i])
        k = (means[p, i] - means[m, i]) / (2 * GRAVITY)
        s = np.hypot(sems[p, i], sems[m, i])
        assert fit[f"bias_{a}"][0] == pytest.approx(bias, rel=1e-9, abs=0)
        assert fit[f"sf_{a}"][0] == pytest.approx(1 / k, rel=1e-9, abs=0)
        assert fit[f"bias_{a}"][1] == pytest.approx(0.5 * s, rel=1e-9)
        assert fit[f"sf_{a}"][1] == pytest.approx(s / (2 * GRAVITY) / k**2, rel=1e-9)
    assert fit.dof == 0
    with pytest.raises(InputError, match="no usable hold labelled -z"):
        six_position(dwells[:5], labels[:5], gravity=GRAVITY)


def test_start_values_from_raw_count_holds():
    dwells = [
        DwellSummary(k, "poses", 1, np.zeros(3), np.zeros(3), m, np.full(3, 1e-3), np.full(3, 1e-2), 100, 1.0)
        for k, m in enumerate(([3.0, 0, 0], [-1.0, 0, 0], [1, 2, -2]))
    ]
    values = start_values(dwells, 2.0)
    assert values["bias_x"] == 1.0 and values["sf_x"] == 1.0


def _cli(tmp_path, log, *extra):
    out = tmp_path / "cal.json"
    code = main(
        [
            "calibrate",
            "poses",
            str(log),
            "--columns",
            LAYOUT["columns"],
            "--units",
            LAYOUT["units"],
            "--zero",
            "32768",
            *extra,
            "--out",
            str(out),
        ]
    )
    return code, out


def test_cli_writes_the_record_holds_and_plot(tmp_path, capsys):
    time, counts, up = _counts_log(np.random.default_rng(7), poses=16)
    log = tmp_path / "log.csv"
    _write_csv(log, time, counts)
    code, out = _cli(
        tmp_path,
        log,
        "--range",
        "0:65535",
        "--gravity",
        f"{GRAVITY}",
        "--write-holds",
        str(tmp_path / "h.csv"),
        "--plot",
        str(tmp_path / "h.png"),
        "--json",
    )
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result["holds"] == 16 and result["model"] == "TWELVE"
    assert out.exists() and (tmp_path / "h.csv").exists() and (tmp_path / "h.png").stat().st_size > 1000
    # its certificate says what was done: static poses of a triad, not a gimbal self-calibration (issue 28)
    from certificate_checks import pages_text, technical_of

    from stableins.reporting import write_report

    write_report(tmp_path / "cert.pdf", out)
    certificate = " ".join("\n".join(pages_text(tmp_path / "cert.pdf")).split())
    technical = " ".join("\n".join(pages_text(technical_of(tmp_path / "cert.pdf"))).split())
    assert "Calibration of a tri-axis accelerometer from static poses" in certificate and "calibrated from static poses" in certificate
    assert "Static poses of an accelerometer triad" in technical and "calibrated from static poses" in technical
    assert not any(word in text for word in ("gimbaled", "self-calibration", "on the system") for text in (certificate, technical))


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("unit", "unknown unit"),
        ("column", "no column 'az'"),
        ("static", "no static hold found"),
        ("clock", "clock goes backwards"),
        ("saturated", "saturated samples"),
    ],
)
def test_bad_real_world_input_is_one_message_and_nothing_written(tmp_path, capsys, case, message):
    rng = np.random.default_rng(8)
    time, counts, _ = _counts_log(rng, poses=12)
    extra = ["--range", "0:65535"]
    if case == "static":  # turned slowly all the time (each window quiet, its mean moving)
        angle = 0.3 * time
        up = np.stack([np.cos(angle), np.sin(angle) * 0.8, np.sin(angle) * 0.6], axis=1)
        counts = np.round(ZERO + COUNTS_PER_G * up + rng.normal(0, 2.0, size=up.shape))
    if case == "clock":
        time = time.copy()
        time[500] = time[498]
    if case == "saturated":
        extra = ["--range", f"0:{ZERO + 0.5 * COUNTS_PER_G:g}"]  # every hold with an axis up rails
        counts = np.minimum(counts, ZERO + 0.5 * COUNTS_PER_G)
    log = tmp_path / "log.csv"
    _write_csv(log, time, counts, header="t,ax,ay,az" if case != "column" else "t,ax,ay,aq")
    if case == "unit":
        out = tmp_path / "cal.json"
        code = main(["calibrate", "poses", str(log), "--columns", LAYOUT["columns"], "--units", "counts:4096/furlong", "--out", str(out)])
    else:
        code, out = _cli(tmp_path, log, *extra, "--write-holds", str(tmp_path / "h.csv"))
    err = capsys.readouterr().err
    assert code == 2, err
    assert message in err and "Traceback" not in err
    assert err.count("stableins: error") <= 1
    assert not out.exists() and not (tmp_path / "h.csv").exists()


def test_hdf5_log_takes_its_range_from_the_integer_dtype(tmp_path):
    import h5py

    time, counts, _ = _counts_log(np.random.default_rng(9), poses=12)
    signed = (counts - ZERO).astype(np.int16)
    signed[100, 2] = np.iinfo(np.int16).max  # one sample at the converter's rail, inside hold 1
    path = tmp_path / "log.h5"
    with h5py.File(path, "w") as handle:
        handle["imu/t"] = time
        handle["imu/acc"] = signed
    layout = layout_from_options("time=imu/t,f_x=imu/acc:0,f_y=imu/acc:1,f_z=imu/acc:2", f"counts:{COUNTS_PER_G:g}/g")
    log = read_raw_log(path, layout)
    assert log.range_source == "HDF5 dtype" and log.full_scale[0] == (-32768.0, 32767.0)
    assert np.flatnonzero(log.railed).tolist() == [100]
    holds = detect_holds(log.time, log.specific_force, resolution=log.resolution).holds
    dwells = summarize_holds(log.time, log.specific_force, log.railed, [(h.first, h.stop) for h in holds])
    flagged = [d.position for d in dwells if not d.usable]
    assert all(d.usable for d in dwells if not (holds[d.position - 1].first <= 100 < holds[d.position - 1].stop))
    assert len(flagged) <= 1
    with pytest.raises(InputError, match="no dataset 'imu/q'"):
        read_raw_log(path, layout_from_options("time=imu/t,f_x=imu/q,f_y=imu/acc:1,f_z=imu/acc:2", "g"))


def test_check_reads_a_holds_table(tmp_path, capsys):
    table = tmp_path / "holds.csv"
    table.write_text("hold,start,end,samples,mean_x,mean_y,mean_z,std_x,std_y,std_z,orientation\n1,0.5,3.0,,,,,,,,+x\n2,4.0,6.0,,,,,,,,\n")
    assert main(["check", str(table)]) == 0
    assert "holds table" in capsys.readouterr().out
    table.write_text("hold,start,end,orientation\n1,0.5,3.0,up\n")
    assert main(["check", str(table)]) == 2
    assert "unknown orientation 'up'" in capsys.readouterr().err


def test_diagnose_finds_a_hidden_effect_in_the_holds_and_add_carries_it(tmp_path, capsys):
    from stableins.discovery.library import calibration_terms

    term = calibration_terms(["K3_x"])[0]
    time, counts, _ = _counts_log(np.random.default_rng(10), poses=40, hidden=(term, 300 * term.scale))
    log = tmp_path / "log.csv"
    _write_csv(log, time, counts)
    code, _ = _cli(tmp_path, log, "--gravity", f"{GRAVITY}", "--diagnose")
    assert code == 0
    err = capsys.readouterr().err
    assert "next: carry the flagged effect K3_x into the calibration" in err and "--add K3_x" in err
    code, out = _cli(tmp_path, log, "--gravity", f"{GRAVITY}", "--add", "K3_x", "--json")
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    k3 = result["parameters"]["K3_x"]
    assert abs(k3["value"] - 300 * term.scale) < 4 * k3["sigma"]
    assert any(n.startswith("added effect K3_x") and "kept" in n for n in result["notes"])


def test_mapping_file_and_per_axis_units(tmp_path):
    mapping = tmp_path / "logger.toml"
    toml = ["zero = [100, 200, 300]", 'time_unit = "ms"', "[units]", 'f_x = "counts:1000/g"', 'f_y = "counts:2000/g"', 'f_z = "g"']
    toml += ["[columns]", 'time = "ms"', 'f_x = "a"', 'f_y = "b"', 'f_z = "c"']
    mapping.write_text("\n".join(toml) + "\n")
    log_path = tmp_path / "log.csv"
    log_path.write_text("ms,a,b,c\n0,1100,2200,1.0\n10,1100,2200,1.0\n20,1100,2200,1.0\n")
    log = read_raw_log(log_path, layout_from_options(str(mapping), None))
    np.testing.assert_allclose(log.time, [0.0, 0.01, 0.02])
    np.testing.assert_allclose(log.specific_force[0], [STANDARD_GRAVITY, STANDARD_GRAVITY, STANDARD_GRAVITY * (1.0 - 300)])
    # options on the command line take precedence over the file
    log = read_raw_log(log_path, layout_from_options(str(mapping), "f_x=g,f_y=g,f_z=g", zero="1099.5,2199,0"))
    np.testing.assert_allclose(log.specific_force[0], np.array([0.5, 1.0, 1.0]) * STANDARD_GRAVITY)
    # converted, a value beyond any accelerometer (the data files' limits, ±10000 m/s^2) is refused naming the sample
    with pytest.raises(InputError, match="sample 1: 10787.3 m/s\\^2 is beyond any accelerometer") as caught:
        read_raw_log(log_path, layout_from_options(str(mapping), "f_x=g,f_y=g,f_z=g", zero="0"))
    assert caught.value.field == "f_x"
    with pytest.raises(InputError, match="unknown axis 'f_q'"):
        layout_from_options(str(mapping), "f_q=g")
