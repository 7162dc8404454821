"""A throw-away PostgreSQL server for the tests: initdb into a temporary folder, started on a Unix socket only.

Debian's ``postgresql`` package (``make system-deps``) puts the server's programs in ``/usr/lib/postgresql/N/bin``.
PostgreSQL refuses to run as root: as root the cluster belongs to the ``postgres`` user the package creates (or to
``nobody``), and its programs run through ``runuser``.  The server listens on no TCP port (``listen_addresses=''``),
only on a socket in its own folder, so tests never collide over a port.  Each test gets a database of its own
(:meth:`PostgresServer.database`).
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import subprocess
import tempfile
from pathlib import Path

USER = "stableins"


def server_binaries() -> Path | None:
    """Return the folder of ``initdb`` and ``pg_ctl`` (None when PostgreSQL's server is not installed)."""
    found = shutil.which("initdb")
    if found:
        return Path(found).parent
    found_all = glob.glob("/usr/lib/postgresql/*/bin/initdb")
    candidates = sorted(found_all, key=lambda p: int(p.split("/")[4]) if p.split("/")[4].isdigit() else 0)
    return Path(candidates[-1]).parent if candidates else None


def missing_reason() -> str | None:
    """Why the PostgreSQL tests cannot run here (None when they can)."""
    if server_binaries() is None:
        return "PostgreSQL's server (initdb, pg_ctl) is not installed: `make system-deps` installs Debian's postgresql"
    try:
        import psycopg  # noqa: F401
    except ImportError:
        return "psycopg is not installed: pip install -e '.[test]'"
    return None


class PostgresServer:
    """A PostgreSQL cluster in a temporary folder, running until :meth:`stop`."""

    def __init__(self) -> None:
        binaries = server_binaries()
        assert binaries is not None
        self.folder = Path(tempfile.mkdtemp(prefix="stableins-pg-"))
        self.data = self.folder / "data"
        self.socket = self.folder
        self.port = 5432
        self._prefix: list[str] = []
        if os.geteuid() == 0:
            owner = "postgres" if _has_user("postgres") else "nobody"
            info = pwd.getpwnam(owner)
            os.chown(self.folder, info.pw_uid, info.pw_gid)
            self._prefix = ["runuser", "-u", owner, "--"]
        self._run([str(binaries / "initdb"), "-D", str(self.data), "-A", "trust", "-U", USER, "--no-sync", "-E", "UTF8"])
        options = f"-k {self.socket} -p {self.port} -c listen_addresses='' -c fsync=on -c max_connections=60"
        log = str(self.folder / "log")
        self._run([str(binaries / "pg_ctl"), "-D", str(self.data), "-o", options, "-l", log, "-w", "-t", "60", "start"])
        self._binaries = binaries
        self._count = 0

    def _run(self, argv: list[str]) -> None:
        subprocess.run([*self._prefix, *argv], check=True, capture_output=True, timeout=120)

    def url(self, database: str = "postgres") -> str:
        """The libpq URL of a database of this server (over its Unix socket)."""
        return f"postgresql://{USER}@/{database}?host={self.socket}&port={self.port}"

    def database(self) -> str:
        """Create a new, empty database and return its URL."""
        import psycopg

        self._count += 1
        name = f"store{self._count}"
        with psycopg.connect(self.url(), autocommit=True) as connection:
            connection.execute(f"CREATE DATABASE {name}")
        return self.url(name)

    def stop(self) -> None:
        """Stop the server at once and remove its folder."""
        try:
            self._run([str(self._binaries / "pg_ctl"), "-D", str(self.data), "-m", "immediate", "-w", "stop"])
        finally:
            shutil.rmtree(self.folder, ignore_errors=True)


def _has_user(name: str) -> bool:
    try:
        pwd.getpwnam(name)
    except KeyError:
        return False
    return True
