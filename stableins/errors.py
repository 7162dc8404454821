"""The one exception type for bad user input.

Everything that reads user files or arguments raises :class:`InputError`; the CLI
turns it into a one-paragraph message on stderr and exit status 2, never a traceback.
"""

from __future__ import annotations

from os import PathLike


class InputError(Exception):
    """Bad input, described for a person.

    Parameters
    ----------
    message : str
        What is wrong.
    path : path-like, optional
        File the problem is in.
    field : str, optional
        Column, key or argument.
    row : int, optional
        1-based data row (or sample index) where it was found.
    expected : str, optional
        What was expected instead.
    """

    exit_status = 2

    def __init__(
        self,
        message: str,
        *,
        path: str | PathLike[str] | None = None,
        field: str | None = None,
        row: int | None = None,
        expected: str | None = None,
    ) -> None:
        self.message = message
        self.path = None if path is None else str(path)
        self.field = field
        self.row = row
        self.expected = expected
        super().__init__(self.describe())

    def describe(self) -> str:
        """Return the message with where it happened and what was expected."""
        where = []
        if self.path:
            where.append(self.path)
        if self.row is not None:
            where.append(f"row {self.row}")
        if self.field:
            where.append(f"field '{self.field}'")
        text = ": ".join([", ".join(where), self.message]) if where else self.message
        if self.expected:
            text += f" (expected {self.expected})"
        return text
