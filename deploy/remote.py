"""Agents of a ``formation run`` on other hosts of a deploy inventory (``formation run --hosts``).

The world and the Zenoh router run on this machine; the robots the inventory names run their
agents on its hosts, in the virtualenv ``formation deploy`` installed in each ``install_dir``, as
clients of this run's router, which listens on the inventory's ``zenoh.router`` (an address of
this machine that the hosts reach). Robots of the scenario that the inventory does not name run
here, as in any run: one Zenoh system spread over machines.

Before anything starts (:meth:`RemotePlacement.check`, one SSH call per agent process, all at
once): the host is reached with deploy's SSH options (``BatchMode``, the project-local
``known_hosts``), ``install_dir`` holds the virtualenv, and the agent installed there is this
checkout's (:func:`package_digest` of the agent's packages, computed there and here). A failure is
:class:`RemoteError` naming the robot, in one line.

Start (:meth:`RemotePlacement.start`): each agent process's files go to ``install_dir/runs/RUN/``
(folder 0700): the configuration of each of its robots and, in a secure run, each robot's own
credentials (0600). Then one ``ssh`` per process runs :func:`remote_script` there: the agent
(``python -m agent``, or ``python -m agent.host`` for K robots with ``--agents-per-process K``)
and a watcher on ssh's stdin. This run closing that pipe (or dying, which closes it too) is
end-of-file there: the watcher sends the agent SIGTERM, the agent commands zero velocity and
writes its counters, and its exit ends the ssh with the agent's status, which the run's
:class:`simulator.fleet.Fleet` sees like any child's exit. :meth:`RemotePlacement.collect` then
copies the counters back into the run's ``agents/`` folder and removes ``runs/RUN`` there.
"""

from __future__ import annotations

import asyncio
import io
import json
import logging
import secrets
import shlex
import tarfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agent.config import AgentConfig, save_config

from .deployer import remote_dir_expr
from .digest import AGENT_PACKAGES, package_digest
from .inventory import Inventory, InventoryError, RobotHost, check_keys, load_inventory
from .ssh import Result, SshTarget, ssh_argv, ssh_run
from .ssh import run as run_argv

logger = logging.getLogger(__name__)

RUNS = "runs"  # in install_dir: one folder per run
PROBE_TIMEOUT_S = 30.0  # [s] on top of the SSH connect timeout
COPY_TIMEOUT_S = 120.0  # [s]
STATS_MARK = "==formation-stats== "  # separates the counters files in collect's reply
_DIGEST_CODE = "from deploy.digest import package_digest; print('digest=' + package_digest())"
_NOT_DEPLOYED = 3  # the probe's exit status for an install_dir without the virtualenv


class RemoteError(RuntimeError):
    """A host of the placement cannot run its agents; the message is one line naming the robot."""


@dataclass(frozen=True)
class AgentProcess:
    """One agent process on another host: its robots, run from ``lead``'s ``install_dir``."""

    name: str  # the run's child name (agent-ROBOT, or remote-host-I for several robots)
    lead: RobotHost  # whose install_dir, env and SSH target the process uses
    robots: tuple[str, ...]
    target: SshTarget


def group_processes(inventory: Inventory, robots: Sequence[str],
                    per_process: int) -> list[AgentProcess]:
    """The agent processes of ``robots`` (in this order): one per robot, or with ``per_process``
    K > 1 the robots of one SSH destination (host, port, user) K at a time, each group run from
    its first robot's ``install_dir``."""
    if per_process < 1:
        raise ValueError(f"per_process: need an integer >= 1, got {per_process!r}")
    by_id = {r.id: r for r in inventory.robots}
    out: list[AgentProcess] = []
    if per_process == 1:
        for rid in robots:
            r = by_id[rid]
            out.append(AgentProcess(f"agent-{rid}", r, (rid,), _target(inventory, r)))
        return out
    machines: dict[tuple[str, int, str], list[str]] = {}
    for rid in robots:
        r = by_id[rid]
        machines.setdefault((r.host.lower(), r.port, r.user), []).append(rid)
    for ids in machines.values():
        for i in range(0, len(ids), per_process):
            group = tuple(ids[i:i + per_process])
            lead = by_id[group[0]]
            out.append(AgentProcess(f"remote-host-{len(out)}", lead, group,
                                    _target(inventory, lead)))
    return out


def _target(inventory: Inventory, r: RobotHost) -> SshTarget:
    return SshTarget(host=r.host, port=r.port, user=r.user, key=r.key,
                     known_hosts=inventory.known_hosts, connect_timeout=inventory.connect_timeout)


def plan_placement(path: Path, scenario_robots: Sequence[str], per_process: int = 1,
                   run_id: str | None = None) -> RemotePlacement:
    """The placement of a run's agents by the inventory at ``path``: the robots it names on their
    hosts, the others here. :class:`InventoryError` (one line) for an invalid inventory, a robot
    the scenario lacks, a fleet that is not Zenoh client mode on a ``tcp/`` router, TLS, or an
    SSH key that is not a file."""
    inventory = load_inventory(path)
    wanted = list(scenario_robots)
    for r in inventory.robots:
        if r.id not in wanted:
            raise InventoryError(f"{inventory.path}: robot {r.id!r} is not in the scenario "
                                 f"(its robots: {', '.join(wanted)})")
    z = inventory.zenoh
    if z.mode != "client":
        raise InventoryError(f"{inventory.path}: zenoh.mode: formation run --hosts needs client "
                             f"(every agent a client of the run's router), got {z.mode!r}")
    if z.tls is not None or z.router is None or not z.router.startswith("tcp/"):
        raise InventoryError(f"{inventory.path}: zenoh.router: formation run --hosts listens on a "
                             f"tcp/ endpoint without TLS, got {z.router!r}"
                             + (" with zenoh.tls" if z.tls is not None else ""))
    check_keys(inventory)
    there = {r.id for r in inventory.robots}
    return RemotePlacement(inventory, [rid for rid in wanted if rid in there], per_process, run_id)


class RemotePlacement:
    """Agents of one run on the hosts of an inventory (see the module docstring); implements
    :class:`simulator.fleet.RemoteAgents`."""

    def __init__(self, inventory: Inventory, robots: Sequence[str], per_process: int = 1,
                 run_id: str | None = None) -> None:
        self.inventory = inventory
        self.endpoint: str = str(inventory.zenoh.router)
        self.robots = frozenset(robots)
        self.processes = group_processes(inventory, robots, per_process)
        self.run_id = run_id or secrets.token_hex(6)
        self.shipped: list[AgentProcess] = []  # processes whose runs/RUN exists there

    @property
    def run_dir(self) -> str:
        """The run's folder, relative to ``install_dir``."""
        return f"{RUNS}/{self.run_id}"

    # ------------------------------------------------------------------ before the run

    def check(self) -> None:
        """Every host reached, deployed, and running this checkout's agent; else
        :class:`RemoteError` naming the first robot (in inventory order) that is not."""
        here = package_digest()

        async def probe_all() -> list[Result]:
            self.inventory.known_hosts.parent.mkdir(parents=True, exist_ok=True)
            return list(await asyncio.gather(*(
                ssh_run(p.target, probe_command(p.lead), PROBE_TIMEOUT_S + p.target.connect_timeout)
                for p in self.processes)))

        for p, res in zip(self.processes, asyncio.run(probe_all()), strict=True):
            problem = probe_problem(p, res, here)
            if problem is not None:
                raise RemoteError(f"{self.inventory.path}: {problem}")

    # ------------------------------------------------------------------ the run

    def start(self, fleet: Any, configs: Mapping[str, AgentConfig], folder: Path,
              extra_argv: Callable[[str], Sequence[str]], per_process: int,
              shared_session: bool = False) -> dict[str, Any]:
        """Ship and start every agent process (``fleet``: the run's
        :class:`simulator.fleet.Fleet`); each robot maps to its process's child."""
        files: dict[str, list[Path]] = {}
        argvs: dict[str, list[str]] = {}
        for p in self.processes:
            files[p.name], argvs[p.name] = self._prepare(p, configs, folder, extra_argv,
                                                         shared_session)
        shipped = self._run_all([self._ship(p, files[p.name]) for p in self.processes])
        self.shipped = [p for p, res in zip(self.processes, shipped, strict=True) if res.ok]
        for p, res in zip(self.processes, shipped, strict=True):
            if not res.ok:
                raise RemoteError(f"robot {p.robots[0]} ({p.lead.address}): cannot copy the "
                                  f"run's files: {res.reason()}")
        agents: dict[str, Any] = {}
        for p in self.processes:
            script = remote_script(p.lead, self.run_dir, argvs[p.name], p.name)
            child = fleet.start_command(p.name, ssh_argv(p.target, script), where=p.lead.address)
            for rid in p.robots:
                agents[rid] = child
        return agents

    def _prepare(self, p: AgentProcess, configs: Mapping[str, AgentConfig], folder: Path,
                 extra_argv: Callable[[str], Sequence[str]],
                 shared_session: bool) -> tuple[list[Path], list[str]]:
        """The local files process ``p`` needs there, and its ``python`` arguments there."""
        files: list[Path] = []
        auths: dict[str, str | None] = {}
        common: list[str] | None = None
        for rid in p.robots:
            path = folder / "configs" / f"{rid}.yaml"
            save_config(configs[rid], path)
            files.append(path)
            rest, auth = _split_auth(list(extra_argv(rid)))
            if common is None:
                common = rest
            elif rest != common:
                raise ValueError(f"per_process: robot {rid} has options of its own: {rest}")
            auths[rid] = None if auth is None else Path(auth).name
            if auth is not None:  # OUT/secure/ROBOT.credentials (0600, kept so by tar)
                files.append(Path(auth))
        return files, agent_argv(p, self.run_dir, common or [], auths, shared_session)

    def describe(self, common: Sequence[str], secure: bool, shared_session: bool = False,
                 here: Sequence[str] = ()) -> list[str]:
        """The placement as text lines (``formation run --hosts ... --dry-run``): the router,
        each agent process with its robots, files and the SSH commands that would start it,
        the robots that stay here. Nothing is touched."""
        lines = [f"router and world here, the router listening on {self.endpoint} "
                 f"(the hosts connect there)"]
        for p in self.processes:
            auths = {rid: f"{rid}.credentials" if secure else None for rid in p.robots}
            argv = agent_argv(p, self.run_dir, common, auths, shared_session)
            files = [f"{rid}.yaml" for rid in p.robots] + [a for a in auths.values() if a]
            script = remote_script(p.lead, self.run_dir, argv, p.name)
            lines += [
                "",
                f"{p.name}: robots {', '.join(p.robots)} on {p.lead.address} in "
                f"{p.lead.install_dir}",
                f"  files   {' '.join(files)} -> {p.lead.install_dir}/{self.run_dir}/",
                f"  start   {shlex.join(ssh_argv(p.target, script))}",
            ]
        if here:
            lines += ["", f"here: robots {', '.join(here)}"]
        return lines

    async def _ship(self, p: AgentProcess, files: list[Path]) -> Result:
        """``install_dir/runs/RUN/`` there (0700) with ``files``, their modes kept: one SSH
        call, the files as a tar stream on its stdin."""
        d = remote_dir_expr(p.lead.install_dir)
        command = (f"cd {d} && mkdir -p {RUNS} && mkdir -m 700 -p {self.run_dir} && "
                   f"tar -x --no-same-owner -f - -C {self.run_dir}")
        return await run_argv(ssh_argv(p.target, command), COPY_TIMEOUT_S + p.target.connect_timeout,
                              tar_of(files))

    def collect(self, folder: Path) -> list[str]:
        """Counters of every started process's robots into ``FOLDER/agents/ROBOT.json``, and
        ``runs/RUN`` removed there; returns the robots whose counters did not come (logged).
        Called once the processes have stopped; a second call does nothing."""
        started, self.shipped = self.shipped, []
        if not started:
            return []
        replies = self._run_all([ssh_run(p.target, collect_command(p, self.run_dir),
                                         COPY_TIMEOUT_S + p.target.connect_timeout)
                                 for p in started])
        missing: list[str] = []
        for p, res in zip(started, replies, strict=True):
            got = parse_stats(res.stdout)
            for rid in p.robots:
                if rid not in got:
                    logger.warning("counters of %s did not come back from %s: %s", rid,
                                   p.lead.address, res.reason() if not res.ok else "not written")
                    missing.append(rid)
                    continue
                path = folder / "agents" / f"{rid}.json"
                tmp = path.with_name(path.name + ".tmp")
                tmp.write_text(got[rid], encoding="utf-8")
                tmp.replace(path)
        return missing

    def summary(self) -> dict:
        """``remote`` of summary.json: the inventory, the router's endpoint, each process."""
        return {
            "inventory": str(self.inventory.path),
            "endpoint": self.endpoint,
            "run_id": self.run_id,
            "processes": {p.name: {"host": p.lead.address, "install_dir": p.lead.install_dir,
                                   "robots": list(p.robots)} for p in self.processes},
        }

    @staticmethod
    def _run_all(coros: list) -> list[Result]:
        async def all_of() -> list[Result]:
            return list(await asyncio.gather(*coros))

        return asyncio.run(all_of())


def tar_of(files: Sequence[Path]) -> bytes:
    """``files`` as an uncompressed tar archive, each under its own name, its mode kept."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w", format=tarfile.PAX_FORMAT) as tar:
        for path in files:
            info = tar.gettarinfo(str(path), arcname=path.name)
            info.uid = info.gid = 0
            info.uname = info.gname = ""
            with path.open("rb") as f:
                tar.addfile(info, f)
    return buf.getvalue()


def _hosted(p: AgentProcess) -> bool:
    """Whether ``p`` is an agent host (named so by :func:`group_processes`)."""
    return p.name.startswith("remote-host-")


def agent_argv(p: AgentProcess, run_dir: str, common: Sequence[str],
               auths: Mapping[str, str | None], shared_session: bool = False) -> list[str]:
    """``python`` arguments of process ``p`` in ``install_dir``: ``-m agent`` for one robot,
    ``-m agent.host`` for several; ``auths`` names each robot's credentials file in ``run_dir``
    (None: none), ``common`` the options every robot shares (``--lockstep``, faults, ...)."""
    specs = []
    for rid in p.robots:
        parts = [f"{run_dir}/{rid}.yaml", f"{run_dir}/{rid}.json"]
        if auths.get(rid):
            parts.append(f"{run_dir}/{auths[rid]}")
        specs.append(parts)
    if not _hosted(p):
        cfg, stats, *auth = specs[0]
        argv = ["-m", "agent", "--config", cfg, "--stats", stats]
        argv += ["--zenoh-auth", auth[0]] if auth else []
    else:
        argv = ["-m", "agent.host"] + (["--shared-session"] if shared_session else [])
        for parts in specs:
            argv += ["--agent", ",".join(parts)]
    return argv + list(common)


def _split_auth(argv: list[str]) -> tuple[list[str], str | None]:
    """``argv`` without its ``--zenoh-auth FILE``, and FILE (None if absent)."""
    if "--zenoh-auth" not in argv:
        return argv, None
    i = argv.index("--zenoh-auth")
    return argv[:i] + argv[i + 2:], argv[i + 1]


def _env_prefix(r: RobotHost) -> str:
    q = shlex.quote
    return "".join(f"{k}={q(v)} " for k, v in r.env)


def probe_command(r: RobotHost) -> str:
    """Shell command: ``install_dir``'s absolute path and the installed agent's digest (exit
    status :data:`_NOT_DEPLOYED` when the virtualenv is missing)."""
    d = remote_dir_expr(r.install_dir)
    return (f"cd {d} 2>/dev/null && test -x venv/bin/python || exit {_NOT_DEPLOYED}; pwd; "
            f"{_env_prefix(r)}venv/bin/python -c {shlex.quote(_DIGEST_CODE)}")


def probe_problem(p: AgentProcess, res: Result, here: str) -> str | None:
    """What keeps ``p``'s host from running this checkout's agent (None: nothing)."""
    r = p.lead
    who = f"robot {r.id} ({r.address})"
    if res.returncode == 255:
        return f"{who}: unreachable: {res.reason()}"
    if res.returncode in (124, 127):  # ssh timed out, or no ssh on this machine
        return f"{who}: {res.reason()}"
    if res.returncode == _NOT_DEPLOYED:
        return (f"{who}: no agent deployed in {r.install_dir} (formation deploy INVENTORY "
                f"SCENARIO installs it)")
    digest = next((ln.split("=", 1)[1].strip() for ln in res.stdout.splitlines()
                   if ln.startswith("digest=")), None)
    if digest is None:
        return f"{who}: the agent in {r.install_dir} does not start: {res.reason()}"
    if digest != here:
        return (f"{who}: the agent installed in {r.install_dir} is not this checkout's (digest "
                f"{digest}, here {here}): formation deploy INVENTORY SCENARIO updates it")
    return None


def remote_script(r: RobotHost, run_dir: str, argv: Sequence[str], name: str) -> str:
    """Shell command run over SSH for one agent process (POSIX sh, the login shell's ``-c``).

    In ``install_dir``: the agent in the background (stdin ``/dev/null``), its pid in
    ``RUN/NAME.pid``, and a watcher reading ssh's stdin (kept as fd 3: a background job's own
    stdin is ``/dev/null``): end-of-file or a line there sends the agent SIGTERM. The agent's
    exit status is the script's, so the ssh on this machine ends with it."""
    d = remote_dir_expr(r.install_dir)
    agent = f"{_env_prefix(r)}venv/bin/python {shlex.join(argv)}"
    return (f"cd {d} || exit {_NOT_DEPLOYED}; exec 3<&0; "
            f"{agent} </dev/null 3<&- & a=$!; echo $a > {run_dir}/{name}.pid; "
            f"{{ read _ <&3; kill -TERM $a 2>/dev/null; }} & w=$!; "
            f"wait $a; s=$?; kill $w 2>/dev/null; exit $s")


def collect_command(p: AgentProcess, run_dir: str) -> str:
    """Shell command: each robot's counters after a :data:`STATS_MARK` line, then the run's
    folder removed."""
    d = remote_dir_expr(p.lead.install_dir)
    q = shlex.quote
    names = " ".join(q(f"{rid}.json") for rid in p.robots)
    return (f"cd {d}/{run_dir} || exit 0; for f in {names}; do test -f \"$f\" && "
            f"{{ echo {q(STATS_MARK.strip())} \"$f\"; cat \"$f\"; echo; }}; done; "
            f"cd {d} && rm -rf {run_dir}")


def parse_stats(text: str) -> dict[str, str]:
    """Robot -> its counters' JSON text, from :func:`collect_command`'s reply (a file that is
    not valid JSON is left out)."""
    out: dict[str, str] = {}
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if line.startswith(STATS_MARK) and i + 1 < len(lines):
            name = line[len(STATS_MARK):].strip()
            body = lines[i + 1]
            try:
                json.loads(body)
            except ValueError:
                continue
            out[name.removesuffix(".json")] = body
    return out


__all__ = ["AGENT_PACKAGES", "AgentProcess", "RemoteError", "RemotePlacement", "group_processes",
           "package_digest", "plan_placement", "probe_command", "remote_script"]
