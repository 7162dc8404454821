"""What guards every request of ``stableins serve`` (docs/fleet.md, "Security"), as one ASGI middleware.

* **Read-only**: only ``GET`` and ``HEAD`` are answered (405 otherwise); no endpoint writes anything.
* **Request size**: a request with a body (``Content-Length`` above 0 or chunked) is refused (413); a target (path
  and query) longer than :data:`MAX_TARGET` bytes or more than :data:`MAX_HEADERS` headers is refused (414, 431).
* **Rate**: a token bucket per client address, :attr:`Limits.rate` requests per second with bursts of
  :attr:`Limits.burst` (429 with ``Retry-After``); the server-sent event streams are counted once when opened, and
  at most :attr:`Limits.streams` are open at once (503).
* **Token**: when the server is given one (it must be when bound beyond the loopback interface), every request
  carries it: ``Authorization: Bearer TOKEN``, or the cookie the server sets when a browser first opens a page
  with ``?token=TOKEN``; compared in constant time (401 otherwise).
* **Headers**: a Content-Security-Policy that lets pages load scripts, styles and data from the server alone
  (``default-src 'self'``: no CDN, no inline script), ``X-Content-Type-Options: nosniff``, ``Referrer-Policy:
  no-referrer`` and ``X-Frame-Options: DENY``.

Paths taken from URLs never leave the store or the run root: records and documents are named by their SHA-256 and
looked up in the store's index and the certificate index, runs by the names the run root lists
(:meth:`stableins.web.runs.RunWatcher.directory`), never joined to a path from the URL.
"""

from __future__ import annotations

import hmac
import json
import threading
import time
from collections.abc import Awaitable, Callable, MutableMapping
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qs

#: Longest request target (path and query) answered [bytes].
MAX_TARGET = 2048
#: Most request headers answered.
MAX_HEADERS = 64
COOKIE = "stableins_token"
CSP = (
    "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; "
    "connect-src 'self'; frame-ancestors 'none'; base-uri 'none'; form-action 'self'"
)
Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]


@dataclass(frozen=True)
class Limits:
    """Rate limits of one client address."""

    rate: float = 20.0  #: requests per second, sustained
    burst: int = 60  #: requests at once
    streams: int = 16  #: server-sent event streams open at once, all clients together


class Guard:
    """The ASGI middleware of the module docstring, around ``app``."""

    def __init__(self, app: ASGIApp, *, token: str | None, limits: Limits, secure_cookie: bool = False) -> None:
        self.app = app
        self.token = token
        self.limits = limits
        self.secure_cookie = secure_cookie
        self._buckets: dict[str, tuple[float, float]] = {}
        self._lock = threading.Lock()
        self.streams = 0

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Answer a refused request at once; pass the others to the application, adding the security headers."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        refusal = self._refusal(scope)
        if refusal is not None:
            await _answer(send, *refusal)
            return
        set_cookie = self._token_from_query(scope)
        stream = scope["path"].endswith("/events")
        head = scope["method"] == "HEAD"
        if head and stream:  # a stream's head: its headers, without opening the stream
            await _answer_head(send, {"content-type": "text/event-stream", "cache-control": "no-cache"})
            return
        if head:  # answered as GET with the body left out (RFC 9110 §9.3.2): the routes are declared for GET only
            scope = {**scope, "method": "GET"}
        if stream:
            if self.streams >= self.limits.streams:
                await _answer(send, 503, "too many event streams open", {"retry-after": "5"})
                return
            self.streams += 1

        guarded = self._guarded(send, set_cookie=set_cookie, head=head)
        try:
            await self.app(scope, receive, guarded)
        finally:
            if stream:
                self.streams -= 1

    def _guarded(self, send: Send, *, set_cookie: bool, head: bool) -> Send:
        """Return ``send`` adding the security headers (and the token's cookie); for HEAD, with the body left out."""
        ended: list[bool] = []

        async def guarded(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                headers += [
                    (b"content-security-policy", CSP.encode()),
                    (b"x-content-type-options", b"nosniff"),
                    (b"referrer-policy", b"no-referrer"),
                    (b"x-frame-options", b"DENY"),
                ]
                if set_cookie and self.token:
                    secure = "; Secure" if self.secure_cookie else ""
                    headers.append((b"set-cookie", f"{COOKIE}={self.token}; HttpOnly; SameSite=Strict; Path=/{secure}".encode()))
                message["headers"] = headers
            elif head and message["type"] == "http.response.body":
                if ended:
                    return
                ended.append(True)
                message = {"type": "http.response.body", "body": b"", "more_body": False}
            await send(message)

        return guarded

    def _refusal(self, scope: Scope) -> tuple[int, str, dict[str, str]] | None:
        """Return (status, message, headers) when the request is refused, else None."""
        method = scope["method"]
        if method not in ("GET", "HEAD"):
            return 405, "read-only: only GET and HEAD", {"allow": "GET, HEAD"}
        if len(scope.get("raw_path") or scope["path"].encode()) + len(scope.get("query_string", b"")) > MAX_TARGET:
            return 414, f"request target longer than {MAX_TARGET} bytes", {}
        headers = scope.get("headers", [])
        if len(headers) > MAX_HEADERS:
            return 431, f"more than {MAX_HEADERS} request headers", {}
        named = {k.lower(): v for k, v in headers}
        length = named.get(b"content-length", b"0").strip() or b"0"
        if not length.isdigit() or int(length) > 0 or b"transfer-encoding" in named:
            return 413, "requests carry no body", {}
        client = (scope.get("client") or ("?", 0))[0]
        wait = self._take(client)
        if wait > 0:
            return 429, "too many requests", {"retry-after": str(max(1, round(wait)))}
        if self.token is not None and not self._authorized(named, scope):
            return (
                401,
                "a token is required (Authorization: Bearer TOKEN, or open a page with ?token=TOKEN)",
                {"www-authenticate": "Bearer"},
            )
        return None

    def _take(self, client: str) -> float:
        """Take one request from the client's bucket; return 0, or the seconds until one is available."""
        now = time.monotonic()
        with self._lock:
            tokens, last = self._buckets.get(client, (float(self.limits.burst), now))
            tokens = min(float(self.limits.burst), tokens + (now - last) * self.limits.rate)
            if tokens < 1.0:
                self._buckets[client] = (tokens, now)
                return (1.0 - tokens) / self.limits.rate
            self._buckets[client] = (tokens - 1.0, now)
            if len(self._buckets) > 10_000:  # forget the idle clients
                self._buckets = {k: v for k, v in self._buckets.items() if now - v[1] < 60.0}
            return 0.0

    def _authorized(self, named: dict[bytes, bytes], scope: Scope) -> bool:
        assert self.token is not None
        expected = self.token.encode()
        given = named.get(b"authorization", b"")
        if given.startswith(b"Bearer ") and hmac.compare_digest(given[7:].strip(), expected):
            return True
        for part in named.get(b"cookie", b"").split(b";"):
            key, _, value = part.strip().partition(b"=")
            if key == COOKIE.encode() and hmac.compare_digest(value, expected):
                return True
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        return any(hmac.compare_digest(v.encode(), expected) for v in query.get("token", []))

    def _token_from_query(self, scope: Scope) -> bool:
        return self.token is not None and b"token=" in scope.get("query_string", b"")


async def _answer_head(send: Send, headers: dict[str, str]) -> None:
    raw = [(k.encode(), v.encode()) for k, v in headers.items()]
    await send({"type": "http.response.start", "status": 200, "headers": raw})
    await send({"type": "http.response.body", "body": b""})


async def _answer(send: Send, status: int, message: str, headers: dict[str, str]) -> None:
    body = json.dumps({"detail": message}).encode()
    raw = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    raw += [(k.encode(), v.encode()) for k, v in headers.items()]
    await send({"type": "http.response.start", "status": status, "headers": raw})
    await send({"type": "http.response.body", "body": body})
