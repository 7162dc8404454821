"""Command-line interface: ``stableins <command> [<subcommand>] [options]``.

Subcommands live in ``stableins/commands/<name>.py``; each defines
``configure(parser)`` (adds its arguments; no heavy imports at module top) and
``run(args) -> int``.  :data:`COMMANDS` maps names to those modules; a group (a nested
mapping) gives two-word commands such as ``stableins calibrate device``.  Only the
module of the command actually invoked is imported, so ``stableins --help`` and
``stableins --version`` never import numpy, scipy, filterpy or matplotlib.

Conventions shared by every command:

- ``--json``: the result goes to stdout as one JSON document (progress and messages go
  to stderr), see :func:`stableins.output.emit`;
- progress bars (:mod:`stableins.progress`) are drawn on stderr only when it is a terminal, never with ``--json`` or
  ``--quiet``;
- a user error (:class:`~stableins.errors.InputError`, bad arguments) prints
  ``stableins: error: <message>`` and exits with status 2, never a traceback; data that do not
  determine what was asked (:class:`~stableins.errors.NotDeterminedError`) the same, with status 4;
- Ctrl-C exits with status 130; an operating-system error (disk full, permission denied)
  prints ``stableins: error: <message>`` and exits with status 1.
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple


class _Version(argparse.Action):
    """``--version``: computed only when asked for (it may ask git), so other commands stay fast."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS, **kwargs: object) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, help="print the version (from git) and exit")

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: object, option_string: str | None = None):
        import stableins

        print(f"stableins {stableins.__version__}")
        parser.exit()


class Command(NamedTuple):
    """A leaf command: the module implementing it, a one-line help, and whether it serves until stopped."""

    module: str
    help: str
    server: bool = False  # prints its address and serves until stopped: no result (no --json), no progress bar


class Group(NamedTuple):
    """A command group: one-line help and its subcommands (leaves or groups)."""

    help: str
    commands: Mapping[str, Command | Group]


#: name -> Command or Group.  Register a command by adding one line.
COMMANDS: dict[str, Command | Group] = {
    "simulate": Command("stableins.commands.simulate", "simulate device-level dwells or a system-level record with a known truth"),
    "demo": Command("stableins.commands.demo", "simulate a platform end to end and write everything to a directory"),
    "check": Command("stableins.commands.check", "validate any file stableins writes: data, records, truth, plans, journals, reports"),
    "noise": Command("stableins.commands.noise", "measure the noise model (Allan deviation) from a static record or dwells"),
    "diagnose": Command("stableins.commands.diagnose", "compare the model with the data, rank missing effects, add them and refit"),
    "calibrate": Group(
        "calibrate from recorded data",
        {
            "device": Command("stableins.commands.calibrate_device", "device-level coarse + fine calibration"),
            "system": Command("stableins.commands.calibrate_system", "system-level (third stage) calibration from a static record"),
            "drift": Command("stableins.commands.calibrate_drift", "gyro drift from an indexing test (drift-two-position)"),
            "thermal": Command(
                "stableins.commands.calibrate_thermal", "temperature sensitivities Kt_bias, Kt_sf from a thermal test (device-thermal)"
            ),
            "lever": Command("stableins.commands.calibrate_lever", "lever arms and time asynchrony from the slews of device-rotating"),
            "poses": Command("stableins.commands.calibrate_poses", "a triad from the static poses of a real log (any columns and units)"),
        },
    ),
    "run": Command("stableins.commands.run_command", "carry out a calibration procedure on a platform (journaled, resumable)"),
    "serve": Command(
        "stableins.commands.serve", "the fleet, a unit's history and the runs in a browser, read-only (docs/fleet.md)", server=True
    ),
    "serve-sim": Command(
        "stableins.commands.serve_sim", "serve the simulated platform over TCP on 127.0.0.1 (docs/protocol.md)", server=True
    ),
    "protocol-check": Command(
        "stableins.commands.protocol_check", "conformance of a platform controller to docs/protocol.md, pass/fail per clause"
    ),
    "recal": Command("stableins.commands.recal", "field recalibration with the unit's previous record as the prior"),
    "history": Command("stableins.commands.history", "a unit's calibration records: in force, stale, changes, drift"),
    "budget": Command(
        "stableins.commands.budget", "navigation budget: what each calibration term's 1σ and the gyro drift do to navigation"
    ),
    "design": Command("stableins.commands.design", "expected σ of a procedure before the platform moves; dwells for σ targets or a budget"),
    "campaign": Command("stableins.commands.campaign", "Monte Carlo campaign of simulated calibrations on Dask (docs/campaigns.md)"),
    "report": Command("stableins.commands.report", "write the PDF calibration report of a calibration record (ISO/IEC 17025 7.8)"),
}

EXIT_FAILURE = 1
EXIT_USAGE = 2
#: The data do not determine what was asked (:class:`~stableins.errors.NotDeterminedError`); nothing was written.
EXIT_NOT_DETERMINED = 4
EXIT_INTERRUPTED = 130


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors use the CLI's one-line format and exit status 2.

    Negative numbers in scientific notation (``--gyro-drift -1e-3 0 0``) are values, not options (Python 3.11's
    argparse only knows ``-1`` and ``-1.5``): no stableins option looks like a number.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?$|^-inf$|^-nan$")

    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        self.exit(EXIT_USAGE, f"stableins: error: {message}\n")


def _first_positional(argv: Sequence[str]) -> str | None:
    for token in argv:
        if token == "--":
            return None
        if not token.startswith("-"):
            return token
    return None


def _add(subparsers: argparse._SubParsersAction, table: Mapping[str, Command | Group], argv: Sequence[str], path: tuple[str, ...]) -> None:
    """Add ``table`` to ``subparsers``; configure only the entry named next in ``argv``."""
    selected = _first_positional(argv)
    for name, entry in table.items():
        parser = subparsers.add_parser(name, help=entry.help, description=entry.help)
        if name != selected:
            continue
        rest = list(argv[list(argv).index(name) + 1 :])
        if isinstance(entry, Group):
            nested = parser.add_subparsers(dest="_".join(("command",) + path + (name,)), metavar="SUBCOMMAND", required=True)
            _add(nested, entry.commands, rest, path + (name,))
        else:
            module = importlib.import_module(entry.module)
            module.configure(parser)
            if entry.server:
                parser.set_defaults(_run=module.run)
                continue
            if not any(action.dest == "json" for action in parser._actions):
                parser.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
            if not any(action.dest == "quiet" for action in parser._actions):
                parser.add_argument("--quiet", action="store_true", help="draw no progress bars (none are drawn off a terminal either)")
            parser.set_defaults(_run=module.run)


def build_parser(argv: Sequence[str] = ()) -> argparse.ArgumentParser:
    """Return the parser, with the command named in ``argv`` (if any) fully configured."""
    parser = _Parser(
        prog="stableins",
        description="On-system calibration of the accelerometer triad of a space-stable inertial navigation system.",
        epilog="Run 'stableins COMMAND --help' for a command's options.  Exit status: 0 ok, 1 failure, 2 bad input, 130 interrupted.",
    )
    parser.add_argument("--version", action=_Version)
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    _add(subparsers, COMMANDS, argv, ())
    return parser


#: Thread-count variables of the linear-algebra libraries (OpenBLAS, MKL, OpenMP builds), read when they load.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")


def single_threaded_blas() -> None:
    """Default the linear-algebra libraries to one thread (a variable the user set is kept).

    The commands' matrices are small (tens to a few hundred rows): a second BLAS thread gains nothing there, and
    on a shared machine its spinning threads multiplied a command's CPU time up to sevenfold (issue 30:
    ``calibrate device`` 29.7 s of CPU with the default threads, 4.1 s with one).  Only libraries loaded after
    the call see it: the CLI calls it before a command imports numpy; workers inherit it.
    """
    import os

    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``stableins`` console script; returns the exit status."""
    from stableins.errors import InputError, NotDeterminedError

    single_threaded_blas()
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        parser = build_parser(argv)
        args = parser.parse_args(argv)
        if getattr(args, "_run", None) is None:
            parser.print_help(sys.stderr)
            return EXIT_USAGE
        from stableins.progress import silence

        silence(quiet=bool(getattr(args, "json", False) or getattr(args, "quiet", False)))  # progress is for a person at a terminal
        try:
            return int(args._run(args) or 0)
        finally:
            silence(quiet=False)
    except (InputError, NotDeterminedError) as error:
        from stableins.commands.flags import as_flag

        print(f"stableins: error: {as_flag(error)}", file=sys.stderr)
        return EXIT_USAGE if isinstance(error, InputError) else EXIT_NOT_DETERMINED
    except KeyboardInterrupt:
        print("stableins: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (IsADirectoryError, NotADirectoryError) as error:  # a path mix-up the argument checks could not see: bad input
        wanted = "a file, not a directory" if isinstance(error, IsADirectoryError) else "a directory on the way, not a file"
        where = error.filename2 or error.filename
        print(f"stableins: error: {where}: {(error.strerror or str(error)).lower()} (expected {wanted})", file=sys.stderr)
        return EXIT_USAGE
    except OSError as error:  # disk full, permission denied ... on a file the user named: no traceback
        if isinstance(error, BrokenPipeError):
            return 0
        print(f"stableins: error: {error}", file=sys.stderr)
        return EXIT_FAILURE
    except SystemExit as exit_:  # argparse: --help, --version, usage errors
        code = exit_.code
        return code if isinstance(code, int) else (0 if code is None else 1)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
