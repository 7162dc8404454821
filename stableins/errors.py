"""The two exceptions a person is told about: bad input, and a question the data do not answer.

:class:`InputError`: a user file or argument is wrong (the message names the file, row or field and what
was expected).  :class:`NotDeterminedError`: the input is well formed but the data do not determine what
was asked (a stage whose data determine no parameter of the record, positions whose design leaves a
direction free, a record too short for the stage).  Both carry no exit status: the CLI maps each to its own
(docs/cli.md, "Exit status") and prints one paragraph on stderr, never a traceback.

Both are ValueErrors (issue 29), so code that expects a ``ValueError`` from a parser or a constructor sees them
too.  Every ``except ValueError`` of the package whose ``try`` calls code that can raise one of them first lets the
described error pass through as it is (``except (InputError, NotDeterminedError): raise``), so its file, row and field
are never re-worded away; the sites that catch only ``float()``, numpy or JSON parsing need none.
"""

from __future__ import annotations

from os import PathLike


class _DescribedError(ValueError):
    """An error described for a person: what is wrong, where, and what was expected.

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


class InputError(_DescribedError):
    """Bad input, described for a person (parameters: :class:`_DescribedError`'s)."""


class NotDeterminedError(_DescribedError):
    """The data do not determine what was asked; nothing is written (parameters: :class:`_DescribedError`'s)."""
