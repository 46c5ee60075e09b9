"""Put the agent on every robot of an inventory over SSH, and start, stop and query it.

The plan (:func:`make_plan`) is pure: per robot, the files to copy and the commands to run. The
work (:func:`deploy`, :func:`control`) serves all robots concurrently; one robot that cannot be
reached or fails is reported and does not stop the others.

On each robot, ``install_dir`` holds::

    robot.yaml                 the robot's agent configuration (agent.config)
    zenoh.json5                its Zenoh session (deploy.zenoh_config; mode 0600)
    zenoh-bridge.json5         TurtleBot bases: for zenoh-bridge-ros2dds -c
    run-agent.sh               start | stop | status | run (deploy.scripts)
    formation-agent.service    a systemd user unit
    wheels/formation_cbf-*.whl the project, built once on this machine
    venv/                      python3 -m venv --system-site-packages; the wheel installed --no-deps
                               (--without-pip when the system python has pip: it is used instead)
    .deploy-stamp              digests of the installed wheel and of the files above
    logs/agent.log, run/agent.pid

The virtualenv sees the robot's system site-packages, so numpy, PyYAML, eclipse-zenoh (and on a
ROS machine whatever else) preinstalled there are used as they are, and installing the wheel with
``--no-deps --no-index`` takes seconds and needs no network on the robot. Redeploying compares
the digests in ``.deploy-stamp``: nothing changed -> ``unchanged`` (nothing copied); only the
generated files -> they are copied, the wheel is not reinstalled.
"""

from __future__ import annotations

import asyncio
import dataclasses
import hashlib
import importlib.metadata
import importlib.util
import logging
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from agent.config import AgentConfig, build_agent_configs, save_config
from scenario import Scenario

from . import pyproject, rmw_zenoh, scripts
from .inventory import Inventory, InventoryError, RobotHost
from .secure import fleet_secrets, robot_auth
from .ssh import Result, SshTarget, scp_argv, scp_files, ssh_argv, ssh_run
from .zenoh_config import agent_zenoh_settings, bridge_json5, has_secrets, zenoh_json5

logger = logging.getLogger(__name__)
T = TypeVar("T")

STAMP_FILE = ".deploy-stamp"
CONFIG_FILE = "robot.yaml"
ZENOH_FILE = "zenoh.json5"
BRIDGE_FILE = "zenoh-bridge.json5"
PROBE_TIMEOUT_S = 30.0  # on top of the SSH connect timeout [s]
INSTALL_TIMEOUT_S = 600.0  # venv creation and pip install on a Raspberry Pi [s]
COPY_TIMEOUT_S = 300.0  # [s]
CONTROL_TIMEOUT_S = 30.0  # start / stop / status [s]
SOURCE_DATE_EPOCH = "315532800"  # 1980-01-01: reproducible zip timestamps in the wheel
_SKIP = shutil.ignore_patterns("__pycache__", "*.pyc", "*.pyo", "*.egg-info", "build", "dist")


class BuildError(RuntimeError):
    """The wheel could not be built on this machine."""


# --------------------------------------------------------------------------------- the plan


@dataclass(frozen=True)
class RobotPlan:
    robot: RobotHost
    target: SshTarget
    files: dict[str, bytes]  # name in install_dir -> content
    modes: dict[str, int]  # name -> file mode
    files_digest: str

    @property
    def remote_dir(self) -> str:
        """``install_dir`` as a shell word on the robot (``~`` -> ``"$HOME"``)."""
        return remote_dir_expr(self.robot.install_dir)


@dataclass(frozen=True)
class Plan:
    inventory: Inventory
    robots: tuple[RobotPlan, ...]
    wheel_name: str


def remote_dir_expr(install_dir: str) -> str:
    d = install_dir.rstrip("/") or "/"
    if d == "~":
        return '"$HOME"'
    if d.startswith("~/"):
        return '"$HOME"/' + shlex.quote(d[2:])
    return shlex.quote(d)


def project_root() -> Path:
    """The source tree this package runs from (where ``pyproject.toml`` is)."""
    root = Path(__file__).resolve().parent.parent
    if not (root / "pyproject.toml").is_file():
        raise BuildError(f"no pyproject.toml in {root}: deploy runs from a source checkout only")
    return root


def wheel_name(root: Path | None = None) -> str:
    """The file name ``pip wheel`` gives the project (pure Python, any platform)."""
    text = _pyproject_text(root or project_root())
    name = re.sub(r"[-_.]+", "_", _field(pyproject.string, text, "project", "name"))
    return f"{name}-{_field(pyproject.string, text, 'project', 'version')}-py3-none-any.whl"


def _pyproject_text(root: Path) -> str:
    return (root / "pyproject.toml").read_text("utf-8")


def _field(read: Callable[[str, str, str], T], text: str, table: str, key: str) -> T:
    """``read(text, table, key)`` (deploy.pyproject), its error a :class:`BuildError`."""
    try:
        return read(text, table, key)
    except pyproject.PyprojectError as exc:
        raise BuildError(f"pyproject.toml: {exc}") from None


def agent_args(inv: Inventory) -> list[str]:
    """Arguments of ``python -m agent`` on a robot (paths relative to the install dir).

    ``--no-trace``: a deployed agent runs for hours, and its per-tick trace (about 400 bytes a
    tick, kept in memory for the launcher's time series) would only grow."""
    args = ["--config", f"./{CONFIG_FILE}", "--log-level", "INFO", "--no-trace"]
    if has_secrets(inv):
        args += ["--zenoh-config", f"./{ZENOH_FILE}"]
    return args


def _agent_takes_zenoh_config() -> bool:
    try:
        text = (project_root() / "agent" / "__main__.py").read_text("utf-8")
    except (OSError, BuildError):
        return False
    return "--zenoh-config" in text or "add_zenoh_args" in text


def agent_configs(inv: Inventory, scenario: Scenario) -> dict[str, AgentConfig]:
    """Each robot's :class:`AgentConfig`: its Zenoh endpoints, the fleet's prefix and base."""
    try:
        base = build_agent_configs(scenario, prefix=inv.prefix, topology=inv.topology,
                                   safety=True, base=inv.base)
    except ValueError as exc:
        raise InventoryError(str(exc)) from None
    names = {f.name for f in dataclasses.fields(AgentConfig)}
    out = {}
    for r in inv.robots:
        changes: dict[str, Any] = {"zenoh": agent_zenoh_settings(inv, r)}
        if "cmd_vel_key" in names:
            changes["cmd_vel_key"] = r.cmd_vel
        if "frame_id" in names:
            changes["frame_id"] = r.frame_id
        if r.rmw is not None:
            changes["rmw"] = r.rmw  # an rmw_zenoh publisher itself, no bridge
        out[r.id] = dataclasses.replace(base[r.id], **changes)
    return out


def make_plan(inv: Inventory, scenario: Scenario, wheel: str | None = None, *,
              write_secrets: bool = True) -> Plan:
    """Every robot's files and SSH target; ``InventoryError`` if a file cannot be generated.

    With ``zenoh.access_control`` every robot gets its own Zenoh user (:mod:`deploy.secure`);
    the credentials folder is written unless ``write_secrets`` is False (a dry run)."""
    if has_secrets(inv) and not _agent_takes_zenoh_config():
        raise InventoryError(
            "zenoh.user/zenoh.tls: this version's agent takes no --zenoh-config, so "
            "authentication and TLS settings could not reach it")
    secrets = (fleet_secrets(inv, scenario, write=write_secrets) if inv.zenoh.access_control
               else None)
    configs = agent_configs(inv, scenario)
    robots = []
    with tempfile.TemporaryDirectory(prefix="formation-deploy-") as tmp:
        for r in inv.robots:
            path = Path(tmp) / f"{r.id}.yaml"
            save_config(configs[r.id], path)
            files = {CONFIG_FILE: path.read_bytes()}
            try:
                auth = robot_auth(secrets, r.id)
                files[ZENOH_FILE] = zenoh_json5(inv, r, auth).encode()
                files.update(rmw_zenoh.base_files(inv, r, auth, BRIDGE_FILE, bridge_json5))
            except ValueError as exc:
                raise InventoryError(f"robot {r.id}: {exc}") from None
            files[scripts.RUN_SCRIPT] = scripts.run_script(r.id, agent_args(inv), r.env).encode()
            files[scripts.UNIT_FILE] = scripts.systemd_unit(r.id, r.install_dir).encode()
            modes = {name: 0o644 for name in files}
            modes[scripts.RUN_SCRIPT] = 0o755
            if has_secrets(inv):
                modes[ZENOH_FILE] = modes[BRIDGE_FILE] = 0o600
                modes.update({n: 0o600 for n in rmw_zenoh.SECRET_FILES if n in files})
            target = SshTarget(host=r.host, port=r.port, user=r.user, key=r.key,
                               known_hosts=inv.known_hosts, connect_timeout=inv.connect_timeout)
            robots.append(RobotPlan(r, target, files, modes, files_digest(files, modes)))
    return Plan(inv, tuple(robots), wheel or wheel_name())


def files_digest(files: dict[str, bytes], modes: dict[str, int]) -> str:
    h = hashlib.sha256()
    for name in sorted(files):
        h.update(f"{name}\0{modes.get(name, 0o644):o}\0{len(files[name])}\0".encode())
        h.update(files[name])
    return h.hexdigest()[:16]


def wheel_digest(path: Path) -> str:
    """Digest of a wheel's contents (names and bytes), independent of zip timestamps."""
    h = hashlib.sha256()
    with zipfile.ZipFile(path) as z:
        for info in sorted(z.infolist(), key=lambda i: i.filename):
            h.update(info.filename.encode() + b"\0")
            h.update(z.read(info))
    return h.hexdigest()[:16]


def build_wheel(out_dir: Path, root: Path | None = None) -> Path:
    """Build the project wheel into ``out_dir`` once (``pip wheel --no-deps``).

    The sources are copied to a scratch folder first, so the checkout gets no ``build/``. The
    build uses this interpreter's setuptools (``--no-build-isolation``) when it can, and falls
    back to an isolated build (which fetches the build requirements) when that fails.
    """
    root = root or project_root()
    packages = _field(pyproject.strings, _pyproject_text(root), "tool.setuptools", "packages")
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="formation-wheel-") as tmp:
        src = Path(tmp) / "src"
        src.mkdir()
        for name in ("pyproject.toml", "README.md", "LICENSE", "setup.cfg", "setup.py"):
            if (root / name).is_file():
                shutil.copy2(root / name, src / name)
        for pkg in packages:
            top = pkg.split(".")[0]
            if (root / top).is_dir() and not (src / top).exists():
                shutil.copytree(root / top, src / top, ignore=_SKIP)
        env = {**os.environ, "SOURCE_DATE_EPOCH": SOURCE_DATE_EPOCH, "PIP_NO_INPUT": "1"}
        base = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet",
                "--disable-pip-version-check", "-w", str(out_dir), str(src)]
        attempts = [base[:4] + ["--no-build-isolation"] + base[4:], base]
        if not _can_build_without_isolation():
            attempts = attempts[1:]
        proc = None
        for argv in attempts:
            proc = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=600,
                                  check=False)
            if proc.returncode == 0:
                break
            logger.info("wheel build failed (%s), %s", shlex.join(argv[3:6]),
                        "retrying with build isolation" if argv is not base else "giving up")
        if proc is None or proc.returncode != 0:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] if proc else []
            raise BuildError(f"pip wheel failed: {' '.join(tail) or 'no output'}")
    path = out_dir / wheel_name(root)
    if not path.is_file():
        raise BuildError(f"pip wheel did not write {path.name}")
    return path


def _can_build_without_isolation() -> bool:
    """Whether this interpreter's setuptools can write wheels (>= 70.1, or with ``wheel``)."""
    try:
        major, minor = (int(x) for x in importlib.metadata.version("setuptools").split(".")[:2])
    except Exception:  # noqa: BLE001 - not installed or an odd version string
        return False
    return (major, minor) >= (70, 1) or importlib.util.find_spec("wheel") is not None


# --------------------------------------------------------------------------------- reports


@dataclass(frozen=True)
class RobotReport:
    robot_id: str
    address: str
    ok: bool
    status: str  # installed | updated | unchanged | running | stopped | failed | ...
    detail: str = ""
    seconds: float = 0.0


@dataclass(frozen=True)
class Outcome:
    reports: tuple[RobotReport, ...]
    notes: tuple[str, ...] = field(default=())

    @property
    def failed(self) -> int:
        return sum(not r.ok for r in self.reports)


def _failed(rp: RobotPlan, stage: str, result: Result, t0: float) -> RobotReport:
    reason = result.reason()
    if result.returncode == 255 and stage == "connect":
        reason = f"unreachable: {reason}"
    return RobotReport(rp.robot.id, rp.robot.address, False, "failed", f"{stage}: {reason}",
                       time.monotonic() - t0)


# --------------------------------------------------------------------------------- deploy


def probe_command(rp: RobotPlan) -> str:
    d = rp.remote_dir
    return (f"mkdir -p {d} && cd {d} && pwd && "
            f"(cat {STAMP_FILE} 2>/dev/null || true) && "
            f"(test -x venv/bin/python && echo venv=yes || echo venv=no) && "
            f"(test -x {scripts.RUN_SCRIPT} && echo running=$(./{scripts.RUN_SCRIPT} pid) || true)")


def install_command(rp: RobotPlan, abs_dir: str, wheel: str, wheel_hash: str,
                    install: bool) -> str:
    q = shlex.quote
    env = " ".join(f"{k}={q(v)}" for k, v in rp.robot.env)
    steps = [f"cd {q(abs_dir)}", "mkdir -p wheels logs run"]
    if install:
        steps += [
            f"mv -f {q(wheel)} wheels/",
            f"find wheels -name '*.whl' ! -name {q(wheel)} -delete",
            _make_venv(q(rp.robot.python)),
            "venv/bin/python -m pip install --quiet --no-deps --no-index --force-reinstall "
            f"--disable-pip-version-check wheels/{q(wheel)}",
            f"{{ {env + ' ' if env else ''}venv/bin/python -c 'import agent.node, agent.base' "
            "|| { echo 'the agent cannot import its dependencies with this python (see above): "
            "install numpy and pyyaml (apt), eclipse-zenoh (into the venv) on the robot' >&2; exit 3; }; }",
        ]
    steps.append(f"printf 'wheel=%s\\nfiles=%s\\n' {wheel_hash} {rp.files_digest} > {STAMP_FILE}")
    return " && ".join(steps)


def _make_venv(python: str) -> str:
    """Create ``venv`` unless it exists: without its own pip when the system python has one
    (the venv's python then runs the system pip, seen through --system-site-packages: 0.2 s
    instead of the 5 to 20 s that bootstrapping pip into every venv takes)."""
    return (f"{{ test -x venv/bin/python || {{ {python} -m venv --system-site-packages "
            f"--without-pip venv && {{ venv/bin/python -c 'import pip' 2>/dev/null || "
            f"{{ rm -rf venv && {python} -m venv --system-site-packages venv; }}; }}; }}; }}")


def _parse_probe(text: str) -> tuple[str, dict[str, str]]:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    if not lines or not lines[0].startswith("/"):
        raise ValueError("unexpected reply to the probe")
    info = dict(ln.split("=", 1) for ln in lines[1:] if "=" in ln)
    return lines[0], info


def _stage_files(rp: RobotPlan, local: Path) -> list[Path]:
    """Write the robot's files (with their modes) under ``local``; their paths."""
    local.mkdir(parents=True, exist_ok=True)
    to_copy = []
    for name, content in rp.files.items():
        p = local / name
        p.write_bytes(content)
        p.chmod(rp.modes[name])
        to_copy.append(p)
    return to_copy


def _what_changed(info: dict[str, str], wheel_hash: str, files_digest: str) -> str:
    """What an install put on the robot, from the probe's answer ``info``."""
    if info.get("venv") != "yes":
        return "new virtualenv, wheel and files"
    if info.get("wheel") != wheel_hash:
        return f"wheel {info.get('wheel', 'none')} -> {wheel_hash} and files"
    return f"files only ({info.get('files', 'none')} -> {files_digest})"


async def deploy_robot(rp: RobotPlan, wheel: Path, wheel_hash: str, staging: Path) -> RobotReport:
    t0 = time.monotonic()
    r = rp.robot
    probe = await ssh_run(rp.target, probe_command(rp), PROBE_TIMEOUT_S + rp.target.connect_timeout)
    if not probe.ok:
        return _failed(rp, "connect", probe, t0)
    try:
        abs_dir, info = _parse_probe(probe.stdout)
    except ValueError as exc:
        return RobotReport(r.id, r.address, False, "failed", f"connect: {exc}", time.monotonic() - t0)
    need_install = info.get("wheel") != wheel_hash or info.get("venv") != "yes"
    need_files = info.get("files") != rp.files_digest
    running = info.get("running", "")
    if not need_install and not need_files:
        return RobotReport(r.id, r.address, True, "unchanged", f"in {abs_dir}",
                           time.monotonic() - t0)
    to_copy = _stage_files(rp, staging / r.id)
    if need_install:
        to_copy.append(wheel)
    copied = await scp_files(rp.target, to_copy, abs_dir, COPY_TIMEOUT_S)
    if not copied.ok:
        return _failed(rp, "copy", copied, t0)
    done = await ssh_run(rp.target, install_command(rp, abs_dir, wheel.name, wheel_hash,
                                                    need_install), INSTALL_TIMEOUT_S)
    if not done.ok:
        return _failed(rp, "install", done, t0)
    status = "installed" if info.get("venv") != "yes" else "updated"
    detail = f"{_what_changed(info, wheel_hash, rp.files_digest)} in {abs_dir}"
    if running:
        detail += f"; agent running (pid {running}): --stop and --start to use the new version"
    return RobotReport(r.id, r.address, True, status, detail, time.monotonic() - t0)


async def _deploy_all(plan: Plan, wheel: Path) -> Outcome:
    digest = wheel_digest(wheel)
    plan.inventory.known_hosts.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="formation-deploy-") as tmp:
        reports = await asyncio.gather(
            *(deploy_robot(rp, wheel, digest, Path(tmp)) for rp in plan.robots))
    return Outcome(tuple(reports), (f"wheel {wheel.name} (digest {digest})",))


def deploy(plan: Plan) -> Outcome:
    """Build the wheel once, then install it and the files on every robot concurrently."""
    with tempfile.TemporaryDirectory(prefix="formation-wheel-out-") as out:
        wheel = build_wheel(Path(out))
        return asyncio.run(_deploy_all(plan, wheel))


# --------------------------------------------------------------------------------- control

ACTIONS = ("start", "stop", "status")


async def control_robot(rp: RobotPlan, action: str) -> RobotReport:
    t0 = time.monotonic()
    d = rp.remote_dir
    command = (f"cd {d} 2>/dev/null && test -x {scripts.RUN_SCRIPT} "
               f"|| {{ echo 'not deployed in {rp.robot.install_dir}' >&2; exit 3; }}; "
               f"./{scripts.RUN_SCRIPT} {action}")
    res = await ssh_run(rp.target, command, CONTROL_TIMEOUT_S + rp.target.connect_timeout)
    if not res.ok:
        return _failed(rp, "connect" if res.returncode == 255 else action, res, t0)
    lines = [ln.strip() for ln in res.stdout.splitlines() if ln.strip()]
    state, _, rest = (lines[0] if lines else "unknown").partition(" ")
    detail = " | ".join([x for x in (rest, *lines[1:2]) if x])
    return RobotReport(rp.robot.id, rp.robot.address, True, state, detail, time.monotonic() - t0)


def control(plan: Plan, action: str) -> Outcome:
    """``start``, ``stop`` or ``status`` of the agent on every robot, concurrently."""
    if action not in ACTIONS:
        raise ValueError(f"action: {action!r} is not one of {ACTIONS}")

    async def all_robots() -> tuple[RobotReport, ...]:
        plan.inventory.known_hosts.parent.mkdir(parents=True, exist_ok=True)
        return tuple(await asyncio.gather(*(control_robot(rp, action) for rp in plan.robots)))

    return Outcome(asyncio.run(all_robots()))


# --------------------------------------------------------------------------------- dry run


def describe(plan: Plan) -> list[str]:
    """The plan as text lines: per robot its files and the commands deploy would run."""
    lines = [f"build once: {sys.executable} -m pip wheel --no-deps --no-build-isolation "
             f"-w TMP {project_root()}  -> {plan.wheel_name}"]
    for rp in plan.robots:
        r = rp.robot
        lines.append("")
        lines.append(f"robot {r.id}: {r.address} install_dir {r.install_dir}")
        for name, content in rp.files.items():
            lines.append(f"  file {name:26s} {len(content):6d} bytes  mode {rp.modes[name]:o}")
        lines.append(f"  file wheels/{plan.wheel_name}")
        probe = ssh_argv(rp.target, probe_command(rp))
        copy = scp_argv(rp.target, [Path(n) for n in rp.files] + [Path(plan.wheel_name)],
                        "INSTALL_DIR")
        install = ssh_argv(rp.target, install_command(rp, "INSTALL_DIR", plan.wheel_name,
                                                      "WHEEL_DIGEST", True))
        for label, argv in (("probe", probe), ("copy", copy), ("install", install)):
            lines.append(f"  {label:8s}{shlex.join(argv)}")
        lines.append(f"  start   ssh ... ./{scripts.RUN_SCRIPT} start   "
                     f"(stop, status likewise)")
    return lines


def summary_line(outcome: Outcome, what: str) -> str:
    n = len(outcome.reports)
    ok = n - outcome.failed
    text = f"{what}: {ok} of {n} robots ok"
    if outcome.failed:
        names = ", ".join(r.robot_id for r in outcome.reports if not r.ok)
        text += f", {outcome.failed} failed ({names})"
    return text


def format_report(r: RobotReport) -> str:
    status = r.status if r.ok else "FAILED"
    return f"{r.robot_id:10s} {r.address:28s} {status:10s} {r.detail}  [{r.seconds:.1f} s]"


def plan_robot_ids(plan: Plan) -> Sequence[str]:
    return [rp.robot.id for rp in plan.robots]
