"""One run per directory: the lock a process holds on a run directory for as long as it runs there.

``stableins run`` (start or ``--resume``) takes the lock before it writes anything into the directory,
and a second process on the same directory is refused at once with one message naming the directory and
the process that holds it.  The lock is an advisory ``flock`` on ``RUNDIR/run.lock`` (which also holds the
holder's process id and start time, for that message): the operating system releases it when its process
ends, also on ``kill -9``, so an interrupted run can always be resumed.

The lock file is removed when the lock is released normally.  Removing a lock file is safe only because a
lock taken on it counts once the path still names the locked file (:meth:`RunLock.acquire` checks the
inode after the ``flock`` and starts again when the file was removed meanwhile).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from datetime import UTC, datetime
from pathlib import Path

from stableins.errors import InputError

#: Name of the lock file in a run directory.
LOCK_NAME = "run.lock"


class RunLock:
    """The lock on a run directory held by this process (:meth:`acquire`, then :meth:`release` or ``with``).

    Attributes
    ----------
    rundir : Path
        The run directory.
    created : bool
        The directory did not exist before the lock was taken (it is removed on release when the run
        left nothing in it, e.g. a run refused before it started).
    """

    def __init__(self, rundir: Path, fd: int, *, created: bool) -> None:
        self.rundir = rundir
        self.created = created
        self._fd = fd

    @classmethod
    def acquire(cls, rundir: str | os.PathLike[str]) -> RunLock:
        """Lock ``rundir`` for this process (created when needed); InputError naming the process that holds it otherwise.

        Raises
        ------
        InputError
            Another process holds the lock (its pid and start time in the message), or the directory cannot be
            created or written.
        """
        rundir = Path(rundir)
        created = not rundir.exists()
        try:
            rundir.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise InputError(f"cannot create the run directory: {error.strerror}", path=rundir, field="--out") from None
        path = rundir / LOCK_NAME
        while True:
            try:
                fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as error:
                raise InputError(f"cannot write the lock file: {error.strerror}", path=path, expected="a writable directory") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _holder(fd)
                os.close(fd)
                raise InputError(
                    f"another stableins process ({holder}) is running the run in {rundir} right now",
                    path=rundir,
                    expected="that process to finish or stop first (then 'stableins run --resume' continues it), or another directory",
                ) from None
            if _same_file(fd, path):
                break
            os.close(fd)  # the holder released and removed the file between our open and our flock: take the new one
        text = f"pid {os.getpid()}, started {datetime.now(UTC).replace(microsecond=0).isoformat()}\n"
        os.ftruncate(fd, 0)
        os.pwrite(fd, text.encode("ascii"), 0)
        return cls(rundir, fd, created=created)

    def release(self) -> None:
        """Release the lock (the file is removed first, while it is held; the directory too if the run left it empty)."""
        if self._fd < 0:
            return
        with contextlib.suppress(OSError):
            os.unlink(self.rundir / LOCK_NAME)
        os.close(self._fd)
        self._fd = -1
        if self.created:
            with contextlib.suppress(OSError):  # not empty: the run wrote something, which stays
                self.rundir.rmdir()

    def __enter__(self) -> RunLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def _holder(fd: int) -> str:
    """Describe the process that holds the lock from what it wrote in the lock file."""
    try:
        text = os.pread(fd, 200, 0).decode("ascii", "replace").strip()
    except OSError:
        text = ""
    return text or "that has just started, its pid not written yet"


def _same_file(fd: int, path: Path) -> bool:
    """Whether ``path`` still names the open file ``fd`` (it was not removed and created again meanwhile)."""
    try:
        return os.path.samestat(os.fstat(fd), os.stat(path))
    except FileNotFoundError:
        return False


__all__ = ["LOCK_NAME", "RunLock"]
