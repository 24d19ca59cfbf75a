"""Who may open the console: the console's door, checked on every HTTP request and WebSocket upgrade.

Three checks, in this order, before anything of the run is served (docs/security.md):

1. `Host` must name this console: a loopback name (127.0.0.1, localhost, [::1]) or the configured host, with the
   console's own port. A DNS-rebinding page (`http://evil.example:PORT`, resolved to 127.0.0.1) sends its own name
   and is refused.
2. `Origin`, when a browser sends one (it always does on a WebSocket upgrade and on cross-origin requests), must be
   this console's own origin: a page served from another port, another host or a `file://` page (`Origin: null`)
   is refused.
3. The per-run secret: `?token=T` in the printed address (as Jupyter does) is exchanged for an HttpOnly,
   SameSite=Strict cookie named after the port and the browser is redirected to the clean URL; afterwards the
   cookie opens the door. Without either: 403 and a short page saying where the address comes from.

The token lives in a file (`token_file`, mode 0600) so that a restarted console keeps it and open pages keep
working; without one the console makes its own and prints it.
"""
from __future__ import annotations

import hashlib
import hmac
import os
import secrets
from pathlib import Path
from urllib.parse import urlencode

from aiohttp import web

LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")
REFUSED_PAGE = """<!doctype html><html lang="en"><meta charset="utf-8"><title>console: not open to this page</title>
<body style="font-family:sans-serif;max-width:40em;margin:3em auto"><h1>Not open to this page</h1>
<p>{why}</p><p>Open the console from the address that <code>python -m services up --teacher web</code> printed
(<code>http://127.0.0.1:PORT/?token=...</code>): the token in it lets your browser in.</p></body></html>"""


def read_or_make_token(path: str | None) -> str:
    """The run's console token: the one in `path` if it exists, else a new one (written there, mode 0600)."""
    if path is None:
        return secrets.token_urlsafe(24)
    p = Path(path)
    if p.exists():
        token = p.read_text().strip()
        if len(token) >= 16:
            return token
    p.parent.mkdir(parents=True, exist_ok=True)
    token = secrets.token_urlsafe(24)
    fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(token + "\n")
    return token


def console_address(scheme: str, host: str, port: int, token: str) -> str:
    name = f"[{host}]" if ":" in host and not host.startswith("[") else host
    return f"{scheme}://{name}:{port}/?token={token}"


class Door:
    """The checks above, as an aiohttp middleware (`door.middleware`); counts every refusal by reason."""

    def __init__(self, token: str, host: str, port: int, scheme: str, counters, server_names: tuple[str, ...] = ()):
        self.token, self.port, self.scheme, self.counters = token, int(port), scheme, counters
        names = set(LOOPBACK_NAMES)
        for name in (host, *server_names):
            if name not in ("0.0.0.0", "::", ""):
                names.add(f"[{name}]" if ":" in name and not name.startswith("[") else name.lower())
        self.hosts = {f"{n}:{self.port}" for n in names}
        self.origins = {f"{scheme}://{h}" for h in self.hosts}
        self.cookie_name = f"hitl-console-{self.port}"
        self.cookie_value = hmac.new(token.encode(), b"hitl-console-cookie", hashlib.sha256).hexdigest()

    def refuse(self, reason: str, why: str) -> web.Response:
        self.counters[f"door_refused_{reason}"] += 1
        return web.Response(status=403, text=REFUSED_PAGE.format(why=why), content_type="text/html")

    def why_not(self, request: web.Request) -> tuple[str, str] | None:
        """(reason, sentence) if this request may not pass; None if it may (token or cookie still to check)."""
        host = request.headers.get("Host", "").lower()
        if host not in self.hosts:
            return "host", "This console answers only to its own address (the Host header names another server)."
        origin = request.headers.get("Origin")
        if origin is not None and origin.lower() not in self.origins:
            return "origin", "A page from another origin may not use this console."
        return None

    @web.middleware
    async def middleware(self, request: web.Request, handler):
        refused = self.why_not(request)
        if refused is not None:
            return self.refuse(*refused)
        given = request.query.get("token")
        if given is not None:
            if not hmac.compare_digest(given.encode(), self.token.encode()):
                return self.refuse("token", "The token in this address is not this console's.")
            if request.path != "/ws":  # the address with the token: keep it as a cookie, show the clean URL
                rest = [(k, v) for k, v in request.query.items() if k != "token"]
                raise web.HTTPSeeOther(request.path + ("?" + urlencode(rest) if rest else ""),
                                       headers={"Set-Cookie": self.cookie_header(), "Cache-Control": "no-store"})
            return await handler(request)
        cookie = request.cookies.get(self.cookie_name, "")
        if not hmac.compare_digest(cookie.encode(), self.cookie_value.encode()):
            return self.refuse("no_token", "This browser has not been let in yet.")
        return await handler(request)

    def cookie_header(self) -> str:
        secure = "; Secure" if self.scheme == "https" else ""
        return f"{self.cookie_name}={self.cookie_value}; Path=/; HttpOnly; SameSite=Strict{secure}"
