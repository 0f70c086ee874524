"""HOST:PORT as a user gives it (a launcher's rendezvous, a Ray cluster): parsed, resolved and,
where asked, tried, so that a wrong address is one line at once rather than a library's
retries for minutes."""

from __future__ import annotations

import socket

from labcli.errors import LabError


def parse(value: str, option: str, example: str) -> tuple[str, int]:
    """`value` as a host this machine can resolve and a port; `option` and `example` name the
    flag and a right value in the error."""
    host, _, port = value.rpartition(":")
    host = host.removeprefix("[").removesuffix("]")  # an IPv6 address, [::1]:29400
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise LabError(f"{option} '{value}' is not HOST:PORT",
                       f"e.g. {option} {example} (a port from 1 to 65535)")
    try:
        socket.getaddrinfo(host, int(port), type=socket.SOCK_STREAM)
    except (OSError, UnicodeError) as exc:
        raise LabError(f"{option} '{value}': host '{host}' cannot be resolved ({exc})",
                       "pass the host's name or address") from None
    return host, int(port)


def check_answers(host: str, port: int, timeout_s: float, what: str, hint: str) -> None:
    """A LabError unless something accepts a TCP connection at host:port within `timeout_s`."""
    try:
        socket.create_connection((host, port), timeout=timeout_s).close()
    except TimeoutError:
        raise LabError(f"{what}: nothing answered at {host}:{port} within {timeout_s:g} s",
                       hint) from None
    except OSError as exc:
        raise LabError(f"{what}: nothing answers at {host}:{port} ({exc.strerror or exc})",
                       hint) from None
