"""Who may talk to the panel, and what a request may carry: pure checks, no aiohttp.

- The Host allow-list: the panel answers only the names it was told it is reached by
  (localhost, 127.0.0.1, [::1], the ``--listen`` host and every ``--allow-host``). A page of
  another site that re-resolves its own name to the panel's address (DNS rebinding) sends
  its own name as Host, and is answered 421 before anything else runs.
- The Origin of a browser's request, when it sends one, must name an allowed host too: it is
  checked against the list, never against the request's own Host (which a rebinding page
  chooses).
- The token: at least 128 bits, from an owner-only file or the environment. Given as
  ``Authorization: Bearer TOKEN`` (scripts) or as the cookie the page gets from its login
  POST (an ``EventSource`` cannot set headers). The cookie holds an HMAC of the token, not
  the token.
- A JSON body: at most ``MAX_JSON_BYTES`` and ``MAX_JSON_DEPTH`` levels of nesting, the depth
  counted by a flat scan before ``json.loads`` (which recurses, and raises RecursionError on
  a few KB of ``[``)."""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
import json
import math
import re
import stat
import string
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

__all__ = [
    "LOOPBACK_NAMES",
    "MAX_JSON_BYTES",
    "MAX_JSON_DEPTH",
    "MIN_TOKEN_BITS",
    "SESSION_COOKIE",
    "BodyRefused",
    "HostAllowList",
    "TokenCheck",
    "TokenRefused",
    "host_name",
    "is_loopback",
    "parse_json_body",
    "read_token_file",
    "token_bits",
]

LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})
MIN_TOKEN_BITS = 128
MAX_JSON_BYTES = 16_384  # a control's arguments: a material's fields are well under 1 KB
MAX_JSON_DEPTH = 8  # the controls take flat objects; 8 leaves room and stops a 14 KB '[[[['
SESSION_COOKIE = "dthc_panel"
_COOKIE_LABEL = b"dthc-panel-cookie-v1"
# The alphabets a token is scored by: the smallest that holds every character of it.
_ALPHABETS = (
    (frozenset(string.hexdigits), 4.0),  # token_hex, openssl rand -hex
    (frozenset(string.ascii_letters + string.digits + "-_"), 6.0),  # token_urlsafe
    (frozenset(string.ascii_letters + string.digits + "+/="), 6.0),  # base64
    (frozenset(string.printable.strip()), math.log2(94)),
)
# Strings (with their escapes) or the brackets between them: what a depth count must tell apart.
_JSON_TOKENS = re.compile(rb'"(?:[^"\\]|\\.)*"|[\[\]{}]', re.DOTALL)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a name: it may resolve to anything


def host_name(authority: str) -> str:
    """The host of a Host header or URL authority, lower case, without port or brackets:
    ``[::1]:8080`` -> ``::1``, ``Panel.Local.:80`` -> ``panel.local``."""
    authority = authority.strip().lower()
    if authority.startswith("["):
        return authority[1:].partition("]")[0]
    if authority.count(":") > 1:  # a bare IPv6 address (no port can be told apart)
        return authority
    return authority.partition(":")[0].rstrip(".")


@dataclass(frozen=True)
class HostAllowList:
    """The names the panel is reached by."""

    names: frozenset[str]

    @classmethod
    def build(cls, listen_host: str, extra: Iterable[str] = ()) -> HostAllowList:
        names = set(LOOPBACK_NAMES)
        for name in (listen_host, *extra):
            host = host_name(name) if name.startswith("[") else name.strip().lower().rstrip(".")
            if not _unspecified(host):  # 0.0.0.0 and :: are no one's Host
                names.add(host)
        return cls(frozenset(names))

    @property
    def loopback_only(self) -> bool:
        return all(is_loopback(name) for name in self.names)

    def allows_host(self, header: str) -> bool:
        return host_name(header) in self.names

    def allows_origin(self, origin: str) -> bool:
        """An Origin header's scheme is http(s) and its host is allowed. Its port is not
        compared: behind a TLS proxy the page's port is the proxy's."""
        try:
            parts = urlsplit(origin)
        except ValueError:
            return False
        return parts.scheme in ("http", "https") and host_name(parts.netloc) in self.names


def _unspecified(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_unspecified
    except ValueError:
        return False


class TokenRefused(Exception):
    """A token the panel will not start with: the reason, naming where it came from."""


def token_bits(token: str) -> float:
    """The bits a token of random characters holds: its length times the bits per character
    of the smallest usual alphabet it fits (hex 4, base64/base64url 6, printable ASCII 6.55).
    A token of other characters scores by printable ASCII too."""
    chars = set(token)
    for alphabet, bits in _ALPHABETS:
        if chars <= alphabet:
            return len(token) * bits
    return len(token) * _ALPHABETS[-1][1]


def check_token(token: str, source: str) -> str:
    """``token`` if it is strong enough, else TokenRefused naming ``source``."""
    if not token:
        raise TokenRefused(f"{source}: the token is empty")
    bits = token_bits(token)
    if bits < MIN_TOKEN_BITS:
        raise TokenRefused(
            f"{source}: the token holds about {bits:.0f} bits ({len(token)} characters); "
            f"at least {MIN_TOKEN_BITS} are needed, e.g. "
            "python3 -c 'import secrets; print(secrets.token_urlsafe(32))'"
        )
    return token


def read_token_file(path: Path) -> str:
    """The token in ``path``: refused when group or others may read or write the file (its
    mode & 0o077), when it is empty or too short. OSError when it cannot be read."""
    mode = stat.S_IMODE(path.stat().st_mode)
    if mode & 0o077:
        raise TokenRefused(
            f"--token-file {path}: mode {mode:04o} lets group or others at the token; "
            f"chmod 600 {path}"
        )
    return check_token(path.read_text().strip(), f"--token-file {path}")


@dataclass(frozen=True)
class TokenCheck:
    """The panel's token, as a Bearer header or as the login cookie's value."""

    token: str

    @property
    def cookie_value(self) -> str:
        """What the login cookie holds: an HMAC of the token, so the cookie never is it."""
        return hmac.new(self.token.encode(), _COOKIE_LABEL, hashlib.sha256).hexdigest()

    def matches(self, given: str) -> bool:
        return hmac.compare_digest(given.encode(), self.token.encode())

    def allows(self, authorization: str, cookie: str | None) -> bool:
        scheme, _, given = authorization.partition(" ")
        if scheme == "Bearer" and self.matches(given):
            return True
        return cookie is not None and hmac.compare_digest(
            cookie.encode(), self.cookie_value.encode()
        )


class BodyRefused(ValueError):
    """A request body the panel will not parse: the reason, naming the limit."""


def json_depth_exceeds(body: bytes, limit: int) -> bool:
    """Whether ``body`` nests arrays and objects deeper than ``limit`` (a flat scan: brackets
    inside strings do not count)."""
    depth = 0
    for match in _JSON_TOKENS.finditer(body):
        token = match.group()
        if token in (b"[", b"{"):
            depth += 1
            if depth > limit:
                return True
        elif token in (b"]", b"}"):
            depth -= 1
    return False


def parse_json_body(
    body: bytes, *, max_bytes: int = MAX_JSON_BYTES, max_depth: int = MAX_JSON_DEPTH
) -> Any:
    """The JSON document in ``body``, or BodyRefused naming the limit it breaks (size, depth,
    not JSON at all)."""
    if len(body) > max_bytes:
        raise BodyRefused(f"the body is over {max_bytes} bytes (MAX_JSON_BYTES)")
    if json_depth_exceeds(body, max_depth):
        raise BodyRefused(f"the body nests deeper than {max_depth} levels (MAX_JSON_DEPTH)")
    try:
        return json.loads(body) if body.strip() else {}
    except (ValueError, RecursionError) as exc:  # RecursionError: cannot pass the scan
        raise BodyRefused("the body is not JSON") from exc
