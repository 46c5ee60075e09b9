"""Helpers for loopback tests and benchmarks: free ports and a router in a child process.

Not used by the product itself. Everything here has a timeout.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from types import TracebackType

import zenoh

from runtime.ports import LOOPBACK, free_tcp_port, tcp_endpoint, wait_for_tcp_port
from wire import acl
from wire.zconf import UsrPwdAuth, ZenohSettings

__all__ = ["LOOPBACK", "RouterProcess", "free_tcp_port", "has_matching_subscribers", "tcp_endpoint",
           "wait_for_matching", "wait_for_tcp_port"]

logger = logging.getLogger(__name__)

_REPO_ROOT = Path(__file__).resolve().parent.parent


def has_matching_subscribers(publisher: object) -> bool:
    """Whether a ``zenoh.Publisher`` (or a :class:`wire.traffic.CountingPublisher`) has matches.

    zenoh-python 1.10's ``Publisher.matching_status`` is a ``MatchingStatus`` object, always
    truthy (its stub says ``bool``); the answer is its ``matching`` attribute.
    """
    inner = getattr(publisher, "publisher", publisher)
    status = inner.matching_status  # type: ignore[attr-defined]
    return bool(getattr(status, "matching", status))


def wait_for_matching(publisher: object, timeout_s: float = 10.0) -> None:
    """Wait until ``publisher`` has a matching subscriber; ``TimeoutError`` if it gets none."""
    deadline = time.monotonic() + timeout_s
    while not has_matching_subscribers(publisher):
        if time.monotonic() >= deadline:
            raise TimeoutError(f"no subscriber matched the publisher within {timeout_s} s")
        time.sleep(0.002)


class RouterProcess:
    """``python -m runtime.router --listen tcp/127.0.0.1:PORT`` as a child process.

    ``with RouterProcess() as router: ... router.endpoint ...``; on exit the child gets SIGTERM,
    then SIGKILL if it has not exited within ``stop_timeout_s``. ``returncode`` holds its exit
    status afterwards.
    """

    def __init__(
        self,
        port: int | None = None,
        *,
        start_timeout_s: float = 10.0,
        stop_timeout_s: float = 5.0,
        log_level: str = "WARNING",
        config: Path | None = None,
    ) -> None:
        self.config = config  # a router configuration file (access control), or none
        self.port = free_tcp_port() if port is None else port
        self.endpoint = tcp_endpoint(self.port)
        self._start_timeout_s = start_timeout_s
        self._stop_timeout_s = stop_timeout_s
        self._log_level = log_level
        self._proc: subprocess.Popen[bytes] | None = None
        self.returncode: int | None = None

    def start(self) -> RouterProcess:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(
            p for p in (str(_REPO_ROOT), env.get("PYTHONPATH", "")) if p
        )
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "runtime.router", "--listen", self.endpoint,
             "--log-level", self._log_level,
             *(("--config", str(self.config)) if self.config is not None else ())],
            env=env,
            stdin=subprocess.DEVNULL,
        )
        try:
            deadline = time.monotonic() + self._start_timeout_s
            while True:
                if self._proc.poll() is not None:
                    raise RuntimeError(
                        f"router exited with status {self._proc.returncode} before listening"
                    )
                try:
                    wait_for_tcp_port(self.port, timeout_s=0.2)
                    break
                except TimeoutError:
                    if time.monotonic() >= deadline:
                        raise
        except BaseException:
            self.stop()
            raise
        return self

    def stop(self) -> int | None:
        """SIGTERM, wait, SIGKILL if needed; returns the exit status."""
        proc = self._proc
        if proc is None:
            return self.returncode
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(self._stop_timeout_s)
            except subprocess.TimeoutExpired:
                logger.warning("router pid %d ignored SIGTERM; killing it", proc.pid)
                proc.kill()
                proc.wait(self._stop_timeout_s)
        self.returncode = proc.returncode
        self._proc = None
        return self.returncode

    def poll(self) -> int | None:
        """The child's exit status if it has exited, else ``None``."""
        if self._proc is None:
            return self.returncode
        return self._proc.poll()

    def wait(self, timeout_s: float) -> int:
        """Wait for the child to exit on its own; ``subprocess.TimeoutExpired`` if it does not."""
        if self._proc is None:
            if self.returncode is None:
                raise RuntimeError("router was never started")
            return self.returncode
        return self._proc.wait(timeout_s)

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    def __enter__(self) -> RouterProcess:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()


@contextmanager
def fleet_acl_router(folder: Path, robots: Mapping[str, str], orders: bool = True
                     ) -> Iterator[tuple[str, dict[str, UsrPwdAuth]]]:
    """A router under a fleet's access control (:func:`wire.acl.fleet_acl` of ``robots``, robot
    id -> formation, with the order keys when ``orders``), its files in ``folder``; yields its
    endpoint and every user's credentials (the camera, manager, viewer and each robot)."""
    creds = acl.new_credentials([acl.CAMERA_USER, acl.MANAGER_USER, acl.VIEWER_USER, *robots])
    acl.write_dictionary(folder / "users.txt", creds)
    router = RouterProcess(start_timeout_s=15.0, config=folder / "router.json5")
    assert router.config is not None
    acl.write_router_config(router.config, acl.router_config(
        [router.endpoint], acl.fleet_acl(robots, robots, orders=orders),
        (folder / "users.txt").resolve()))
    with router:
        yield router.endpoint, creds


def open_as(router: tuple[str, Mapping[str, UsrPwdAuth]], user: str) -> zenoh.Session:
    """A client session on ``router`` (as :func:`fleet_acl_router` yields it) as ``user``."""
    endpoint, creds = router
    return zenoh.open(ZenohSettings(mode="client", connect=(endpoint,), multicast_scouting=False,
                                    connect_timeout_s=5.0, auth=creds[user]).to_config())
