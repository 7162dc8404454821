"""The documentation's commands run as written, and every command and option it or a message names exists.

* ``sh`` blocks of README.md, docs/*.md and procedures/README.md run in order, per document, in a fresh
  directory: ``stableins`` lines in-process through :func:`stableins.cli.main` (a new directory is the user's
  working directory; the shipped procedures are found by name), lines with shell syntax through bash with this
  interpreter's ``bin`` first on PATH, ``make`` lines checked against the Makefile's targets (``make test`` is
  what runs this test).  Fast settings: the simulated platform and the procedures sample at 2 Hz instead of
  100 Hz (the simulated device files keep their names: coarse passes in CSV, the fine stage in HDF5), no fsync.
  A person answers prompts: yes to a confirmation, the default to an entry.  Then ``stableins check`` runs on
  every file the document's commands wrote.
* ``text`` blocks are synopses, need a platform on the network, or repeat what a ``sh`` block or another test
  runs: each ``stableins`` command and ``--option`` they name must exist (the real parser's), as must those that
  messages in the code quote.
"""

from __future__ import annotations

import ast
import dataclasses
import glob
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from stableins import cli

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md")), "procedures/README.md"]
BLOCK = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)
SHELL_SYNTAX = ("|", ">", ">>", "<", "&", "&&", ";", "||")
#: Fast settings of the documentation test: the sample rate of the simulated platform and of the procedures [Hz].
FAST_RATE = 2.0


def blocks(document: str, kind: str) -> list[tuple[int, str]]:
    """``(line number, text)`` of the fenced blocks of ``kind`` in a document."""
    text = (ROOT / document).read_text(encoding="utf-8")
    return [(text[: m.start()].count("\n") + 1, m.group(2)) for m in BLOCK.finditer(text) if m.group(1) == kind]


def commands(block: str, *, shell: bool = True) -> list[str]:
    """The command lines of a block: continuation lines joined, comments and blank lines dropped (``shell``: lines are
    shell syntax; else only the lines that start with ``stableins`` are kept, as they are)."""
    out, pending = [], ""
    for line in block.splitlines():
        if line.rstrip().endswith("\\"):
            pending += line.rstrip()[:-1] + " "
            continue
        line, pending = pending + line, ""
        if shlex.split(line, comments=True) if shell else line.strip().startswith("stableins "):
            out.append(line)
    return out


def _fast(load):
    def load_procedure(name_or_path):
        definition = load(name_or_path)
        steps = tuple(dataclasses.replace(s, sample_rate=min(s.sample_rate, FAST_RATE)) for s in definition.steps)
        return dataclasses.replace(definition, steps=steps)

    return load_procedure


def _fast_draw(draw):
    def fast(cls, seed, **kwargs):
        from stableins.simulator.truth import DEFAULT_SITE

        site = kwargs.get("site", DEFAULT_SITE)
        if site.sample_rate == DEFAULT_SITE.sample_rate:  # the default rate (the documents' commands ask for others explicitly)
            kwargs["site"] = dataclasses.replace(site, sample_rate=FAST_RATE)
        return draw(cls, seed, **kwargs)

    return classmethod(fast)


def _person(self, prompt: str) -> str:
    """A person at the terminal: confirms, and takes the default of an entry (a prompt without one fails the test)."""
    if prompt.rstrip().endswith("[y/n]"):
        return "y"
    assert prompt.rstrip().endswith("]:"), f"the documentation's command asks for a value without a default: {prompt!r}"
    return ""


def _shell(line: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}", MPLBACKEND="Agg")
    return subprocess.run(["bash", "-c", line], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def _expand(tokens: list[str], cwd: Path) -> list[str]:
    out = []
    for token in tokens:
        matches = sorted(glob.glob(token, root_dir=cwd)) if any(c in token for c in "*?[") else []
        out += matches or [token]
    return out


@pytest.mark.parametrize("document", [d for d in DOCUMENTS if blocks(d, "sh")])
def test_the_documents_commands_run_as_written(document, tmp_path, monkeypatch, capsys):
    import stableins.procedures.definition
    from stableins.console import Console
    from stableins.simulator.truth import Truth

    fast = _fast(stableins.procedures.definition.load_procedure)
    import stableins.commands.simulate

    monkeypatch.setattr(Truth, "draw", _fast_draw(Truth.draw.__func__))
    # the shipped procedures' coarse passes (2 to 5) stay in CSV and the fine stage in HDF5, as at 100 Hz with the docs' seeds
    monkeypatch.setattr(stableins.commands.simulate, "CSV_ROW_LIMIT", 10_000)
    monkeypatch.setattr(stableins.procedures.definition, "load_procedure", fast)
    monkeypatch.setattr(Console, "_ask", _person)
    monkeypatch.setattr("os.fsync", lambda fd: None)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.delenv("STABLEINS_HISTORY", raising=False)
    monkeypatch.chdir(tmp_path)
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    for line_number, block in blocks(document, "sh"):
        for line in commands(block):
            where = f"{document}:{line_number}: {line.strip()}"
            tokens = shlex.split(line, comments=True)
            if tokens[0] == "make":
                assert all(re.search(rf"^{re.escape(t)}:", makefile, re.M) for t in tokens[1:]), f"{where}: no such make target"
                continue
            if "$(" in line or any(t in SHELL_SYNTAX for t in tokens) or tokens[0] != "stableins":
                done = _shell(line, tmp_path)
                assert done.returncode == 0, f"{where}\n{done.stderr}"
                continue
            status = cli.main(_expand(tokens[1:], tmp_path))
            captured = capsys.readouterr()
            assert status == 0, f"{where}\nexit status {status}\n{captured.err[-3000:]}"
    written = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*") if p.is_file() and ".partial" not in p.name)
    assert written, f"{document}: the commands wrote nothing"
    status = cli.main(["check", *written])
    captured = capsys.readouterr()
    assert status == 0, f"{document}: stableins check refuses a file the commands wrote\n{captured.err}"
    assert captured.out.count(": ok (") == len(written)


# --------------------------------------------------------------------------- commands and options that exist
def _parser_of(path: tuple[str, ...]):
    """The configured parser of a command (``("calibrate", "device")``), or None when there is no such command."""
    parser = cli.build_parser(list(path))
    for name in path:
        choices = next((a.choices for a in parser._actions if isinstance(a.choices, dict)), None)
        if not choices or name not in choices:
            return None
        parser = choices[name]
    if any(isinstance(a.choices, dict) for a in parser._actions):
        return None  # a group: the subcommand is missing
    return parser


def problems_of(command: str) -> list[str]:
    """What is wrong with a ``stableins ...`` command line (a synopsis may hold placeholders and [optional] parts)."""
    tokens = [t for t in re.split(r"\s+", command.strip()) if t]
    assert tokens[0] == "stableins"
    if len(tokens) < 2 or tokens[1].startswith(("-", "[")) or tokens[1].isupper():
        return []
    path = (tokens[1],)
    if isinstance(cli.COMMANDS.get(tokens[1]), cli.Group):
        if len(tokens) == 2:
            return []  # the group named as a whole ('stableins calibrate')
        path += (tokens[2].strip("[]"),)
    parser = _parser_of(path)
    if parser is None:
        return [f"no command 'stableins {' '.join(path)}'"]
    known = {o for a in parser._actions for o in a.option_strings}
    options = {m.group(1) for t in tokens for m in [re.match(r"^\[*(--[a-z][a-z0-9-]*)", t)] if m}
    return [f"'stableins {' '.join(path)}' has no option {o}" for o in sorted(options - known)]


def _text_block_commands() -> list[tuple[str, str]]:
    out = []
    for document in DOCUMENTS:
        for line_number, block in blocks(document, "text") + blocks(document, "sh"):
            for line in commands(block, shell=False):
                for part in re.split(r"\s(?:&&|\||;)\s", line.split("  #")[0].strip().rstrip("&").strip()):
                    if part.startswith("stableins "):
                        out.append((f"{document}:{line_number}", part))
    return out


def test_every_command_and_option_the_documents_name_exists():
    found = _text_block_commands()
    assert len(found) > 40
    wrong = [f"{where}: {command}: {problem}" for where, command in found for problem in problems_of(command)]
    assert not wrong, "\n".join(wrong)


def test_messages_name_only_commands_and_options_that_exist():
    quoted = re.compile(r"['`](stableins [a-z][^'`{}]*)['`]")
    found = []
    for path in sorted((ROOT / "stableins").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                found += [(f"{path.relative_to(ROOT)}:{node.lineno}", m.group(1)) for m in quoted.finditer(node.value)]
    assert len(found) > 10
    wrong = [f"{where}: {command!r}: {problem}" for where, command in found for problem in problems_of(command)]
    assert not wrong, "\n".join(wrong)


def test_cli_md_documents_every_command():
    text = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    table = text[: text.index("## Conventions")]
    for name, entry in cli.COMMANDS.items():
        names = [f"{name} {sub}" for sub in entry.commands] if isinstance(entry, cli.Group) else [name]
        for command in names:
            assert f"`stableins {command}" in table, f"docs/cli.md's table lacks {command}"
            assert re.search(rf"^## .*\b{re.escape(command)}\b", text, re.M) or re.search(rf"^## {re.escape(name)}\b", text, re.M), (
                f"docs/cli.md has no section for {command}"
            )
