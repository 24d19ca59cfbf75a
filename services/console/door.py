"""Who may open the console: the console's door, checked on every HTTP request and WebSocket upgrade.

Checks, in this order, before anything of the run is served (docs/security.md):

1. `Host` must name this console: a loopback name (127.0.0.1, localhost, [::1]) or the configured host, with the
   console's own port. A DNS-rebinding page (`http://evil.example:PORT`, resolved to 127.0.0.1) sends its own name
   and is refused.
2. `Origin`, when a browser sends one (it always does on a WebSocket upgrade, a POST and cross-origin requests),
   must be this console's own origin: a page served from another port, another host or a `file://` page
   (`Origin: null`) is refused.
3. A key. The page itself (`/`, `/static/...`: shipped files, nothing of the run) needs none; everything else does.
   The printed address carries a one-use entry key in its fragment (`/#token=E`): a fragment never reaches a server,
   a log or a Referer. The page reads it, removes it from the address bar (`history.replaceState`) and exchanges it
   (`POST /enter`, `Authorization: Bearer E`) for a session key that it keeps in this tab's sessionStorage and
   presents itself: `Authorization: Bearer K` on requests, `?key=K` on the WebSocket. There is no cookie: nothing
   the browser sends by itself to other ports of 127.0.0.1 opens the console. The entry key is spent on first use,
   so the address a browser keeps in its history opens nothing. An open page hands out more one-use addresses
   (`POST /invite`) for another tab or person.

Keys are derived from the run's secret (`token_file`, mode 0600; a restarted console keeps it, so open pages keep
their session keys and printed addresses stay valid until used); spent entry keys are listed beside it (0600).
"""

from __future__ import annotations

import hashlib
import hmac
import os
import secrets
from collections.abc import Awaitable, Callable, MutableMapping
from pathlib import Path

from aiohttp import web

LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")
PUBLIC_PREFIX = "/static/"  # the shipped files of the page: nothing of the run
REFUSED_PAGE = """<!doctype html><html lang="en"><meta charset="utf-8"><title>console: not open to this page</title>
<body style="font-family:sans-serif;max-width:40em;margin:3em auto"><h1>Not open to this page</h1>
<p>{why}</p><p>Open the console from the address that <code>python -m services up --teacher web</code> printed
(<code>http://127.0.0.1:PORT/#token=...</code>): the key in it lets one page in.</p></body></html>"""
Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


def _write_private(path: Path, text: str, mode: str = "w") -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    flags = os.O_WRONLY | os.O_CREAT | (os.O_APPEND if mode == "a" else os.O_TRUNC)
    fd = os.open(path, flags, 0o600)
    with os.fdopen(fd, mode) as f:
        f.write(text)


def read_or_make_token(path: str | None) -> str:
    """The run's console secret: the one in `path` if it exists, else a new one (written there, mode 0600)."""
    if path is None:
        return secrets.token_urlsafe(24)
    p = Path(path)
    if p.exists():
        token = p.read_text().strip()
        if len(token) >= 16:
            return token
    token = secrets.token_urlsafe(24)
    _write_private(p, token + "\n")
    return token


class Keys:
    """The keys derived from the run's secret: `e.NONCE.MAC` entry keys (one use each) and `s.NONCE.MAC` session
    keys. Both are checked without a table (the MAC), so a restarted console with the same secret knows them."""

    def __init__(self, secret: str, spent_file: str | None = None):
        self.secret = secret.encode()
        self.spent_file = Path(spent_file) if spent_file else None
        self.spent: set[str] = set()
        if self.spent_file is not None and self.spent_file.exists():
            self.spent = set(self.spent_file.read_text().split())

    def _mac(self, kind: str, nonce: str) -> str:
        return hmac.new(self.secret, f"{kind}:{nonce}".encode(), hashlib.sha256).hexdigest()[:32]

    def _make(self, kind: str) -> str:
        nonce = secrets.token_urlsafe(12)
        return f"{kind}.{nonce}.{self._mac(kind, nonce)}"

    def entry(self) -> str:
        return self._make("e")

    def session(self) -> str:
        return self._make("s")

    def valid(self, kind: str, key: str | None) -> bool:
        parts = (key or "").split(".")
        if len(parts) != 3 or parts[0] != kind or not 8 <= len(parts[1]) <= 64:
            return False
        return hmac.compare_digest(parts[2].encode(), self._mac(kind, parts[1]).encode())

    def spend(self, key: str | None) -> str:
        """'ok' (the entry key is now spent), 'spent' (used before) or 'bad'."""
        if not self.valid("e", key):
            return "bad"
        nonce = str(key).split(".")[1]
        if nonce in self.spent:
            return "spent"
        self.spent.add(nonce)
        if self.spent_file is not None:  # a restarted console must not take it again
            _write_private(self.spent_file, nonce + "\n", "a")
        return "ok"


def spent_file_for(token_file: str | None) -> str | None:
    return None if token_file is None else token_file + ".spent"


def console_address(scheme: str, host: str, port: int, entry_key: str) -> str:
    name = f"[{host}]" if ":" in host and not host.startswith("[") else host
    return f"{scheme}://{name}:{port}/#token={entry_key}"


def bearer(request: web.Request) -> str | None:
    value = request.headers.get("Authorization", "")
    return value[7:].strip() if value[:7].lower() == "bearer " else None


class Door:
    """The checks above, as an aiohttp middleware (`door.middleware`); counts every refusal by reason. `guard`
    (services/console/sockets.py) is told which connections presented a valid key."""

    def __init__(
        self,
        keys: Keys,
        host: str,
        port: int,
        scheme: str,
        counters: MutableMapping[str, int],
        server_names: tuple[str, ...] = (),
        guard=None,
    ):
        self.keys, self.port, self.scheme, self.counters, self.guard = keys, int(port), scheme, counters, guard
        self.host = host
        names = set(LOOPBACK_NAMES)
        for name in (host, *server_names):
            if name not in ("0.0.0.0", "::", ""):
                names.add(f"[{name}]" if ":" in name and not name.startswith("[") else name.lower())
        self.hosts = {f"{n}:{self.port}" for n in names}
        self.origins = {f"{scheme}://{h}" for h in self.hosts}

    def refuse(self, reason: str, why: str) -> web.Response:
        self.counters[f"door_refused_{reason}"] += 1
        return web.Response(
            status=403,
            text=REFUSED_PAGE.format(why=why),
            content_type="text/html",
            headers={"Cache-Control": "no-store"},
        )

    def why_not(self, request: web.Request) -> tuple[str, str] | None:
        """(reason, sentence) if this request may not pass Host and Origin; None if it may."""
        host = request.headers.get("Host", "").lower()
        if host not in self.hosts:
            return "host", "This console answers only to its own address (the Host header names another server)."
        origin = request.headers.get("Origin")
        if origin is not None and origin.lower() not in self.origins:
            return "origin", "A page from another origin may not use this console."
        return None

    def address(self) -> str:
        """A new one-use address (the printed one, or one an open page hands out)."""
        return console_address(self.scheme, self.host, self.port, self.keys.entry())

    @web.middleware
    async def middleware(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        guard = self.guard
        if guard is not None:
            guard.busy(request.transport, True)
        try:
            return await self.through(request, handler)
        finally:
            if guard is not None:
                guard.busy(request.transport, False)

    async def through(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        refused = self.why_not(request)
        if refused is not None:
            return self.refuse(*refused)
        if request.path == "/" or request.path.startswith(PUBLIC_PREFIX):
            return await handler(request)  # the page asks for its key itself
        if request.path == "/enter" and request.method == "POST":
            return self.enter(request)
        key = bearer(request) or (request.query.get("key") if request.path == "/ws" else None)
        if key is None:
            return self.refuse("no_token", "This page has no key to this console.")
        if not self.keys.valid("s", key):
            return self.refuse("token", "The key this page presented is not this console's.")
        if self.guard is not None:
            self.guard.authenticated(request.transport)
        return await handler(request)

    def enter(self, request: web.Request) -> web.Response:
        """An entry key (one use) for a session key."""
        outcome = self.keys.spend(bearer(request))
        if outcome == "spent":
            return self.refuse(
                "spent",
                "This address was used already: each printed address opens one page. "
                "An open page gives another (its 'another page' link).",
            )
        if outcome != "ok":
            return self.refuse("token", "The key in this address is not this console's.")
        self.counters["door_entered"] += 1
        return web.json_response({"key": self.keys.session()}, headers={"Cache-Control": "no-store"})
