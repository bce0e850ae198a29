"""Who may command the vehicle from the dashboard: the session's token, the page's origin, and one
holder at a time.

Viewing is open to whoever can reach the dashboard (loopback by default). Control (arming, the
references, the controller and feedback choices) is accepted only from a tab

* that connected with the session's token, which the command line prints at start, as Jupyter
  does: ``http://127.0.0.1:8080/?websocket=ws://127.0.0.1:8080/control/<token>`` (viser's client
  opens its websocket at the ``websocket`` parameter's address, and the token is its path);
* whose ``Origin`` (what a browser sends with every websocket) is the dashboard's own page, so that
  another web page open in the operator's browser cannot drive it, and whose ``Host`` is an address
  the dashboard serves on (a DNS-rebinding page names its own host);
* and that holds control: one tab at a time takes it (``Take control``), the others see which tab
  holds it, and an authorised tab may take it over (to stop a vehicle whose holder's tab hangs),
  which the panel says.

Binding to an address other than loopback needs ``allow_remote`` (``--allow-remote``): the
dashboard is then viewable from the network, and the token is the only key to control.
"""

from __future__ import annotations

import ipaddress
import secrets
from dataclasses import dataclass, field

LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def _all(headers, name: str) -> list[str]:
    """Every value of header ``name`` (websockets' ``Headers.get`` raises on a header named twice)."""
    get_all = getattr(headers, "get_all", None)
    if get_all is not None:
        return [str(v) for v in get_all(name)]
    v = headers.get(name)
    return [] if v is None else [str(v)]


class RemoteRefused(ValueError):
    """Binding to a non-loopback address without ``allow_remote`` (one line)."""


def remote_refusal(host: str, allow_remote: bool) -> str | None:
    """Why a dashboard may not be served on ``host`` (one line), or None: a network address needs
    ``allow_remote``."""
    if is_loopback(host) or allow_remote:
        return None
    return (
        f"dashboard on {host}: that exposes it to the network; pass --allow-remote to do so "
        "(control then needs the session's token)"
    )


@dataclass
class Authority:
    host: str
    port: int
    allow_remote: bool = False
    token: str = field(default_factory=lambda: secrets.token_urlsafe(18))
    #: the client id holding control, if one does
    holder: int | None = None

    def __post_init__(self) -> None:
        why = remote_refusal(self.host, self.allow_remote)
        if why is not None:
            raise RemoteRefused(why)

    # -- addresses -------------------------------------------------------------------------------
    @property
    def _shown_host(self) -> str:
        return "127.0.0.1" if self.host in ("0.0.0.0", "::", "") else self.host

    @property
    def view_url(self) -> str:
        return f"http://{self._shown_host}:{self.port}"

    @property
    def control_url(self) -> str:
        return f"{self.view_url}/?websocket=ws://{self._shown_host}:{self.port}/control/{self.token}"

    def _hosts(self) -> set[str]:
        names = set(LOOPBACK_NAMES) | {self.host, self._shown_host}
        return {f"{h}:{self.port}" for h in names}

    # -- who may command ---------------------------------------------------------------------------
    def refusal(self, path: str, headers) -> str | None:
        """Why a connection with this request path and headers may not command, or None. A request
        that names its Host or Origin more than once is malformed, and refused: which one would a
        browser have meant?"""
        if path.split("?")[0].rstrip("/") != f"/control/{self.token}":
            return "view only: open the control address the command line printed (it carries the session's token)"
        hosts, origins = _all(headers, "Host"), _all(headers, "Origin")
        if len(hosts) > 1 or len(origins) > 1:
            return "view only: a malformed request (a header named twice)"
        host = hosts[0] if hosts else ""
        if not self.allow_remote and host not in self._hosts():
            return f"view only: the page came through {host or 'no host'}, not this dashboard's address"
        origin = origins[0] if origins else None
        if origin is not None:
            allowed = {f"http://{h}" for h in self._hosts()} | {f"https://{h}" for h in self._hosts()}
            if self.allow_remote:
                allowed.add(f"http://{host}")
            if origin not in allowed:
                return f"view only: a page from {origin} may not command this vehicle"
        return None

    def take(self, client_id: int) -> str:
        """``client_id`` (already authorised) holds control from now on; what happened, in words."""
        before, self.holder = self.holder, client_id
        if before is None or before == client_id:
            return f"tab {client_id} holds control"
        return f"tab {client_id} took control over from tab {before}"

    def left(self, client_id: int) -> None:
        if self.holder == client_id:
            self.holder = None

    def holds(self, client_id: int) -> bool:
        return self.holder is not None and self.holder == client_id

    def command_refusal(self, request_refusal: str | None, client_id: int | None) -> str | None:
        """Why the tab ``client_id`` may not command now (``request_refusal``: what its request
        says against it, :meth:`refusal`), or None: it may, as the tab holding control."""
        if request_refusal is not None:
            return request_refusal
        if client_id is None or not self.holds(client_id):
            held = self.holder
            if held is not None:
                return f"tab {held} holds control; press Take control first"
            return "nobody holds control: press Take control first"
        return None
