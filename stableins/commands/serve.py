"""``stableins serve``: the laboratory's fleet, a unit's history and the runs in a browser, read-only (docs/fleet.md).

::

    stableins serve --store cal/ --runs runs/                       # http://127.0.0.1:8000/fleet
    stableins serve --store postgresql://lab@db/history --runs /srv/runs --host 0.0.0.0 --token-file token.txt

Bound to 127.0.0.1 unless ``--host`` is given; bound to any other address it needs a token (``--token-file`` or
``$STABLEINS_SERVE_TOKEN``), which every request carries.  Prints ``serving on http://HOST:PORT`` once it accepts
connections (``--port 0`` picks a free port).
"""

from __future__ import annotations

import argparse
import os

#: Where a token comes from when no --token-file is given.
TOKEN_ENV = "STABLEINS_SERVE_TOKEN"
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins serve`` to ``parser``."""
    from stableins.commands.arguments import input_file, integer, real

    parser.add_argument(
        "--store",
        metavar="DIR",
        help="history store: a directory or a postgresql:// URL (default $STABLEINS_HISTORY or ~/.local/share/stableins/history)",
    )
    parser.add_argument("--runs", metavar="DIR", help="run root: the runs, certificates and technical reports below it (3 levels)")
    parser.add_argument("--policy", type=input_file, metavar="FILE", help="laboratory policy (TOML): calibration intervals (docs/fleet.md)")
    parser.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1; any other needs a token)")
    parser.add_argument("--port", type=integer(0, 65535), default=8000, help="TCP port (default 8000; 0: any free port)")
    parser.add_argument("--token-file", type=input_file, metavar="FILE", help=f"the token every request must carry (default ${TOKEN_ENV})")
    parser.add_argument("--rate", type=real(0.0, 10000.0, above=True), default=20.0, help="requests per second per client (default 20)")
    parser.add_argument("--burst", type=integer(1, 100000), default=60, help="requests at once per client (default 60)")
    parser.add_argument("--secure-cookie", action="store_true", help="mark the token cookie Secure (behind an HTTPS reverse proxy)")


def run(args: argparse.Namespace) -> int:
    """Run ``stableins serve`` until interrupted."""
    from pathlib import Path

    from stableins.errors import InputError

    try:
        import fastapi  # noqa: F401
        import uvicorn
    except ImportError:
        raise InputError("stableins serve needs FastAPI and uvicorn", expected="pip install 'stableins[web]'") from None
    from stableins.web.app import ServeSettings, create_app
    from stableins.web.policy import Policy
    from stableins.web.security import Limits

    token = _token(args)
    if args.host not in LOOPBACK_HOSTS and token is None:
        raise InputError(
            f"bound to {args.host} the server is reachable from other machines: it needs a token",
            field="--host",
            expected=f"--token-file FILE or ${TOKEN_ENV} (or --host 127.0.0.1 behind a reverse proxy that authenticates, docs/fleet.md)",
        )
    runs = Path(args.runs) if args.runs else None
    if runs is not None and not runs.is_dir():
        raise InputError("is not a directory", path=runs, field="--runs", expected="the run root: a directory of run directories")
    settings = ServeSettings(
        store=args.store,
        run_root=runs,
        policy=Policy.load(args.policy) if args.policy else Policy(),
        token=token,
        limits=Limits(rate=args.rate, burst=args.burst),
        secure_cookie=args.secure_cookie,
    )
    app = create_app(settings)
    config = uvicorn.Config(app, host=args.host, port=args.port, log_level="warning", timeout_graceful_shutdown=2, access_log=False)
    server = uvicorn.Server(config)
    _announce(server, args.host)
    server.run()
    return 0


def _token(args: argparse.Namespace) -> str | None:
    """Return the token of --token-file or $STABLEINS_SERVE_TOKEN (None when neither is given)."""
    from pathlib import Path

    from stableins.errors import InputError

    if args.token_file:
        try:
            text = Path(args.token_file).read_text(encoding="utf-8")
        except OSError as error:
            raise InputError(f"cannot read the token ({error.strerror})", path=args.token_file, field="--token-file") from None
    else:
        text = os.environ.get(TOKEN_ENV, "")
        if not text:
            return None
    token = text.strip()
    if len(token) < 16 or any(c.isspace() or not c.isprintable() for c in token):
        raise InputError(
            "the token is too short or has spaces", field="--token-file", expected="at least 16 printable characters, no spaces"
        )
    return token


def _announce(server: object, host: str) -> None:
    """Print ``serving on http://HOST:PORT`` once uvicorn listens (the port it got, for --port 0)."""
    import sys

    startup = server.startup  # type: ignore[attr-defined]

    async def announced(sockets: object = None) -> None:
        await startup(sockets=sockets)
        for s in getattr(server, "servers", []):
            for sock in s.sockets:
                address = sock.getsockname()
                shown = f"[{address[0]}]" if ":" in address[0] else address[0]
                print(f"serving on http://{shown}:{address[1]}", flush=True)
                sys.stdout.flush()
                return

    server.startup = announced  # type: ignore[attr-defined]
