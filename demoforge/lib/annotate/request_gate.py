"""Which requests the local annotation server answers: the gate every request passes before any route.

``demoforge annotate`` serves a page on loopback that reads frames and writes the take's
``annotations.json``. Loopback alone does not protect it: any web page open in another tab can send
"simple" cross-origin requests to ``127.0.0.1`` (a POST with ``Content-Type: text/plain`` needs no
preflight), and DNS rebinding lets a foreign site read answers under its own host name. The gate
refuses, as local web tools do (Jupyter's token, Host and Origin checks):

- a ``Host`` other than ``127.0.0.1:PORT`` or ``localhost:PORT`` (DNS rebinding), 403;
- a request without the session's token (``?token=`` in the URL the command prints, or the
  ``X-Demoforge-Token`` header the page sends), 403;
- a request that changes something (any method but GET/HEAD) whose ``Origin`` is not the page's
  own, 403;
- a body that is not ``Content-Type: application/json`` (415), has no length (411) or is larger
  than ``max_body_bytes`` (413).

Pure logic: the server (:mod:`demoforge.runtime.annotate`) asks :meth:`RequestGate.check` before it
looks at the route, so a route added later is gated without anyone thinking of it.
"""

from __future__ import annotations

import hmac
import secrets
from dataclasses import dataclass, field
from typing import Mapping
from urllib.parse import parse_qs, urlsplit

__all__ = ["TOKEN_HEADER", "TOKEN_PARAM", "MAX_BODY_BYTES", "Refusal", "RequestGate", "new_token"]

TOKEN_HEADER = "X-Demoforge-Token"
TOKEN_PARAM = "token"
#: The page's largest request (a save: 11 points, the ranges and the task) is a few kB.
MAX_BODY_BYTES = 1 << 20
SAFE_METHODS = ("GET", "HEAD")
LOOPBACK_NAMES = ("127.0.0.1", "localhost")


def new_token() -> str:
    """A random per-session token (192 bits, URL-safe)."""
    return secrets.token_urlsafe(24)


@dataclass(frozen=True)
class Refusal:
    """Why a request is refused: the HTTP status and one line for the client."""

    status: int
    reason: str


def _header(headers: Mapping[str, str], name: str) -> str | None:
    """A header's value, its name matched without regard to case (http.client's messages already do)."""
    value = headers.get(name)
    if value is None:
        lowered = name.lower()
        value = next((v for k, v in headers.items() if k.lower() == lowered), None)
    return value


@dataclass(frozen=True)
class RequestGate:
    """The checks of the module docstring for a server on ``127.0.0.1:port`` with ``token``."""

    port: int
    token: str = field(default_factory=new_token)
    max_body_bytes: int = MAX_BODY_BYTES

    @property
    def hosts(self) -> tuple[str, ...]:
        return tuple(f"{name}:{self.port}" for name in LOOPBACK_NAMES)

    @property
    def origins(self) -> tuple[str, ...]:
        return tuple(f"http://{host}" for host in self.hosts)

    def check(self, method: str, target: str, headers: Mapping[str, str]) -> Refusal | None:
        """None when the request may reach its route, else the :class:`Refusal` to answer with."""
        host = (_header(headers, "Host") or "").strip().lower()
        if host not in self.hosts:
            return Refusal(403, f"refused: Host {host or '(none)'!r} is not this server's "
                                f"({' or '.join(self.hosts)}); open the URL that demoforge annotate printed")
        if not self._token_ok(target, headers):
            return Refusal(403, "refused: missing or wrong session token; open the URL that demoforge annotate "
                                "printed (it ends in ?token=...)")
        if method.upper() in SAFE_METHODS:
            return None
        origin = _header(headers, "Origin")
        if origin is not None and origin.strip().lower() not in self.origins:
            return Refusal(403, f"refused: a request from {origin!r} may not change this take; only the "
                                f"annotation page itself ({self.origins[0]}) may")
        media_type = (_header(headers, "Content-Type") or "").split(";", 1)[0].strip().lower()
        if media_type != "application/json":
            return Refusal(415, f"refused: the body must be Content-Type application/json, got "
                                f"{media_type or '(none)'!r}")
        length = _header(headers, "Content-Length")
        if length is None or not length.strip().isdigit():
            return Refusal(411, "refused: the request must state its Content-Length")
        if int(length) > self.max_body_bytes:
            return Refusal(413, f"refused: a body of {int(length)} bytes is over the limit of "
                                f"{self.max_body_bytes} bytes")
        return None

    def _token_ok(self, target: str, headers: Mapping[str, str]) -> bool:
        given = _header(headers, TOKEN_HEADER)
        if given is None:
            given = next(iter(parse_qs(urlsplit(target).query).get(TOKEN_PARAM, [])), None)
        return given is not None and hmac.compare_digest(given.encode(), self.token.encode())
