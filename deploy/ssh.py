"""Run commands on and copy files to robots with the system OpenSSH client (``ssh``, ``scp``).

Every call is an ``asyncio`` subprocess, so many robots are served at once. Options on every
call: ``BatchMode=yes`` (never prompt: a missing key fails at once), ``StrictHostKeyChecking=
accept-new`` with a project-local ``UserKnownHostsFile`` (a robot's host key is learnt on first
contact and checked from then on; a changed key fails), ``ConnectTimeout``, ``IdentitiesOnly``
with the inventory's key, and ``LogLevel=ERROR`` so the robot's banner does not end up in reports.
"""

from __future__ import annotations

import asyncio
import logging
import shlex
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

logger = logging.getLogger(__name__)

SSH = "ssh"
SCP = "scp"
EXIT_SSH_ERROR = 255  # ssh's own failure (connection, authentication)


@dataclass(frozen=True)
class SshTarget:
    host: str
    port: int
    user: str
    key: Path
    known_hosts: Path
    connect_timeout: float = 10.0  # [s]

    def options(self) -> list[str]:
        return [
            "-o", "BatchMode=yes",
            "-o", "StrictHostKeyChecking=accept-new",
            "-o", f"UserKnownHostsFile={self.known_hosts}",
            "-o", f"ConnectTimeout={max(1, round(self.connect_timeout))}",
            "-o", "IdentitiesOnly=yes",
            "-o", "LogLevel=ERROR",
            "-o", "ServerAliveInterval=5",
            "-o", "ServerAliveCountMax=3",
            "-i", str(self.key),
        ]

    @property
    def destination(self) -> str:
        return f"{self.user}@{self.host}"


@dataclass(frozen=True)
class Result:
    returncode: int
    stdout: str
    stderr: str

    @property
    def ok(self) -> bool:
        return self.returncode == 0

    def reason(self) -> str:
        """A one-line reason for a failure: the last line ssh or the command wrote."""
        for text in (self.stderr, self.stdout):
            lines = [ln.strip() for ln in text.strip().splitlines() if ln.strip()]
            if lines:
                return lines[-1]
        return f"exit status {self.returncode}"


def ssh_argv(target: SshTarget, command: str) -> list[str]:
    """The ``ssh`` command line that runs the shell ``command`` on ``target``."""
    return [SSH, *target.options(), "-p", str(target.port), target.destination, "--", command]


def scp_argv(target: SshTarget, files: Sequence[Path], remote_dir: str) -> list[str]:
    """The ``scp`` command line copying ``files`` into ``remote_dir`` (modes kept: ``-p``)."""
    remote = f"{target.destination}:{remote_dir.rstrip('/')}/"
    return [SCP, "-q", "-p", *target.options(), "-P", str(target.port), *map(str, files), remote]


async def run(argv: Sequence[str], timeout: float, data: bytes | None = None) -> Result:
    """Run ``argv`` (``data`` on its stdin, else none); a timeout kills it and returns exit
    status 124 with a reason."""
    logger.debug("run %s", shlex.join(argv))
    try:
        proc = await asyncio.create_subprocess_exec(
            *argv,
            stdin=asyncio.subprocess.DEVNULL if data is None else asyncio.subprocess.PIPE,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
        )
    except OSError as exc:
        return Result(127, "", f"cannot run {argv[0]}: {exc.strerror or exc}")
    try:
        out, err = await asyncio.wait_for(proc.communicate(data), timeout)
    except TimeoutError:
        proc.kill()
        await proc.wait()
        return Result(124, "", f"timed out after {timeout:g} s")
    except asyncio.CancelledError:
        proc.kill()
        await proc.wait()
        raise
    return Result(proc.returncode if proc.returncode is not None else -1,
                  out.decode("utf-8", "replace"), err.decode("utf-8", "replace"))


async def ssh_run(target: SshTarget, command: str, timeout: float = 120.0) -> Result:
    return await run(ssh_argv(target, command), timeout)


async def scp_files(target: SshTarget, files: Sequence[Path], remote_dir: str,
                    timeout: float = 300.0) -> Result:
    return await run(scp_argv(target, files, remote_dir), timeout)
