"""CLI subcommands, one module each (``configure(parser)`` and ``run(args) -> int``); see :mod:`stableins.cli`."""
