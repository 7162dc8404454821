"""Mutation fuzzing of the commands added since ``tests/fuzzing.py`` was written (issue 31).

``budget``, ``design``, ``campaign``, ``noise``, ``calibrate poses``, ``calibrate system --systematic``,
``calibrate drift``, ``calibrate thermal``, ``calibrate lever``, ``recal --estimate``, ``report --procedure`` and the
procedure kinds shipped since (``device-rotating``, ``device-thermal``, ``drift-two-position``,
``drift-three-position``, ``field-recal-device``, ``system-indexed``, ``system-static``).  Each case mutates one input of
a command whose unmutated form the command accepts (:data:`VALID_BASE` says which ones: the drift, thermal and lever
stages need records of their own tests, so their base is refused and only tracebacks, exits and files left count), or
gives one of its options a value that is not a finite number, and classifies the outcome with :mod:`fuzzing`'s oracle.
``tests/test_fuzz.py`` runs a few fixed cases of every kind, ``benchmarks/bench_fuzz.py`` many.
"""

from __future__ import annotations

import random
import shutil
from collections.abc import Callable
from pathlib import Path

import fuzzing as fz
import numpy as np

#: Option values no numeric option may accept (not numbers, not finite, beyond a double).
NOT_A_NUMBER = ("nan", "inf", "-inf", "1e400", "abc", "", "0x10", "1_0", "\uff15")
#: Procedure kinds shipped since the fuzz suite was written (it fuzzed device-fine only).
NEW_PROCEDURES = (
    "device-rotating",
    "device-thermal",
    "drift-two-position",
    "drift-three-position",
    "field-recal-device",
    "system-indexed",
    "system-static",
)
#: Extra TOML mutations of a procedure given to ``report --procedure``: what ``run`` refuses (issue 31).
REPORT_PROCEDURE_OPS = (*fz.TOML_OPS, "unknown_section", "empty")


class CommandInputs:
    """Valid inputs of the newer commands, built once beside a :class:`fuzzing.Workspace`."""

    def __init__(self, ws: fz.Workspace) -> None:
        from stableins import cli
        from stableins.errormodel import CORE_TERMS
        from stableins.procedures.definition import PROCEDURE_DIRECTORY

        self.ws = ws
        root = ws.root / "commands"
        root.mkdir(exist_ok=True)
        self.root = root
        # a record with the unit's noise model (what the system stages need as their prior)
        self.noisy_record = root / "noisy.json"
        status = cli.main(["noise", str(ws.system_h5), "--record", str(ws.record), "--out", str(self.noisy_record)])
        assert status == 0, "the workspace's noise record"
        # recal's estimate: a device calibration of the device data's unit, and an earlier record of that unit in force
        self.device_serial = "TEST-1"
        self.estimate = root / "estimate.json"
        status = cli.main(["calibrate", "device", str(ws.device_csv), "--out", str(self.estimate)])
        assert status == 0, "the workspace's device calibration"
        values = {t.id: float(t.reference) for t in CORE_TERMS}
        sigmas = {t.id: 10.0 * float(t.nominal) for t in CORE_TERMS}
        self.in_force = root / "in-force.json"
        record = fz.make_record(self.device_serial, "2025-04-01T09:30:00+00:00", values, sigmas, inputs=(("old.csv", "1" * 64),))
        record.save(self.in_force)
        self.coarse_procedure = root / "device-coarse.toml"
        self.coarse_procedure.write_text((PROCEDURE_DIRECTORY / "device-coarse.toml").read_text(encoding="utf-8"), encoding="utf-8")
        self.procedures = {name: (PROCEDURE_DIRECTORY / f"{name}.toml").read_text(encoding="utf-8") for name in NEW_PROCEDURES}
        self.campaign = root / "campaign.toml"
        self.campaign.write_text(
            '[campaign]\nname = "fuzz"\nfirst_seed = 11\ndevices = 2\ndiagnose = false\n\n'
            '[[procedure]]\nname = "wu"\ncoarse = "device-coarse"\nfine = "device-fine"\npasses = 2\n\n'
            '[[noise]]\nname = "quartz"\npreset = "quartz"\n\n[[hidden]]\nname = "kcc"\neffects = { Kcc_xxy = 6e-6 }\n',
            encoding="utf-8",
        )
        self.raw_log = root / "imu.csv"
        self.raw_log.write_text(_raw_log(np.random.default_rng(2)), encoding="utf-8")


def _raw_log(rng: np.random.Generator, poses: int = 16, hold: int = 400, move: int = 100) -> str:
    """A continuous log of an ideal triad in m/s² at 50 Hz: holds of random orientation joined by motion."""
    up = rng.normal(size=(poses, 3))
    up[:6] = np.vstack([np.eye(3), -np.eye(3)])
    up /= np.linalg.norm(up, axis=1)[:, None]
    parts = []
    for k in range(poses):
        parts.append(np.repeat(9.80665 * up[k][None], hold, axis=0))
        if k + 1 < poses:
            s = np.linspace(0, 1, move)[:, None]
            path = (1 - s) * up[k] + s * up[k + 1]
            parts.append(9.80665 * path / np.linalg.norm(path, axis=1)[:, None] + 3.0 * np.sin(np.pi * s) * rng.normal(size=(move, 3)))
    f = np.vstack(parts) + 4e-3 * rng.normal(size=(sum(len(p) for p in parts), 3))
    rows = [f"{k / 50.0:.3f},{a:.6f},{b:.6f},{c:.6f}" for k, (a, b, c) in enumerate(f)]
    return "t,ax,ay,az\n" + "\n".join(rows) + "\n"


def _mutate_raw_log(text: str, rng: random.Random, op: str) -> tuple[bytes, str, bool | None]:
    """One mutation of a raw log: (bytes, what, must it be refused?)."""
    lines = text.splitlines(keepends=True)
    k = rng.randrange(1, len(lines))
    if op == "bad_number":
        fields = lines[k].rstrip("\n").split(",")
        token = rng.choice(fz.BAD_NUMBER_TOKENS)
        fields[rng.randrange(len(fields))] = token
        lines[k] = ",".join(fields) + "\n"
        return "".join(lines).encode(), f"row {k}: {token!r}", True
    if op == "backwards":
        j = rng.randrange(1, len(lines) - 1)
        lines[j], lines[j + 1] = lines[j + 1], lines[j]
        return "".join(lines).encode(), f"rows {j} and {j + 1} swapped (time runs back)", True
    if op == "header":
        lines[0] = lines[0].replace(rng.choice(["t", "ax", "ay", "az"]), "q", 1)
        return "".join(lines).encode(), "a named column missing", True
    if op == "truncate":
        data = "".join(lines).encode()
        cut = rng.randrange(1, len(data))
        return data[:cut], f"cut at byte {cut}", None
    if op == "bytes":
        data = bytearray("".join(lines).encode())
        for _ in range(rng.randint(1, 4)):
            data[rng.randrange(len(data))] = rng.randrange(256)
        return bytes(data), "random bytes", None
    if op == "huge":
        fields = lines[k].rstrip("\n").split(",")
        fields[rng.randrange(1, 4)] = rng.choice(["1e300", "-1e300", "1e30"])
        lines[k] = ",".join(fields) + "\n"
        return "".join(lines).encode(), f"row {k}: specific force beyond any accelerometer", True
    raise ValueError(op)


RAW_LOG_OPS = ("bad_number", "backwards", "header", "truncate", "bytes", "huge")


def _toml_op(text: str, rng: random.Random, op: str) -> tuple[bytes, str, bool | None]:
    """A TOML mutation; one that finds nothing to change in ``text`` (no ``noise_blocks``, no position 5) leaves it valid."""
    if op == "unknown_section":
        return (text + "\n[bogus]\nx = 1\n").encode(), "unknown section [bogus]", True
    if op == "empty":
        return b"", "empty file", True
    data, what, must = fz.mutate_toml(text, rng, op)
    return data, what, (False if data == text.encode() else must)


# --------------------------------------------------------------------------- cases
def case_budget_record(ci: CommandInputs, rng: random.Random, op: str) -> fz.Result:
    directory = ci.ws.case_directory()
    data, what, must = fz.mutate_json(ci.ws.record.read_text(encoding="utf-8"), rng, op, free_paths=(("site", "extra"),))
    path = fz._write(directory, "record.json", data)
    return fz.run_cli(["budget", str(path), "--latitude", "40", "--duration", "5d", "--json"], f"budget record {what}", must, directory)


def case_design_procedure(ci: CommandInputs, rng: random.Random, op: str) -> fz.Result:
    directory = ci.ws.case_directory()
    data, what, must = _toml_op(ci.coarse_procedure.read_text(encoding="utf-8"), rng, op)
    path = fz._write(directory, "device-coarse.toml", data)
    out = directory / "out"
    out.mkdir()
    argv = ["design", str(path), "--white", "4.5e-4", "--bias-instability", "2", "--json"]
    return fz.run_cli(argv, f"design procedure {what}", must, out)


def case_campaign_file(ci: CommandInputs, rng: random.Random, op: str) -> fz.Result:
    from stableins.campaign.config import load_campaign
    from stableins.errors import InputError

    directory = ci.ws.case_directory()
    data, what, must = _toml_op(ci.campaign.read_text(encoding="utf-8"), rng, op)
    path = fz._write(directory, "campaign.toml", data)
    return fz.run_call(lambda: load_campaign(path), f"campaign {what}", must, (InputError,))


def case_noise_h5(ci: CommandInputs, rng: random.Random, op: str) -> fz.Result:
    directory = ci.ws.case_directory()
    path = directory / "system.h5"
    shutil.copyfile(ci.ws.system_h5, path)
    what, must = fz.mutate_h5(path, rng, op, "system")
    out = directory / "out"
    out.mkdir()
    argv = ["noise", str(path), "--record", str(ci.ws.record), "--out", str(out / "noise.json")]
    return fz.run_cli(argv, f"noise system h5 {what}", must, out)


def case_noise_record(ci: CommandInputs, rng: random.Random, op: str) -> fz.Result:
    directory = ci.ws.case_directory()
    data, what, must = fz.mutate_json(ci.ws.record.read_text(encoding="utf-8"), rng, op, free_paths=(("site", "extra"),))
    path = fz._write(directory, "record.json", data)
    out = directory / "out"
    out.mkdir()
    argv = ["noise", str(ci.ws.system_h5), "--record", str(path), "--out", str(out / "noise.json")]
    return fz.run_cli(argv, f"noise --record {what}", must, out)


def case_poses_log(ci: CommandInputs, rng: random.Random, op: str) -> fz.Result:
    directory = ci.ws.case_directory()
    data, what, must = _mutate_raw_log(ci.raw_log.read_text(encoding="utf-8"), rng, op)
    path = fz._write(directory, "imu.csv", data)
    out = directory / "out"
    out.mkdir()
    argv = ["calibrate", "poses", str(path), "--columns", "time=t,f_x=ax,f_y=ay,f_z=az", "--units", "m/s2", "--out", str(out / "c.json")]
    return fz.run_cli(argv, f"poses log {what}", must, out)


def case_systematic_prior(ci: CommandInputs, rng: random.Random, op: str) -> fz.Result:
    directory = ci.ws.case_directory()
    data, what, must = fz.mutate_json(ci.noisy_record.read_text(encoding="utf-8"), rng, op, free_paths=(("site", "extra"),))
    path = fz._write(directory, "prior.json", data)
    out = directory / "out"
    out.mkdir()
    argv = ["calibrate", "system", str(ci.ws.system_h5), "--prior", str(path), "--systematic", "--out", str(out / "c.json")]
    return fz.run_cli(argv, f"systematic prior {what}", must, out)


Case = Callable[[CommandInputs, random.Random, str], fz.Result]


def _stage_with_mutated_prior(stage: str, data_file: Callable[[CommandInputs], Path]) -> Case:
    def case(ci: CommandInputs, rng: random.Random, op: str) -> fz.Result:
        directory = ci.ws.case_directory()
        data, what, must = fz.mutate_json(ci.noisy_record.read_text(encoding="utf-8"), rng, op, free_paths=(("site", "extra"),))
        path = fz._write(directory, "prior.json", data)
        out = directory / "out"
        out.mkdir()
        argv = ["calibrate", stage, str(data_file(ci)), "--prior", str(path), "--out", str(out / "c.json")]
        return fz.run_cli(argv, f"{stage} prior {what}", must, out)

    return case


def case_recal_estimate(ci: CommandInputs, rng: random.Random, op: str) -> fz.Result:
    directory = ci.ws.case_directory()
    data, what, must = fz.mutate_json(ci.estimate.read_text(encoding="utf-8"), rng, op, free_paths=(("site", "extra"),))
    path = fz._write(directory, "estimate.json", data)
    out = directory / "recal"
    argv = ["recal", "--unit", ci.device_serial, "--prior", str(ci.in_force), "--estimate", str(path), "--out", str(out)]
    argv += ["--no-file", "--yes"]  # --yes: no prompt for the operator (the fuzz has no person at the keyboard)
    return fz.run_cli(argv, f"recal estimate {what}", must, directory)


def case_report_procedure(ci: CommandInputs, rng: random.Random, op: str) -> fz.Result:
    directory = ci.ws.case_directory()
    data, what, must = _toml_op(ci.procedures["system-static"], rng, op)
    path = fz._write(directory, "procedure.toml", data)
    out = directory / "out"
    out.mkdir()
    argv = ["report", str(ci.ws.record), "--procedure", str(path), "--no-statement", "--out", str(out / "r.pdf")]
    return fz.run_cli(argv, f"report --procedure {what}", must, out)


def case_new_procedure(ci: CommandInputs, rng: random.Random, op: str) -> fz.Result:
    """A shipped procedure of a newer kind, mutated, through the loader ``stableins run`` calls before the platform moves."""
    from stableins.commands.run import load_plan
    from stableins.errors import InputError

    name = rng.choice(NEW_PROCEDURES)
    directory = ci.ws.case_directory()
    data, what, must = _toml_op(ci.procedures[name], rng, op)
    path = fz._write(directory, f"{name}.toml", data)
    return fz.run_call(lambda: load_plan(str(path), None, None), f"procedure {name} {what}", must, (InputError,))


# --------------------------------------------------------------------------- option values that are not numbers
POSES = ("calibrate", "poses", "{log}", "--columns", "time=t,f_x=ax,f_y=ay,f_z=az", "--units", "m/s2", "--out", "{out}/c.json")
#: (command argv with ``{name}`` placeholders, option, how many values it takes): every numeric option of the newer commands.
NUMERIC_OPTIONS: tuple[tuple[tuple[str, ...], str, int], ...] = (
    (("budget", "{record}", "--latitude", "40"), "--duration", 1),
    (("budget", "{record}"), "--latitude", 1),
    (("budget", "{record}", "--latitude", "40"), "--damping", 1),
    (("budget", "{record}", "--latitude", "40"), "--drift", 3),
    (("design", "{coarse}", "--bias-instability", "2"), "--white", 1),
    (("design", "{coarse}", "--white", "4.5e-4"), "--bias-instability", 1),
    (("design", "{coarse}", "--white", "4.5e-4"), "--random-walk", 1),
    (("design", "{coarse}", "--white", "4.5e-4"), "--quantization", 1),
    (("design", "{coarse}", "--white", "4.5e-4"), "--passes", 1),
    (("design", "{coarse}", "--white", "4.5e-4"), "--sample-rate", 1),
    (("design", "{coarse}", "--white", "4.5e-4", "--match", "--out", "{out}"), "--min-dwell", 1),
    (("design", "{coarse}", "--white", "4.5e-4", "--match", "--out", "{out}"), "--max-dwell", 1),
    (("design", "{coarse}", "--white", "4.5e-4", "--criterion", "D"), "--budget", 1),
    (("campaign", "{campaign}", "--out", "{out}"), "--workers", 1),
    (("noise", "{system}"), "--confidence", 1),
    (POSES, "--gravity", 1),
    (POSES, "--window", 1),
    (POSES, "--min-hold", 1),
    (POSES, "--false-split", 1),
    ((*POSES[:4], "f_x=ax,f_y=ay,f_z=az", *POSES[5:]), "--rate", 1),
    ((*POSES[:6], "counts:4096/g", *POSES[7:]), "--zero", 1),
    (("calibrate", "lever", "{device}", "--prior", "{noisy}", "--out", "{out}/c.json"), "--window", 1),
    (("calibrate", "system", "{system}", "--prior", "{noisy}", "--systematic", "--out", "{out}/c.json"), "--bias-instability", 1),
    (
        ("recal", "--unit", "TEST-1", "--prior", "{in_force}", "--estimate", "{estimate}", "--out", "{out}/r", "--no-file", "--yes"),
        "--retries",
        1,
    ),
)


def case_numeric_option(ci: CommandInputs, index: int, value: str) -> fz.Result:
    """A numeric option of a newer command given ``value`` that is not a finite number: refused (exit 2), nothing written."""
    argv, option, count = NUMERIC_OPTIONS[index]
    directory = ci.ws.case_directory()
    out = directory / "out"
    out.mkdir()
    names = {
        "record": ci.ws.record, "coarse": ci.coarse_procedure, "campaign": ci.campaign, "out": out, "system": ci.ws.system_h5,
        "log": ci.raw_log, "device": ci.ws.device_h5, "noisy": ci.noisy_record, "in_force": ci.in_force, "estimate": ci.estimate,
    }  # fmt: skip
    tokens = [a.format(**names) for a in argv] + [option, value] + ["0"] * (count - 1)
    return fz.run_cli(tokens, f"{' '.join(argv[:2])} {option} {value!r}", True, out)


#: Every kind: (name, operators, case, does the command accept the unmutated input?).
KINDS: tuple[tuple[str, tuple[str, ...], Case, bool], ...] = (
    ("budget, record", fz.JSON_OPS, case_budget_record, True),
    ("design, procedure", fz.TOML_OPS, case_design_procedure, True),
    ("campaign, file", ("value", "non_utf8", "delete", "truncate", "unknown_section", "empty"), case_campaign_file, True),
    ("noise, system HDF5", fz.H5_OPS, case_noise_h5, True),
    ("noise --record", fz.JSON_OPS, case_noise_record, True),
    ("calibrate poses, raw log", RAW_LOG_OPS, case_poses_log, True),
    ("calibrate system --systematic, prior", fz.JSON_OPS, case_systematic_prior, False),
    ("calibrate drift, prior", fz.JSON_OPS, _stage_with_mutated_prior("drift", lambda ci: ci.ws.system_h5), False),
    ("calibrate thermal, prior", fz.JSON_OPS, _stage_with_mutated_prior("thermal", lambda ci: ci.ws.device_h5), False),
    ("calibrate lever, prior", fz.JSON_OPS, _stage_with_mutated_prior("lever", lambda ci: ci.ws.device_h5), False),
    ("recal --estimate", fz.JSON_OPS, case_recal_estimate, True),
    ("report --procedure", REPORT_PROCEDURE_OPS, case_report_procedure, True),
    ("procedures of the newer kinds", REPORT_PROCEDURE_OPS, case_new_procedure, True),
)
VALID_BASE = {name: valid for name, _, _, valid in KINDS}

__all__ = ["KINDS", "NEW_PROCEDURES", "NOT_A_NUMBER", "NUMERIC_OPTIONS", "VALID_BASE", "CommandInputs", "case_numeric_option"]
