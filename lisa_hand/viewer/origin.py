"""Who may talk to ``lisa view``: its web server answers its own page and local programs only.

A page open in the user's browser may open a websocket to any address, 127.0.0.1 included: the
same-origin policy does not cover websockets. The browser names the page that asks in the
``Origin`` header, and only the server can refuse it. Without this check any web site the user
visits could drive the viewer's panel, and its Export button writes files.

The rule (:func:`origin_allowed`): a request is answered when it carries no ``Origin`` (not a
web page: a local script, ``curl``; a browser always sends one with a websocket handshake) or
the viewer's own origin, ``http://HOST:PORT`` with PORT the viewer's port and HOST a loopback
name (``127.0.0.1``, ``localhost``, ``[::1]``) or the address the request came in on (a viewer
served on 0.0.0.0 and opened as ``http://192.168.1.5:8080``). Everything else gets 403
Forbidden before the handshake: other sites, ``null`` (a sandboxed frame, a ``file://`` page),
another port of localhost (another local server's page), and host names other than
``localhost`` even when they resolve to this machine (a DNS-rebinding page has such a name:
open a viewer served on 0.0.0.0 by its IP address).

viser 1.1.1 has no option for this; it serves through ``websockets.asyncio.server.serve``,
whose ``process_request`` hook sees every request first. :func:`origin_checked_servers` wraps
the ``process_request`` viser passes, for the servers started while it is open (viser starts
its server inside ``ViserServer()``, which returns only once it listens).
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from http import HTTPStatus
from typing import Any

__all__ = ["LOOPBACK_NAMES", "OriginGuard", "origin_allowed", "origin_checked",
           "origin_checked_servers"]

LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")
"""Host names of the viewer's own page on this machine."""

_log = logging.getLogger(__name__)
_install_lock = threading.Lock()


def _url_host(address: str) -> str:
    """An IP address as a URL writes it: IPv6 in brackets, IPv4-mapped IPv6 as IPv4."""
    try:
        ip = ipaddress.ip_address(address.split("%")[0])
    except ValueError:
        return address.lower()
    if isinstance(ip, ipaddress.IPv6Address):
        return str(ip.ipv4_mapped) if ip.ipv4_mapped is not None else f"[{ip.compressed}]"
    return str(ip)


def origin_allowed(origin: str | None, port: int, local_host: str | None = None) -> bool:
    """Whether a request with header ``Origin: origin`` (None: no such header) may talk to the
    viewer served on ``port``; ``local_host``: the IP address the request came in on (see the
    module docstring)."""
    if origin is None:
        return True
    hosts = set(LOOPBACK_NAMES)
    if local_host:
        hosts.add(_url_host(local_host))
    allowed = {f"http://{host}:{port}" for host in hosts}
    if port == 80:  # a browser leaves out the scheme's default port
        allowed |= {f"http://{host}" for host in hosts}
    return origin.strip().lower() in allowed


def origin_checked(process_request: Callable[..., Any] | None) -> Callable[..., Any]:
    """A websockets ``process_request`` hook that answers 403 Forbidden to a request whose
    ``Origin`` :func:`origin_allowed` refuses (or that has several), then hands the others to
    ``process_request`` (None: none)."""

    def checked(connection: Any, request: Any) -> Any:
        origins = request.headers.get_all("Origin")
        host, port = connection.local_address[:2]
        if len(origins) > 1 or not origin_allowed(origins[0] if origins else None, port, host):
            _log.warning("lisa view: refused a connection from %r (not the viewer's page)",
                         origins[0][:200] if len(origins) == 1 else origins[:4])
            return connection.respond(HTTPStatus.FORBIDDEN,
                                      "lisa view answers its own page only\n")
        return None if process_request is None else process_request(connection, request)

    return checked


@dataclass
class OriginGuard:
    """What :func:`origin_checked_servers` did: ``servers``, how many servers it checks."""

    servers: int = 0


@contextlib.contextmanager
def origin_checked_servers() -> Iterator[OriginGuard]:
    """While open, every server started by ``websockets.asyncio.server.serve`` (viser's)
    refuses foreign origins (:func:`origin_checked`). Openings are serialized by a lock.
    -> an :class:`OriginGuard` (``servers == 0`` afterwards: nothing was protected)."""
    import websockets.asyncio.server as ws_server

    guard = OriginGuard()
    with _install_lock:
        original = ws_server.serve

        def serve(*args: Any, process_request: Callable[..., Any] | None = None,
                  **kwargs: Any) -> Any:
            guard.servers += 1
            return original(*args, process_request=origin_checked(process_request), **kwargs)

        ws_server.serve = serve  # type: ignore[assignment, misc]
        try:
            yield guard
        finally:
            ws_server.serve = original  # type: ignore[misc]
