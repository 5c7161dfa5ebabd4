"""Browser-facing protections of every response: cross-site request refusal and headers.

:class:`SecurityMiddleware` (installed by :func:`app.main.create_app`) is a pure ASGI
middleware, so it sees HTTP requests and websocket handshakes alike:

* **Cross-site requests are refused** (CSRF, cross-site websocket hijacking). The console
  authenticates by a cookie, which a browser also attaches to requests another page makes.
  ``SameSite=Strict`` stops other *sites*, but not another *origin of the same site* (a
  different port of the same host, e.g. viser's own port or another service on the clinic
  server). So a state-changing request (any method but GET/HEAD/OPTIONS) and every
  websocket handshake whose ``Origin`` (else ``Referer``) names another origin than the
  one the request was sent to (its ``Host``, or ``X-Forwarded-Host`` from a reverse proxy)
  is refused with 403, unless that origin is listed in ``Settings.allowed_origins``.
  Browsers always send ``Origin`` on such requests; scripts and nodes, which authenticate
  by bearer or pairing token and send no ``Origin``, are not affected.
* **Security headers**: ``Content-Security-Policy`` (the console: scripts only from this
  server plus the hashes of the inline ``<script>`` blocks of ``static/*.html``, no
  inline event handlers; the
  embedded 3D view, whose viser client unpacks its code into an inline module and runs
  WebAssembly, gets its own; frames only from this origin), ``X-Frame-Options:
  SAMEORIGIN`` (the console embeds ``/viewer/`` from the same origin),
  ``X-Content-Type-Options: nosniff``, ``Referrer-Policy: same-origin``,
  ``Cross-Origin-Opener-Policy``/``-Resource-Policy: same-origin``, a restrictive
  ``Permissions-Policy``, ``Strict-Transport-Security`` when the request came over HTTPS,
  and ``Cache-Control: no-store`` on every ``/api`` answer (health data and report PDFs
  must not stay in a shared browser's or proxy's cache).
"""

from __future__ import annotations

import base64
import hashlib
import json
import re
from collections.abc import Iterable
from pathlib import Path
from urllib.parse import urlsplit

from starlette.datastructures import Headers, MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

#: Methods that change nothing (RFC 9110 safe methods); every other one is checked.
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS", "TRACE"})

_INLINE_SCRIPT = re.compile(r"<script(?![^>]*\bsrc\s*=)[^>]*>(.*?)</script>",
                            re.DOTALL | re.IGNORECASE)

_HOST_CHARS = re.compile(r"[A-Za-z0-9.\-\[\]:]{1,255}")

#: Headers every HTTP answer carries (a route's own value wins where it set one).
BASE_HEADERS = {
    "x-content-type-options": "nosniff",
    "x-frame-options": "SAMEORIGIN",
    "referrer-policy": "same-origin",
    "cross-origin-opener-policy": "same-origin",
    "cross-origin-resource-policy": "same-origin",
    "permissions-policy": "camera=(), microphone=(), geolocation=(), usb=(), payment=()",
}

#: The 3D view (viser's client): it unpacks its bundle into an inline module script,
#: decompresses with WebAssembly and evaluates generated code, so it needs
#: 'unsafe-inline', 'unsafe-eval' and 'wasm-unsafe-eval' — for ``/viewer/`` only; the
#: console keeps the strict policy.
VIEWER_CSP = ("default-src 'self'; "
              "script-src 'self' 'unsafe-inline' 'unsafe-eval' 'wasm-unsafe-eval' blob:; "
              "style-src 'self' 'unsafe-inline'; img-src 'self' data: blob:; "
              "font-src 'self' data:; connect-src 'self' {ws} data: blob:; "
              "worker-src 'self' blob:; object-src 'none'; base-uri 'self'; "
              "form-action 'self'; frame-ancestors 'self'")

#: FastAPI's API description pages (no data) load Swagger UI / ReDoc from a CDN.
DOCS_CSP = ("default-src 'self'; script-src 'self' 'unsafe-inline' https://cdn.jsdelivr.net; "
            "style-src 'self' 'unsafe-inline' https://cdn.jsdelivr.net "
            "https://fonts.googleapis.com; font-src 'self' https://fonts.gstatic.com; "
            "img-src 'self' data: https://fastapi.tiangolo.com https://cdn.redoc.ly; "
            "worker-src 'self' blob:; connect-src 'self'; object-src 'none'; "
            "base-uri 'self'; frame-ancestors 'self'")


def inline_script_hashes(static_dir: Path) -> list[str]:
    """CSP source expressions (``'sha256-…'``) of the inline ``<script>`` blocks of the
    console's HTML pages, so the console's CSP allows exactly those and no injected one.

    Computed when the app is created, so a page edited later needs no list kept by hand.
    """
    found: set[str] = set()
    for page in sorted(static_dir.glob("*.html")) if static_dir.is_dir() else []:
        for body in _INLINE_SCRIPT.findall(page.read_text(encoding="utf-8", errors="replace")):
            digest = base64.b64encode(hashlib.sha256(body.encode()).digest()).decode()
            found.add(f"'sha256-{digest}'")
    return sorted(found)


def console_csp(script_hashes: Iterable[str]) -> str:
    """The console's CSP template (``{ws}``: this server's websocket origins)."""
    # No 'unsafe-eval': the console's code never evaluates a string. The browser tests'
    # driver does (Playwright's wait_for_function), so their contexts bypass the policy,
    # except tests/browser/test_csp.py, which opens every page under it.
    scripts = " ".join(["'self'", *script_hashes])
    return (f"default-src 'self'; script-src {scripts}; style-src 'self' 'unsafe-inline'; "
            "img-src 'self' data: blob:; font-src 'self' data:; connect-src 'self' {ws}; "
            "worker-src 'self'; frame-src 'self'; object-src 'none'; base-uri 'self'; "
            "form-action 'self'; frame-ancestors 'self'")


def _authority(url: str) -> tuple[str, str, int] | None:
    """``(scheme, host, port)`` of an absolute http(s)/ws(s) URL, or None."""
    try:
        p = urlsplit(url.strip())
        port = p.port
    except ValueError:
        return None
    scheme = {"ws": "http", "wss": "https"}.get(p.scheme.lower(), p.scheme.lower())
    if scheme not in ("http", "https") or not p.hostname:
        return None
    return scheme, p.hostname.lower(), port or (443 if scheme == "https" else 80)


def _host_port(host_header: str, default_port: int) -> tuple[str, int] | None:
    try:
        p = urlsplit("//" + host_header.strip())
        port = p.port
    except ValueError:
        return None
    if not p.hostname:
        return None
    return p.hostname.lower(), port or default_port


def origin_allowed(origin: str, headers: Headers, allowed: frozenset[tuple[str, str, int]]
                   ) -> bool:
    """Whether a request's ``Origin`` (or ``Referer``) is the server's own origin.

    The server's own origin is the ``Host`` the browser sent the request to (or the
    ``X-Forwarded-Host`` a reverse proxy set: a page cannot add that header to a
    cross-origin request without a CORS pre-flight, which this server never grants).
    The scheme is not compared: behind a TLS proxy the browser says https, the server
    sees http.
    """
    got = _authority(origin)
    if got is None:  # "null" (sandboxed frames, file: pages, privacy-stripped) and garbage
        return False
    if got in allowed:
        return True
    scheme, host, port = got
    default = 443 if scheme == "https" else 80
    for name in ("host", "x-forwarded-host"):
        for value in headers.getlist(name):
            for one in value.split(","):
                if _host_port(one, default) == (host, port):
                    return True
    return False


class SecurityMiddleware:
    """Refuses cross-site state changes and websockets; adds the security headers.

    Args:
        app: the ASGI app to wrap.
        allowed_origins: further origins (``https://console.example.org``) whose pages may
            send state-changing requests (the console served under another name by a
            proxy that rewrites ``Host``).
        static_dir: the console's folder (its inline scripts' hashes go into the CSP).
    """

    def __init__(self, app: ASGIApp, allowed_origins: Iterable[str] = (),
                 static_dir: Path | None = None) -> None:
        self.app = app
        self.allowed = frozenset(a for a in map(_authority, allowed_origins) if a is not None)
        self.console_csp = console_csp(inline_script_hashes(static_dir) if static_dir else [])

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        if scope["type"] == "websocket" or scope["method"] not in SAFE_METHODS:
            origin = headers.get("origin") or (
                headers.get("referer") if scope["type"] == "http" else None)
            if origin is not None and not origin_allowed(origin, headers, self.allowed):
                await self._refuse(scope, send, origin)
                return
        if scope["type"] == "websocket":
            await self.app(scope, receive, send)
            return
        await self.app(scope, receive, self._with_headers(scope, headers, send))

    def _csp(self, path: str, headers: Headers) -> str:
        if path.startswith("/viewer"):
            template = VIEWER_CSP
        elif path in ("/docs", "/redoc", "/docs/oauth2-redirect"):
            return DOCS_CSP
        else:
            template = self.console_csp
        host = headers.get("host", "")
        # connect-src 'self' covers same-origin websockets only in CSP level 3 browsers;
        # a Host with anything but name/address characters adds nothing to the policy
        ok = _HOST_CHARS.fullmatch(host) and _host_port(host, 80) is not None
        ws = f"ws://{host} wss://{host}" if ok else ""
        return template.replace("{ws}", ws)

    def _with_headers(self, scope: Scope, headers: Headers, send: Send) -> Send:
        path: str = scope.get("path", "")
        https = scope.get("scheme") == "https"

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                h = MutableHeaders(scope=message)
                for k, v in BASE_HEADERS.items():
                    if k not in h:
                        h[k] = v
                if "content-security-policy" not in h:
                    h["content-security-policy"] = self._csp(path, headers)
                if path.startswith("/api/") or path == "/api":
                    h["cache-control"] = "no-store"  # health data: never in a cache
                if https and "strict-transport-security" not in h:
                    h["strict-transport-security"] = "max-age=31536000"
            await send(message)

        return send_with_headers

    @staticmethod
    async def _refuse(scope: Scope, send: Send, origin: str) -> None:
        reason = (f"cross-site request refused: a page at {origin[:100]!r} may not change "
                  "data on this server. Use the console at this server's own address; if "
                  "a reverse proxy serves it under another one, list that address in "
                  "GAITRIG_ALLOWED_ORIGINS")
        if scope["type"] == "websocket":
            # before accept: the server answers the handshake with HTTP 403
            await send({"type": "websocket.close", "code": 4403, "reason": "cross-site"})
            return
        body = json.dumps({"detail": reason}).encode()
        await send({"type": "http.response.start", "status": 403,
                    "headers": [(b"content-type", b"application/json"),
                                (b"content-length", str(len(body)).encode()),
                                (b"cache-control", b"no-store"),
                                *((k.encode(), v.encode()) for k, v in BASE_HEADERS.items())]})
        await send({"type": "http.response.body", "body": body})
