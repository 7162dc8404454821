"""CLI frame: lazy start-up, command groups, exit statuses, --json, progress."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import inprocess
import numpy as np
import pytest

from stableins import __version__, cli
from stableins.data.device import save_device
from stableins.progress import Progress, silence
from tests.test_formats import data_line_index, edit_lines, make_device_columns, make_metadata, make_system_chunk

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("numpy", "scipy", "filterpy", "matplotlib", "h5py")


def run_cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "stableins.cli", *args], capture_output=True, text=True, env=env, cwd=cwd, timeout=60)


# --------------------------------------------------------------------------- start-up
def test_help_and_version_import_nothing_heavy():
    code = textwrap.dedent(
        f"""
        import sys
        from stableins import cli
        for argv in (["--help"], ["--version"], ["check", "--help"]):
            try:
                cli.main(argv)
            except SystemExit:
                pass
            cli.build_parser(argv)
        heavy = sorted(m for m in {HEAVY!r} if m in sys.modules)
        print("HEAVY", heavy, file=sys.stderr)
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=60
    )
    assert done.returncode == 0, done.stderr
    assert "HEAVY []" in done.stderr


def test_help_lists_commands_and_version_answers():
    done = inprocess.run_cli(["--help"])
    assert done.returncode == 0 and "check" in done.stdout and "COMMAND" in done.stdout
    done = inprocess.run_cli(["--version"])
    assert done.returncode == 0 and done.stdout.strip() == f"stableins {__version__}"


def test_one_blas_thread_unless_the_user_set_one(monkeypatch):
    """cli.single_threaded_blas (also what tests/conftest.py gives the suite): 1 where unset, a set value kept."""
    for name in cli.BLAS_THREAD_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("MKL_NUM_THREADS", "3")
    cli.single_threaded_blas()
    assert [os.environ[name] for name in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")] == ["1", "3", "1"]


def test_no_command_prints_help_and_exits_2(capsys):
    assert cli.main([]) == 2
    assert "usage: stableins" in capsys.readouterr().err


def test_unknown_command_and_bad_option_exit_2(capsys):
    assert cli.main(["calibrat"]) == 2
    err = capsys.readouterr().err
    assert "stableins: error:" in err and "calibrat" in err
    assert cli.main(["check", "--bogus", "x.csv"]) == 2
    assert "unrecognized arguments: --bogus" in capsys.readouterr().err


# --------------------------------------------------------------------------- groups and dispatch
@pytest.fixture
def fake_commands(tmp_path, monkeypatch):
    """A package of fake command modules, and a COMMANDS table with a group using them."""
    package = tmp_path / "fakecmds"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "calibrate_device.py").write_text(
        textwrap.dedent(
            """
            def configure(parser):
                parser.add_argument("data")
                parser.add_argument("--passes", type=int, default=1)

            def run(args):
                from stableins.output import emit
                emit(args, {"data": args.data, "passes": args.passes}, f"device {args.data} x{args.passes}")
                return 0
            """
        )
    )
    (package / "calibrate_system.py").write_text("raise ImportError('must not be imported unless invoked')\n")
    (package / "interrupt.py").write_text("def configure(parser):\n    pass\n\ndef run(args):\n    raise KeyboardInterrupt\n")
    (package / "crash_input.py").write_text(
        "def configure(parser):\n    pass\n\n"
        "def run(args):\n    from stableins.errors import InputError\n"
        "    raise InputError('bad thing', path='f.csv', row=3, field='f_x', expected='a number')\n"
    )
    (package / "not_determined.py").write_text(
        "def configure(parser):\n    pass\n\n"
        "def run(args):\n    from stableins.errors import NotDeterminedError\n"
        "    raise NotDeterminedError('the data determine no parameter', field='stage', expected='one sidereal day')\n"
    )
    (package / "disk_full.py").write_text(
        "def configure(parser):\n    pass\n\ndef run(args):\n    import errno, os\n"
        "    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), 'out/system.h5')\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    table = {
        "calibrate": cli.Group(
            "calibrate from data",
            {
                "device": cli.Command("fakecmds.calibrate_device", "device-level stages"),
                "system": cli.Command("fakecmds.calibrate_system", "system-level stage"),
            },
        ),
        "interrupt": cli.Command("fakecmds.interrupt", "raises KeyboardInterrupt"),
        "crash": cli.Command("fakecmds.crash_input", "raises InputError"),
        "undetermined": cli.Command("fakecmds.not_determined", "raises NotDeterminedError"),
        "disk-full": cli.Command("fakecmds.disk_full", "raises OSError(ENOSPC)"),
    }
    monkeypatch.setattr(cli, "COMMANDS", table)
    return table


def test_group_dispatches_and_imports_only_the_invoked_module(fake_commands, capsys):
    assert cli.main(["calibrate", "device", "session.csv", "--passes", "3"]) == 0
    assert capsys.readouterr().out.strip() == "device session.csv x3"
    assert "fakecmds.calibrate_system" not in sys.modules
    assert cli.main(["calibrate", "device", "s.h5", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == {"data": "s.h5", "passes": 1}


def test_group_help_lists_subcommands_without_importing_them(fake_commands, capsys):
    assert cli.main(["calibrate", "--help"]) == 0
    out = capsys.readouterr().out
    assert "device" in out and "system-level stage" in out
    assert "fakecmds.calibrate_system" not in sys.modules


def test_group_without_subcommand_exits_2(fake_commands, capsys):
    assert cli.main(["calibrate"]) == 2
    assert "stableins: error:" in capsys.readouterr().err


def test_input_error_and_interrupt_statuses(fake_commands, capsys):
    assert cli.main(["crash"]) == 2
    err = capsys.readouterr().err
    assert err.strip() == "stableins: error: f.csv, row 3, field 'f_x': bad thing (expected a number)"
    assert cli.main(["undetermined"]) == 4  # the data do not determine what was asked: a status of its own
    err = capsys.readouterr().err
    assert err.strip() == "stableins: error: field 'stage': the data determine no parameter (expected one sidereal day)"
    assert cli.main(["interrupt"]) == 130
    assert cli.main(["disk-full"]) == 1
    assert (
        capsys.readouterr().err.strip() == "stableins: interrupted\nstableins: error: [Errno 28] No space left on device: 'out/system.h5'"
    )


def test_the_two_errors_are_distinct_value_errors():
    """Both are ValueErrors (issue 29), distinct, and carry no exit status (the CLI maps them)."""
    from stableins.errors import InputError, NotDeterminedError

    assert not issubclass(InputError, NotDeterminedError) and not issubclass(NotDeterminedError, InputError)
    assert issubclass(InputError, ValueError) and issubclass(NotDeterminedError, ValueError)
    assert not hasattr(InputError("x"), "exit_status")  # the CLI maps the statuses, the error carries none


def test_an_except_value_error_lets_the_described_error_through():
    """The diagnosis document's ``stage`` is read inside ``except ValueError`` (an unknown stage is re-worded there).

    A stage that is no string raises the reader's InputError, a ValueError now: it passes through with its own words,
    its file and its field, not the re-wording meant for an unknown stage.
    """
    from stableins.discovery.diagnose_report import DiagnoseReport
    from stableins.errors import InputError

    with pytest.raises(InputError) as raised:
        DiagnoseReport.from_json({"stage": 5}, "d.json")
    assert str(raised.value) == "d.json, field 'stage': 5 is not a string (expected a string)"
    with pytest.raises(InputError, match="'fine-ish' is not a stage"):
        DiagnoseReport.from_json({"stage": "fine-ish"}, "d.json")


# --------------------------------------------------------------------------- bad input through the CLI
def _bad_files(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    """One file per bad-input class, with a fragment the message must contain."""
    files = {}

    def device_csv(name, edit):
        path = save_device(tmp_path / f"{name}.csv", make_device_columns(), make_metadata())
        edit_lines(path, edit)
        return path

    def header(old, new):
        return lambda lines: [line.replace(old, new) if line.startswith("time[") else line for line in lines]

    def field(row, column, value):
        def edit(lines):
            k = data_line_index(lines, row)
            fields = lines[k].split(",")
            fields[column] = value
            lines[k] = ",".join(fields)
            return lines

        return edit

    files["missing"] = (device_csv("missing", header(",temperature[degC]", "")), "field 'temperature': missing column")
    files["misnamed"] = (device_csv("misnamed", header("f_z[", "fz[")), "did you mean 'f_z[m/s^2]'")
    files["unit"] = (device_csv("unit", header("time_since_command[s]", "time_since_command[ms]")), "unit 'ms' found")
    files["nan"] = (device_csv("nan", field(9, 13, "nan")), "row 9, field 'f_z'")
    files["time"] = (device_csv("time", field(30, 0, "0.0")), "row 30, field 'time'")
    files["duplicate"] = (device_csv("duplicate", field(120, 3, "1")), "occurs again")
    files["version"] = (device_csv("version", lambda lines: [x.replace('"schema_version": 1', '"schema_version": 3') for x in lines]), "3")
    cut = save_device(tmp_path / "cut.csv", make_device_columns(), make_metadata())
    cut.write_text(cut.read_text()[:-500])
    files["truncated_csv"] = (cut, "cut short")
    h5 = save_device(tmp_path / "cut.h5", make_device_columns(), make_metadata())
    h5.write_bytes(h5.read_bytes()[:3000])
    files["truncated_h5"] = (h5, "truncated or corrupt")
    from stableins.data.system import SystemRecordWriter

    gap = tmp_path / "gap.h5"
    chunk = make_system_chunk(0, 400)
    chunk["time"][200:] += 10.0
    with SystemRecordWriter(gap, make_metadata()) as writer:
        writer.append(chunk)
    files["gap"] = (gap, "row 201, field 'time': gap")
    return files


def test_every_bad_input_class_exits_2_with_a_message(tmp_path, capsys):
    for name, (path, fragment) in _bad_files(tmp_path).items():
        status = cli.main(["check", str(path)])
        err = capsys.readouterr().err
        assert status == 2, name
        assert err.startswith("stableins: error: ") and str(path) in err and fragment in err, (name, err)


def test_bad_input_in_a_real_process_has_no_traceback(tmp_path):
    files = _bad_files(tmp_path)
    for name in ("misnamed", "truncated_h5", "gap"):
        done = run_cli("check", str(files[name][0]))
        assert done.returncode == 2, (name, done.stderr)
        assert "Traceback" not in done.stderr and done.stderr.startswith("stableins: error:")


def test_check_json_output(tmp_path, capsys):
    path = save_device(tmp_path / "ok.h5", make_device_columns(), make_metadata())
    with h5py.File(path, "r") as f:
        assert f.attrs["complete"]
    assert cli.main(["check", str(path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)["files"][0]
    assert summary["kind"] == "device" and summary["rows"] == 120 and summary["dwells"] == 6


# --------------------------------------------------------------------------- progress and output
class FakeTerminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_is_silent_when_piped():
    stream = io.StringIO()
    with Progress(total=10, label="x", stream=stream) as progress:
        for _ in range(10):
            progress.update()
    assert stream.getvalue() == "" and progress.done == 10


def test_progress_draws_a_bar_on_a_terminal():
    stream = FakeTerminal()
    with Progress(total=4, label="simulate", stream=stream, width=8) as progress:
        progress.update(2)
        assert "[####....]  50%" in progress.line()
        progress.update(2)
    text = stream.getvalue()
    assert text.startswith("\rsimulate [") and "[########] 100%" in text and text.endswith("\n")
    # a step whose size becomes known later (a callback saying done, total), and --json/--quiet silence every bar
    stream = FakeTerminal()
    with Progress(label="report", stream=stream, width=8) as progress:
        progress.set(1, 4)
        assert "[##......]  25%" in progress.line()
    silence()
    try:
        quiet = FakeTerminal()
        with Progress(total=4, label="x", stream=quiet) as progress:
            progress.update(4)
        assert quiet.getvalue() == "" and progress.done == 4
    finally:
        silence(quiet=False)


def test_json_and_quiet_silence_progress(monkeypatch):
    from stableins import progress
    from stableins.cli import main

    seen = []
    monkeypatch.setattr("stableins.commands.simulate.run", lambda args: seen.append(progress.silenced()) or 0)
    for flags in (["--json"], [], ["--quiet"]):
        assert main(["simulate", "--list-effects", *flags]) == 0
    assert seen == [True, False, True] and not progress.silenced()  # the command's own run; restored after it


def test_progress_is_silent_in_a_real_pipe():
    code = "from stableins.progress import Progress, silence\np = Progress(100)\nfor _ in range(100): p.update()\np.close()\n"
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=60
    )
    assert done.returncode == 0 and done.stderr == "" and done.stdout == ""


def test_emit_json_handles_numpy_and_non_finite(capsys):
    from types import SimpleNamespace

    from stableins.output import emit

    emit(SimpleNamespace(json=True), {"a": np.arange(3), "b": np.float64(np.nan), "c": (1, Path("x"))})
    assert json.loads(capsys.readouterr().out) == {"a": [0, 1, 2], "b": None, "c": [1, "x"]}


# --------------------------------------------------------------------------- simulate
def simulate(tmp_path: Path, *extra: str, name: str = "sim") -> tuple[int, Path]:
    out = tmp_path / name
    # one pass at the nominal commands: these tests are about the files, not the zero-offset iteration
    argv = [
        "simulate",
        "device",
        "--out",
        str(out),
        "--procedure",
        "device-coarse",
        "--dwell",
        "1",
        "--settle",
        "0.5",
        "--no-iteration",
        *extra,
    ]
    return cli.main(argv), out


def test_simulate_device_writes_data_and_truth(tmp_path, capsys):
    from stableins.data.device import load_device
    from stableins.data.truth import load_truth

    status, out = simulate(tmp_path, "--seed", "4", "--json")
    assert status == 0
    result = json.loads(capsys.readouterr().out)
    assert sorted(p.name for p in out.iterdir()) == ["device-coarse.csv", "truth.json"]
    assert result["files"][0]["rows"] == 18 * 100 and result["seed"] == 4
    session = load_device(out / "device-coarse.csv")
    dwells = session.dwells(stage="coarse", pass_number=1)
    assert [d.position for d in dwells] == list(range(1, 19)) and all(len(d) == 100 for d in dwells)
    truth = load_truth(out / "truth.json")
    assert truth.seed == 4 and session.metadata.serial_number == truth.site.serial_number
    text = (out / "device-coarse.csv").read_text()
    assert "installed_calibration" not in text and "bias_x" not in text  # the data never carry the truth
    # |f| is gravity at every dwell (to the 1e-3 of the instrument errors)
    g = np.linalg.norm(np.array([d.specific_force.mean(axis=0) for d in dwells]), axis=1)
    np.testing.assert_allclose(g, truth.site.gravity, rtol=2e-3)


def test_simulate_is_reproducible_and_hidden_effects_reach_the_data(tmp_path, capsys):
    from stableins.data.device import load_device
    from stableins.data.truth import load_truth

    assert simulate(tmp_path, "--seed", "9", name="a")[0] == 0
    assert simulate(tmp_path, "--seed", "9", name="b")[0] == 0
    k3 = 1e-6  # s^4/m^2: 1e-3 m/s^2 at 1 g, far above the noise
    assert simulate(tmp_path, "--truth", str(tmp_path / "a" / "truth.json"), "--seed", "9", "--hidden", f"K3_x={k3}", name="c")[0] == 0
    a, b, c = (load_device(tmp_path / n / "device-coarse.csv") for n in "abc")
    np.testing.assert_array_equal(a.columns["f_x"], b.columns["f_x"])
    assert load_truth(tmp_path / "c" / "truth.json").effects == {"K3_x": k3}
    # same seed, same noise: the dwell means differ by the cubic term, to the quantizer's
    # resolution (its carry moves a dwell mean by at most one LSB / 100 samples = 1e-5 m/s^2)
    change = [(dc.specific_force[:, 0] - da.specific_force[:, 0]).mean() for da, dc in zip(a.dwells(), c.dwells())]
    expected = [(k3 * da.specific_force[:, 0] ** 3).mean() for da in a.dwells()]
    assert max(map(abs, expected)) > 9e-4
    np.testing.assert_allclose(change, expected, rtol=0, atol=2.5e-5)
    np.testing.assert_array_equal(c.columns["f_y"], a.columns["f_y"])


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        (["--hidden", "K3_x"], "is not ID=VALUE"),
        (["--hidden", "K3_x=big"], "'big' is not a value of K3_x"),
        (["--hidden", "K3_q=1e-6"], "'K3_q' is not an effect of the simulator"),
        (["--duration", "1h"], "--duration applies to system-level simulation only"),
        (["--dwell", "-1"], "-1 is out of range"),
        (["--procedure", "no-such-procedure"], "no-such-procedure"),
        (["--truth", "missing.json"], "missing.json"),
    ],
)
def test_simulate_bad_arguments_exit_2(tmp_path, capsys, argv, fragment):
    status, out = simulate(tmp_path, *argv)
    err = capsys.readouterr().err
    assert status == 2 and "stableins: error:" in err and fragment in err, err
    assert not (out / "device-coarse.csv").exists()


def test_simulate_into_an_unwritable_place_exits_2(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    status = cli.main(["simulate", "device", "--out", str(blocker / "sub"), "--procedure", "device-coarse", "--dwell", "1"])
    err = capsys.readouterr().err
    assert status == 2 and "argument --out" in err and f"{blocker} is a file, not a directory" in err  # refused when parsed


def test_simulate_list_effects(capsys):
    assert cli.main(["simulate", "device", "--list-effects", "--json"]) == 0
    effects = {e["id"]: e for e in json.loads(capsys.readouterr().out)["effects"]}
    assert effects["K3_x"]["unit"] == "s^4/m^2"


def test_simulate_system_streams_a_valid_record(tmp_path, capsys):
    from stableins.data.system import open_system_record
    from stableins.data.truth import load_truth

    out = tmp_path / "sys"
    assert cli.main(["simulate", "system", "--seed", "5", "--duration", "2min", "--rate", "50", "--out", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["files"][0]["rows"] == 6000 and sorted(p.name for p in out.iterdir()) == ["system.h5", "truth.json"]
    record = open_system_record(out / "system.h5")
    report = record.check_sampling()
    assert record.n_samples == 6000 and record.sample_rate == 50.0 and report.uniform
    truth = load_truth(out / "truth.json")
    assert record.metadata.damping["zeta"] == truth.damping["zeta"]  # the INS loop settings a site knows
    chunk = next(record.iter_chunks(["f_x", "f_y", "f_z"], rows=1000))
    g = np.linalg.norm([chunk[name].mean() for name in ("f_x", "f_y", "f_z")])
    assert g == pytest.approx(truth.site.gravity, rel=2e-3)  # a static platform measures gravity
    assert cli.main(["simulate", "system", "--out", str(out), "--procedure", "device-coarse"]) == 2
    assert "device-level simulation only" in capsys.readouterr().err


def test_simulate_device_runs_the_zero_offset_iteration_then_fine_at_repointed_positions(tmp_path, capsys):
    from stableins.conventions import ARCSEC
    from stableins.data.device import load_device
    from stableins.data.truth import load_truth

    out = tmp_path / "session"
    argv = ["simulate", "device", "--out", str(out), "--seed", "11", "--dwell", "5", "--settle", "1", "--json"]
    assert cli.main(argv) == 0
    files = {f["procedure"]: f for f in json.loads(capsys.readouterr().out)["files"]}
    assert files["device-coarse"]["passes"] >= 2 and files["device-fine"]["passes"] == 1
    coarse = load_device(files["device-coarse"]["path"])
    fine = load_device(files["device-fine"]["path"])
    truth = load_truth(out / "truth.json")
    first = coarse.dwells(stage="coarse", pass_number=1)
    last = coarse.dwells(stage="coarse", pass_number=files["device-coarse"]["passes"])
    assert [d.position for d in first] == [d.position for d in last] == list(range(1, 19))
    # pass 1 is commanded at the nominal readings; later passes and the fine dwells are re-pointed by
    # -theta20_hat, -theta30_hat, which must approach the true offsets (60 arcsec class) to a few arcsec
    nominal = np.array([d.command for d in first])
    for dwells in (last, fine.dwells(stage="fine")):
        shift = np.array([d.command for d in dwells]) - nominal
        np.testing.assert_allclose(shift[:, 0], 0.0, atol=1e-12)
        for column, offset_id in ((1, "theta20"), (2, "theta30")):
            assert np.ptp(shift[:, column]) < 1e-12
            assert abs(shift[0, column] + truth.parameters[offset_id]) < 5 * ARCSEC
