"""Errors raised by platform drivers (the hardware, the link or a recording failed, not the user's input)."""

from __future__ import annotations


class DriverError(Exception):
    """The platform could not do what was asked; the message says what and where."""


class DriverConnectionError(DriverError):
    """The link to the platform failed (refused, timed out, closed)."""


class DriverProtocolError(DriverError):
    """The platform answered something that is not the protocol (garbage, wrong id, bad checksum)."""


class AcquisitionInterrupted(DriverConnectionError):
    """An acquisition stopped part-way; ``received`` samples arrived before it did.

    Acquisitions are not repeatable (time moves on), so the driver does not retry them: the
    runner discards the partial attempt (it stays in the journal) and repeats the step.
    """

    def __init__(self, message: str, received: int = 0) -> None:
        super().__init__(message)
        self.received = received
