"""formation deploy: inventory validation, generated files, and real deploys over a real sshd.

The end-to-end tests start OpenSSH's ``sshd`` on 127.0.0.1 (two ports, as the current user, with
a host key and a client key generated in a temporary folder) and deploy to three "robots": three
install dirs, two behind one sshd. The robots' python is this interpreter; their virtualenvs see
its site-packages (``--system-site-packages``; when the tests themselves run inside a virtualenv,
its site-packages reach the robots through the inventory's ``env: PYTHONPATH``).
"""

from __future__ import annotations

import argparse
import getpass
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import sysconfig
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
import zenoh
from system import require

from deploy import deployer
from deploy.inventory import InventoryError, check_against_scenario, load_inventory
from deploy.zenoh_config import bridge_config_dict, check_json5, zenoh_config_dict
from formation.cli import UsageError
from formation.cli import main as formation_main
from formation.commands.deploy import deploy_command
from scenario import load_scenario
from wire import zconf

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

ROOT = Path(__file__).resolve().parent.parent
SSHD = Path("/usr/sbin/sshd")
SCENARIO = """\
name: deploy-triangle
dt: 0.05
duration: 60.0
robot: {max_speed: 0.22, radius: 0.105}
controller: {kp: 2.0, gamma: 1.0, epsilon: 0.05}
formations:
  - name: T
    leader: r1
    robots:
      r1: {start: [0.0, 0.35], goal: [2.0, 0.35]}
      r2: {start: [-0.3031, -0.175], goal: [1.6969, -0.175]}
      r3: {start: [0.3031, -0.175], goal: [2.3031, -0.175]}
    edges: [[r1, r2], [r2, r3], [r1, r3]]
"""
STARTS = {"r1": (0.0, 0.35), "r2": (-0.3031, -0.175), "r3": (0.3031, -0.175)}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_port(port: int, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return
        except OSError:
            time.sleep(0.05)
    raise TimeoutError(f"nothing listens on 127.0.0.1:{port}")


def stop_process(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def sshd(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    """Two sshd on 127.0.0.1 accepting a generated key for the current user."""
    require(SSHD.exists(), "OpenSSH's server (sshd)", "openssh-server")
    require(bool(shutil.which("ssh") and shutil.which("scp")), "OpenSSH's client (ssh, scp)",
            "openssh-client")
    d = tmp_path_factory.mktemp("sshd")
    keygen = ["ssh-keygen", "-q", "-t", "ed25519", "-N", ""]
    subprocess.run([*keygen, "-f", str(d / "host_key")], check=True)
    subprocess.run([*keygen, "-f", str(d / "client_key")], check=True)
    (d / "authorized_keys").write_text((d / "client_key.pub").read_text())
    if os.geteuid() == 0:
        Path("/run/sshd").mkdir(mode=0o755, exist_ok=True)  # privilege separation dir
    procs: list[subprocess.Popen] = []
    ports = [free_port(), free_port()]
    try:
        for port in ports:
            cfg = d / f"sshd_{port}.conf"
            cfg.write_text(
                f"Port {port}\nListenAddress 127.0.0.1\nHostKey {d / 'host_key'}\n"
                f"PidFile {d / f'sshd_{port}.pid'}\nAuthorizedKeysFile {d / 'authorized_keys'}\n"
                "StrictModes no\nUsePAM no\nPasswordAuthentication no\n"
                "KbdInteractiveAuthentication no\nPubkeyAuthentication yes\n"
                "PermitRootLogin prohibit-password\nSubsystem sftp internal-sftp\n"
                "LogLevel ERROR\n"
            )
            with open(d / f"sshd_{port}.log", "wb") as log:
                procs.append(subprocess.Popen([str(SSHD), "-D", "-e", "-f", str(cfg)],
                                              stdout=subprocess.DEVNULL, stderr=log))
        for port in ports:
            try:
                wait_port(port)
            except TimeoutError:
                pytest.fail(f"sshd did not start: {(d / f'sshd_{port}.log').read_text()[-500:]}")
        yield {"ports": ports, "key": d / "client_key", "dir": d}
    finally:
        for proc in procs:
            stop_process(proc)


@pytest.fixture
def router() -> Iterator[str]:
    """A free loopback endpoint for the fleet's router (started by the test that needs it,
    with the configuration deploy writes: :func:`start_router`)."""
    yield f"tcp/127.0.0.1:{free_port()}"


def start_router(endpoint: str, config: Path) -> subprocess.Popen:
    """``python -m runtime.router`` with ``config`` (deploy's router.json5: users and ACL)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "runtime.router", "--listen", endpoint,
                             "--config", str(config), "--log-level", "WARNING"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_port(int(endpoint.rsplit(":", 1)[1]))
    except BaseException:
        stop_process(proc)
        raise
    return proc


def robot_env() -> dict[str, str]:
    """What the robots' venvs need to see this interpreter's packages (see the docstring)."""
    if sys.prefix != sys.base_prefix:
        return {"PYTHONPATH": sysconfig.get_paths()["purelib"]}
    return {}


def kill_agents(install_dirs: list[Path]) -> None:
    """Last resort: kill every supervisor process group a test left behind."""
    for d in install_dirs:
        pid_file = d / "run" / "agent.pid"
        try:
            pid = int(pid_file.read_text().strip())
        except (OSError, ValueError):
            continue
        for target in (-pid, pid):
            try:
                os.kill(target, signal.SIGKILL)
            except OSError:
                pass


@pytest.fixture(scope="module")
def source_snapshot(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the source tree, so files others edit meanwhile do not change the wheel."""
    from deploy import pyproject

    snap = tmp_path_factory.mktemp("src")
    shutil.copy2(ROOT / "pyproject.toml", snap / "pyproject.toml")
    packages = pyproject.strings((ROOT / "pyproject.toml").read_text(), "tool.setuptools", "packages")
    for pkg in (p for p in packages if "." not in p):  # a subpackage comes with its parent
        shutil.copytree(ROOT / pkg, snap / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    return snap


@pytest.fixture
def fleet(tmp_path: Path, sshd: dict, router: str, source_snapshot: Path,
          monkeypatch: pytest.MonkeyPatch) -> Iterator[dict]:
    """Files of a three-robot deploy: scenario, inventory, install dirs (agents killed at the end)."""
    monkeypatch.setattr(deployer, "project_root", lambda: source_snapshot)
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(SCENARIO)
    dirs = [tmp_path / "robots" / f"r{i}" / "formation-cbf" for i in (1, 2, 3)]
    a, b = sshd["ports"]
    inv = {
        "prefix": "warehouse",
        "base": "turtlebot3-humble",  # commands also go to {id}/cmd_vel, as to a real base
        "connect_timeout": 5,
        "zenoh": {"router": router, "mode": "client"},
        "defaults": {"user": getpass.getuser(), "key": str(sshd["key"]), "host": "127.0.0.1",
                     "python": sys.executable},
        "env": robot_env(),
        "robots": [
            {"id": "r1", "port": a, "install_dir": str(dirs[0])},
            {"id": "r2", "port": a, "install_dir": str(dirs[1])},
            {"id": "r3", "port": b, "install_dir": str(dirs[2])},
        ],
    }
    inv["defaults"].pop("host")
    for r in inv["robots"]:
        r["host"] = "127.0.0.1"
    inventory = tmp_path / "inventory.yaml"
    inventory.write_text(yaml.safe_dump(inv, sort_keys=False))
    try:
        yield {"inventory": inventory, "scenario": scenario, "dirs": dirs, "data": inv,
               "router": router, "tmp": tmp_path}
    finally:
        kill_agents(dirs)


TIMINGS: list[tuple[str, float]] = []  # (command, seconds), printed by the end-to-end test


def run_cli(capsys: pytest.CaptureFixture, *argv: str) -> tuple[int, str]:
    t0 = time.monotonic()
    code = formation_main(["deploy", *map(str, argv)])
    TIMINGS.append((" ".join(a for a in map(str, argv) if a.startswith("--")) or "deploy",
                    time.monotonic() - t0))
    out = capsys.readouterr()
    return code, out.out + out.err


def lines_of(text: str, robot: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.startswith(f"{robot} ")]


# ----------------------------------------------------------------------------- end to end


def check_installed(d: Path, rid: str, router: str) -> None:
    """Robot ``rid``'s directory ``d`` holds what deploy installs, its files private, its venv
    the one the agent imports from."""
    for name in ("robot.yaml", "zenoh.json5", "run-agent.sh", "formation-agent.service",
                 ".deploy-stamp"):
        assert (d / name).is_file(), name
    assert os.access(d / "run-agent.sh", os.X_OK)
    cfg = yaml.safe_load((d / "robot.yaml").read_text())
    assert cfg["robot_id"] == rid and cfg["zenoh"]["connect"] == [router]
    check_json5((d / "zenoh.json5").read_text())
    # each robot logs in as itself, its base's bridge too; the files are private
    for name in ("zenoh.json5", "zenoh-bridge.json5"):
        assert zconf.read_auth_file(d / name).auth.user == rid
        assert (d / name).stat().st_mode & 0o777 == 0o600
    assert list((d / "wheels").glob("formation_cbf-*.whl"))
    # the wheel is installed in the venv, which is the one the agent imports from
    py = d / "venv" / "bin" / "python"
    env = {"PATH": os.environ.get("PATH", ""), **robot_env()}
    where = subprocess.run(
        [str(py), "-c", "import agent.base, deploy; print(agent.base.__file__)"],
        capture_output=True, text=True, env=env, cwd="/", check=True).stdout.strip()
    assert where.startswith(str(d / "venv")), where
    assert (d / "venv" / "pyvenv.cfg").read_text().count("include-system-site-packages = true")


def check_secure(secure: Path) -> None:
    """The camera PC's credentials: one private file per user of the fleet."""
    assert secure.stat().st_mode & 0o777 == 0o700
    assert sorted(p.name for p in secure.iterdir()) == [
        "camera.json5", "manager.json5", "router.json5", "users.txt", "viewer.json5"]
    assert all(p.stat().st_mode & 0o777 == 0o600 for p in secure.iterdir())
    assert sorted(ln.split(":")[0] for ln in (secure / "users.txt").read_text().splitlines()) == [
        "camera", "manager", "r1", "r2", "r3", "viewer"]


def test_deploy_status_start_stop_and_redeploy_over_real_ssh(
        fleet: dict, capsys: pytest.CaptureFixture) -> None:
    inv, scen, dirs = fleet["inventory"], fleet["scenario"], fleet["dirs"]

    TIMINGS.clear()
    code, out = run_cli(capsys, inv, scen)
    assert code == 0, out
    for rid in ("r1", "r2", "r3"):
        (line,) = lines_of(out, rid)
        assert " installed " in line, out
    assert "deploy: 3 of 3 robots ok" in out

    for rid, d in zip(("r1", "r2", "r3"), dirs, strict=True):
        check_installed(d, rid, fleet["router"])
    secure = fleet["tmp"] / "secure"
    check_secure(secure)

    code, out = run_cli(capsys, inv, scen, "--status")
    assert code == 0, out
    for rid in ("r1", "r2", "r3"):
        assert " stopped " in lines_of(out, rid)[0], out

    # a second deploy changes nothing
    code, out = run_cli(capsys, inv, scen)
    assert code == 0, out
    for rid in ("r1", "r2", "r3"):
        assert " unchanged " in lines_of(out, rid)[0], out

    # start: every supervisor runs, the agents come up (each as its own Zenoh user, through the
    # router with the very files deploy wrote) and publish their state and base commands
    router = start_router(fleet["router"], secure / "router.json5")
    subscriber = StateWatcher(fleet["router"], ["r1", "r2", "r3"], secure / "camera.json5")
    bridge = BaseWatcher(dirs[0] / "zenoh-bridge.json5")  # r1's bridge, as installed
    intruder = BaseWatcher(dirs[1] / "zenoh.json5", "r1/cmd_vel")  # r2's user, on r1's base key
    try:
        code, out = run_cli(capsys, inv, scen, "--start")
        assert code == 0, out
        pids = {}
        for rid in ("r1", "r2", "r3"):
            line = lines_of(out, rid)[0]
            match = re.search(r" running +pid (\d+)", line)
            assert match, out
            pids[rid] = int(match.group(1))
        for pid in pids.values():
            os.kill(pid, 0)  # the supervisor process exists
        got = subscriber.wait_for_states(timeout=30.0)
        assert got == {"r1", "r2", "r3"}, (got, agent_logs(dirs))
        assert bridge.wait(timeout=10.0), agent_logs(dirs)  # a base command arrived on cmd_vel
        assert intruder.count == 0  # another robot's user cannot listen to r1's base
        code, out = run_cli(capsys, inv, scen, "--status")
        assert code == 0
        for rid in ("r1", "r2", "r3"):
            line = lines_of(out, rid)[0]
            assert re.search(rf" running +pid {pids[rid]} \| last log: ", line), out
        code, out = run_cli(capsys, inv, scen, "--start")  # starting twice keeps one agent
        assert code == 0 and all(f"pid {p} (already)" in out for p in pids.values()), out
    finally:
        subscriber.close()
        bridge.close()
        intruder.close()
        stop_process(router)

    code, out = run_cli(capsys, inv, scen, "--stop")
    assert code == 0, out
    for rid in ("r1", "r2", "r3"):
        assert " stopped " in lines_of(out, rid)[0], out
    for pid in pids.values():  # no supervisor, and no process of its group, is left
        with pytest.raises(ProcessLookupError):
            os.killpg(pid, 0)
    assert not any((d / "run" / "agent.pid").exists() for d in dirs)
    code, out = run_cli(capsys, inv, scen, "--status")
    assert code == 0 and len(re.findall(r" stopped +last log: ", out)) == 3, out

    # a changed scenario updates the generated files only, not the wheel
    scen.write_text(SCENARIO.replace("duration: 60.0", "duration: 61.0").replace(
        "epsilon: 0.05", "epsilon: 0.06"))
    code, out = run_cli(capsys, inv, scen)
    assert code == 0, out
    assert out.count(" updated ") == 3 and "files only" in out, out
    timings = ", ".join(f"{name} {sec:.1f} s" for name, sec in TIMINGS)
    print(f"\ndeploy timings: {timings}", file=sys.__stderr__)


def agent_logs(dirs: list[Path]) -> str:
    out = []
    for d in dirs:
        log = d / "logs" / "agent.log"
        if log.exists():
            out.append(f"--- {log}\n" + "\n".join(log.read_text().splitlines()[-15:]))
    return "\n".join(out)


class BaseWatcher:
    """A session opened from a robot's installed ``zenoh-bridge.json5`` (its user and the
    bridge's namespace), counting what arrives on ``key`` (``cmd_vel``: the namespaced base
    key, as zenoh-bridge-ros2dds would receive it)."""

    def __init__(self, config: Path, key: str = "cmd_vel") -> None:
        self.session = zenoh.open(zenoh.Config.from_file(str(config)))
        self.count = 0
        self.event = threading.Event()
        self.sub = self.session.declare_subscriber(key, self._on)

    def _on(self, _sample: zenoh.Sample) -> None:
        self.count += 1
        self.event.set()

    def wait(self, timeout: float) -> bool:
        return self.event.wait(timeout)

    def close(self) -> None:
        self.session.close()


class StateWatcher:
    """Publishes each robot's pose on the router and records which robots publish ``state``
    (logged in as the camera service, with deploy's ``camera.json5``)."""

    def __init__(self, router: str, robots: list[str], auth: Path) -> None:
        from wire import keys
        from wire.payloads import Pose, encode

        found = zconf.read_auth_file(auth)
        assert found.connect == (router,)
        self.session = zenoh.open(zconf.ZenohSettings(mode="client", connect=found.connect,
                                                      auth=found.auth).to_config())
        self.seen: set[str] = set()
        self.event = threading.Event()
        self.robots = robots
        self.subs = [self.session.declare_subscriber(keys.state_key("warehouse", r),
                                                     self._handler(r)) for r in robots]
        self.pubs = {r: self.session.declare_publisher(keys.pose_key("warehouse", r))
                     for r in robots}
        self._stop = threading.Event()
        self._encode, self._pose = encode, Pose
        self.thread = threading.Thread(target=self._publish_poses, daemon=True)
        self.thread.start()

    def _handler(self, robot: str):
        def on_sample(_sample: zenoh.Sample) -> None:
            self.seen.add(robot)
            if self.seen >= set(self.robots):
                self.event.set()
        return on_sample

    def _publish_poses(self) -> None:
        while not self._stop.wait(0.05):
            now = time.time()
            for r, pub in self.pubs.items():
                x, y = STARTS[r]
                pub.put(self._encode(self._pose(x, y, 0.0, now)))

    def wait_for_states(self, timeout: float) -> set[str]:
        self.event.wait(timeout)
        return set(self.seen)

    def close(self) -> None:
        self._stop.set()
        self.thread.join(5)
        for s in self.subs:
            s.undeclare()
        for p in self.pubs.values():
            p.undeclare()
        self.session.close()


def test_unreachable_robot_is_reported_and_the_others_are_served(
        fleet: dict, capsys: pytest.CaptureFixture) -> None:
    data = fleet["data"]
    data["robots"][2]["port"] = free_port()  # nothing listens there
    inv = fleet["tmp"] / "inventory-closed.yaml"
    inv.write_text(yaml.safe_dump(data, sort_keys=False))
    code, out = run_cli(capsys, inv, fleet["scenario"])
    assert code == 1, out
    assert " installed " in lines_of(out, "r1")[0] and " installed " in lines_of(out, "r2")[0]
    line = lines_of(out, "r3")[0]
    assert "FAILED" in line and "unreachable" in line and "refused" in line.lower(), out
    assert "deploy: 2 of 3 robots ok, 1 failed (r3)" in out
    code, out = run_cli(capsys, inv, fleet["scenario"], "--status")
    assert code == 1 and "FAILED" in lines_of(out, "r3")[0], out
    assert " stopped " in lines_of(out, "r1")[0]


def test_dry_run_prints_the_plan_and_touches_nothing(
        fleet: dict, capsys: pytest.CaptureFixture) -> None:
    code, out = run_cli(capsys, fleet["inventory"], fleet["scenario"], "--dry-run")
    assert code == 0, out
    for rid in ("r1", "r2", "r3"):
        assert f"robot {rid}: " in out
    for name in ("robot.yaml", "zenoh.json5", "run-agent.sh", "formation-agent.service"):
        assert out.count(f"file {name}") == 3
    assert "BatchMode=yes" in out and "StrictHostKeyChecking=accept-new" in out
    assert "venv --system-site-packages" in out and "dry run: 3 robots planned" in out
    assert not any(d.exists() for d in fleet["dirs"])
    assert not (fleet["tmp"] / "known_hosts").exists()


# ----------------------------------------------------------------------------- inventory

BASE_INV = {
    "base": "turtlebot3-humble",
    "zenoh": {"router": "tcp/192.168.0.10:7447", "mode": "client"},
    "defaults": {"user": "ubuntu", "key": "id_ed25519"},
    "robots": [
        {"id": "r1", "host": "192.168.0.21"},
        {"id": "r2", "host": "192.168.0.22"},
        {"id": "r3", "host": "192.168.0.23", "port": 2222, "user": "pi"},
    ],
}


def write_inv(tmp_path: Path, data: dict) -> Path:
    p = tmp_path / "inv.yaml"
    p.write_text(yaml.safe_dump(data, sort_keys=False))
    return p


def test_inventory_defaults_and_relative_paths(tmp_path: Path) -> None:
    inv = load_inventory(write_inv(tmp_path, BASE_INV))
    r1, _, r3 = inv.robots
    assert (r1.port, r1.user, r1.install_dir, r1.python) == (22, "ubuntu", "~/formation-cbf",
                                                             "python3")
    assert r1.key == tmp_path / "id_ed25519" and inv.known_hosts == tmp_path / "known_hosts"
    assert (r3.port, r3.user, r3.address) == (2222, "pi", "pi@192.168.0.23:2222")
    assert r1.cmd_vel == "r1/cmd_vel" and inv.prefix == "warehouse"


def mutate(path: str, value: object) -> dict:
    data = yaml.safe_load(yaml.safe_dump(BASE_INV))
    node = data
    parts = path.split(".")
    for p in parts[:-1]:
        node = node[int(p)] if p.isdigit() else node[p]
    last = parts[-1]
    if value is KeyError:
        del node[int(last) if last.isdigit() else last]
    elif last.isdigit():
        node[int(last)] = value
    else:
        node[last] = value
    return data


@pytest.mark.parametrize(("path", "value", "message"), [
    ("robots.0.hots", "x", "unknown key 'robots[0] (r1).hots'"),
    ("colour", "red", "unknown key 'colour'"),
    ("zenoh.modee", "peer", "unknown key 'zenoh.modee'"),
    ("robots.1.host", KeyError, "robots[1] (r2): missing key 'host'"),
    ("defaults.key", KeyError, "robots[0] (r1): missing key 'key'"),
    ("robots.1.port", 70000, "robots[1] (r2).port"),
    ("robots.1.install_dir", "formation", "robots[1] (r2).install_dir"),
    ("base", "turtlebot4", "base: 'turtlebot4'"),
    ("zenoh.mode", "router", "zenoh.mode"),
    ("zenoh.access_control", "yes", "zenoh.access_control: must be true or false"),
    ("zenoh.router", "192.168.0.10", "zenoh.router"),
    ("zenoh.router", KeyError, "zenoh.router: required in client mode"),
    ("robots.1.id", "r1", "duplicate robot id 'r1'"),
    ("robots", [], "robots: must be a non-empty list"),
])
def test_invalid_inventory_names_the_culprit(tmp_path: Path, path: str, value: object,
                                             message: str) -> None:
    with pytest.raises(InventoryError) as err:
        load_inventory(write_inv(tmp_path, mutate(path, value)))
    text = str(err.value)
    assert message in text and "\n" not in text


def test_two_robots_on_one_host_port_and_dir_are_rejected(tmp_path: Path) -> None:
    data = mutate("robots.1.host", "192.168.0.21")
    with pytest.raises(InventoryError, match="already robot 'r1'"):
        load_inventory(write_inv(tmp_path, data))
    data["robots"][1]["install_dir"] = "~/other"  # same host, another dir: fine
    load_inventory(write_inv(tmp_path, data))


def test_inventory_must_match_the_scenario_robots(tmp_path: Path) -> None:
    inv = load_inventory(write_inv(tmp_path, BASE_INV))
    check_against_scenario(inv, ["r1", "r2", "r3"])
    with pytest.raises(InventoryError, match="robot 'r3' is not in the scenario"):
        check_against_scenario(inv, ["r1", "r2"])
    with pytest.raises(InventoryError, match="scenario robot 'r4' is missing"):
        check_against_scenario(inv, ["r1", "r2", "r3", "r4"])


def test_cli_maps_a_bad_inventory_to_exit_2_with_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    scen = tmp_path / "s.yaml"
    scen.write_text(SCENARIO)
    inv = write_inv(tmp_path, mutate("robots.2.id", "r9"))
    code = formation_main(["deploy", str(inv), str(scen), "--dry-run"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "robot 'r9' is not in the scenario" in err and "\n" not in err
    ns = argparse.Namespace(inventory=str(inv), scenario=str(scen), dry_run=True, start=False,
                            stop=False, status=False)
    with pytest.raises(UsageError):
        deploy_command(ns)


# ----------------------------------------------------------------------------- zenoh files


def test_client_and_peer_zenoh_configs_are_accepted_by_zenoh(tmp_path: Path) -> None:
    inv = load_inventory(write_inv(tmp_path, BASE_INV))
    conf = zenoh_config_dict(inv, inv.robots[0])
    assert conf["mode"] == "client"
    assert conf["connect"]["endpoints"] == ["tcp/192.168.0.10:7447"]
    assert conf["scouting"]["multicast"]["enabled"] is False
    bridge = bridge_config_dict(inv, inv.robots[0])
    assert bridge["namespace"] == "r1" and bridge["connect"]["endpoints"] == ["tcp/192.168.0.10:7447"]

    peer = load_inventory(write_inv(tmp_path, mutate("zenoh.mode", "peer")))
    conf = zenoh_config_dict(peer, peer.robots[0])
    assert conf["mode"] == "peer" and conf["listen"]["endpoints"] == ["tcp/0.0.0.0:7447"]
    assert conf["connect"]["endpoints"] == ["tcp/192.168.0.10:7447", "tcp/192.168.0.22:7447",
                                            "tcp/192.168.0.23:7447"]
    scenario = tmp_path / "s.yaml"
    scenario.write_text(SCENARIO)
    plan = deployer.make_plan(peer, load_scenario(scenario), wheel="w.whl")
    for rp in plan.robots:  # every generated file was parsed by zenoh in make_plan; again here
        check_json5(rp.files["zenoh.json5"].decode())
        check_json5(rp.files["zenoh-bridge.json5"].decode())
        cfg = yaml.safe_load(rp.files["robot.yaml"])
        assert cfg["base"] == "turtlebot3-humble" and cfg["zenoh"]["mode"] == "peer"


def test_generated_zenoh_config_opens_a_session(tmp_path: Path) -> None:
    data = mutate("zenoh.router", "tcp/127.0.0.1:1")  # nothing there: the client gives up
    inv = load_inventory(write_inv(tmp_path, data))
    conf = zenoh_config_dict(inv, inv.robots[0])
    conf["connect"]["timeout_ms"] = 0
    conf["mode"] = "peer"  # a peer opens without its router
    import json
    with zenoh.open(zenoh.Config.from_json5(json.dumps(conf))) as session:
        assert str(session.zid())


def test_password_and_tls_are_recorded_into_the_zenoh_config(tmp_path: Path) -> None:
    (tmp_path / "pw").write_text("s3cret\n")
    for name in ("ca.pem", "robot.pem", "robot.key"):
        (tmp_path / name).write_text(f"-----{name}-----\n")
    data = mutate("zenoh.router", "tls/192.168.0.10:7447")
    data["zenoh"].update({"user": "fleet", "password_file": "pw",
                          "tls": {"root_ca": "ca.pem", "certificate": "robot.pem",
                                  "private_key": "robot.key"}})
    inv = load_inventory(write_inv(tmp_path, data))
    conf = zenoh_config_dict(inv, inv.robots[0])
    assert conf["transport"]["auth"]["usrpwd"] == {"user": "fleet", "password": "s3cret"}
    tls = conf["transport"]["link"]["tls"]
    assert tls["enable_mtls"] is True and tls["root_ca_certificate_base64"]
    import json
    check_json5(json.dumps(conf))
    with pytest.raises(InventoryError, match="must be a tls/ endpoint"):
        load_inventory(write_inv(tmp_path, {**data, "zenoh": {**data["zenoh"],
                                                              "router": "tcp/1.2.3.4:7447"}}))


def test_run_script_and_unit_refer_to_the_install_dir(tmp_path: Path) -> None:
    inv = load_inventory(write_inv(tmp_path, BASE_INV))
    scenario = tmp_path / "s.yaml"
    scenario.write_text(SCENARIO)
    plan = deployer.make_plan(inv, load_scenario(scenario), wheel="w.whl")
    rp = plan.robots[0]
    unit = rp.files["formation-agent.service"].decode()
    assert "ExecStart=%h/formation-cbf/run-agent.sh run" in unit
    script = rp.files["run-agent.sh"].decode()
    assert '-m agent --config "$DIR"/robot.yaml' in script
    assert rp.modes["run-agent.sh"] == 0o755
    assert deployer.remote_dir_expr("~/formation-cbf") == '"$HOME"/formation-cbf'
    assert deployer.remote_dir_expr("/opt/x y") == "'/opt/x y'"


def test_run_script_restarts_a_dying_agent_and_stops_cleanly(tmp_path: Path) -> None:
    """The supervisor alone, locally: a fake agent that dies at once is restarted."""
    from deploy import scripts

    d = tmp_path / "inst"
    (d / "venv" / "bin").mkdir(parents=True)
    fake = d / "venv" / "bin" / "python"
    fake.write_text("#!/bin/sh\necho fake agent \"$@\"\nexit 3\n")
    fake.chmod(0o755)
    run = d / "run-agent.sh"
    run.write_text(scripts.run_script("r1", ["--config", "./robot.yaml"], [("FOO", "a b")]))
    run.chmod(0o755)
    try:
        out = subprocess.run([str(run), "start"], capture_output=True, text=True, timeout=20)
        assert out.stdout.startswith("running pid"), out
        deadline = time.monotonic() + 10
        log = d / "logs" / "agent.log"
        while time.monotonic() < deadline and log.read_text().count("exited with status 3") < 2:
            time.sleep(0.1)
        text = log.read_text()
        assert "fake agent -m agent --config" in text and "restarting in 2 s" in text, text
        out = subprocess.run([str(run), "stop"], capture_output=True, text=True, timeout=20)
        assert out.stdout.startswith("stopped pid"), out
        out = subprocess.run([str(run), "status"], capture_output=True, text=True, timeout=20)
        assert out.stdout.startswith("stopped") and "last log:" in out.stdout
    finally:
        kill_agents([d])
