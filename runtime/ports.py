"""Loopback TCP ports for a fleet on one machine: a free port, its zenoh endpoint, waiting for a
listener. Used by the launcher, the benchmarks and the tests. Everything here has a timeout."""

from __future__ import annotations

import socket
import time

LOOPBACK = "127.0.0.1"


def free_tcp_port(host: str = LOOPBACK) -> int:
    """A TCP port the OS reports free on ``host`` right now (another process may take it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])


def tcp_endpoint(port: int, host: str = LOOPBACK) -> str:
    """The zenoh endpoint ``tcp/{host}:{port}``."""
    if not 0 < port < 65536:
        raise ValueError(f"port {port!r} must be in 1..65535")
    return f"tcp/{host}:{port}"


def wait_for_tcp_port(port: int, host: str = LOOPBACK, timeout_s: float = 10.0) -> None:
    """Wait until something accepts TCP connections on ``host:port``; ``TimeoutError`` if not."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with socket.create_connection((host, port), timeout=0.2):
                return
        except OSError:
            if time.monotonic() >= deadline:
                message = f"nothing listens on {host}:{port} after {timeout_s} s"
                raise TimeoutError(message) from None
            time.sleep(0.02)
