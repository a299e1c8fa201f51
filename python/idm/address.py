"""Which idmd a client talks to when the caller names none: ``IDMD_SOCKET=path``, else
``IDMD_ADDRESS=host:port``, else TCP 127.0.0.1:5025 -- the same rules, and the same messages, as
the C++ clients' ``client::address_from_environment`` (idmctl, idm-web, idm-tango)."""

from __future__ import annotations

import os
from typing import Mapping, NamedTuple, Optional

__all__ = ["Address", "DEFAULT_HOST", "DEFAULT_PORT", "parse_host_port",
           "address_from_environment"]

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 5025
_HOST_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789.-_:%")


class Address(NamedTuple):
    host: str
    port: int
    unix: Optional[str]  # when set, host and port are not used


def parse_host_port(text: str, default_port: int = DEFAULT_PORT) -> Address:
    """``host:port``, ``[v6 address]:port`` or ``host`` alone (port ``default_port``); the port
    1..65535. ValueError naming the text and what is wrong."""
    shown = text[:200]
    host, port = text, None
    if text.startswith("["):
        close = text.find("]")
        if close < 0:
            raise ValueError("'%s': a '[' without its ']'" % shown)
        host, rest = text[1:close], text[close + 1:]
        if rest:
            if not rest.startswith(":"):
                raise ValueError("'%s': expected ':PORT' after ']'" % shown)
            port = rest[1:]
            if not port:
                raise ValueError("'%s': an empty port" % shown)
    elif ":" in text:
        if text.count(":") > 1:
            raise ValueError("'%s': an IPv6 address goes in brackets: [ADDRESS]:PORT" % shown)
        host, port = text.split(":")
        if not port:
            raise ValueError("'%s': an empty port" % shown)
    if not host:
        raise ValueError("'%s': an empty host" % shown)
    if not set(host) <= _HOST_CHARS:
        raise ValueError("'%s': the host holds a character a host name cannot" % shown)
    if port is None:
        return Address(host, default_port, None)
    if len(port) > 5 or not port.isdigit() or not port.isascii():
        raise ValueError("'%s': the port is not a number in 1..65535" % shown)
    if not 1 <= int(port) <= 65535:
        raise ValueError("'%s': the port is out of range, allowed 1..65535" % shown)
    return Address(host, int(port), None)


def address_from_environment(environ: Optional[Mapping[str, str]] = None) -> Address:
    """``IDMD_SOCKET=path``, else ``IDMD_ADDRESS=host:port``, else 127.0.0.1:5025. Both set is
    an error (ValueError), as is an address that does not parse."""
    env = os.environ if environ is None else environ
    socket_path, address = env.get("IDMD_SOCKET", ""), env.get("IDMD_ADDRESS", "")
    if socket_path and address:
        raise ValueError("IDMD_SOCKET and IDMD_ADDRESS are both set: set one")
    if socket_path:
        return Address(DEFAULT_HOST, DEFAULT_PORT, socket_path)
    if address:
        try:
            return parse_host_port(address)
        except ValueError as e:
            raise ValueError("IDMD_ADDRESS: %s" % e) from None
    return Address(DEFAULT_HOST, DEFAULT_PORT, None)
