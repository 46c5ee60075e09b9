"""``formation run --hosts INVENTORY``: agents on other hosts of a deploy inventory, the world here.

The hosts are the deploy tests' real OpenSSH servers on 127.0.0.1 (two ports, as the current user;
:func:`test_deploy.sshd`), the agents installed once for the module by a real ``formation deploy``
into three install dirs. Runs then place some or all robots there: their agents start over SSH in
the deployed virtualenvs, as clients of the run's router on the inventory's ``zenoh.router``.
"""

from __future__ import annotations

import getpass
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
import zenoh
from test_deploy import SCENARIO, free_port, kill_agents, robot_env, source_snapshot, sshd

from deploy import deployer
from deploy.inventory import RobotHost
from deploy.remote import package_digest, parse_stats, remote_script
from formation.cli import main as formation_main
from simulator.fleet import ChildFailed, Fleet
from tests.same_files import assert_same
from wire import keys, zconf
from wire.payloads import decode_cmd

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

__all__ = ["source_snapshot", "sshd"]  # module fixtures shared with test_deploy

ROOT = Path(__file__).resolve().parent.parent
ROBOTS = ("r1", "r2", "r3")


@pytest.fixture(scope="module")
def hosts(tmp_path_factory: pytest.TempPathFactory, sshd: dict,
          source_snapshot: Path) -> Iterator[dict]:
    """Three robots deployed over the loopback sshd (r1, r2 behind one port, r3 the other), and
    a writer of run inventories naming any of them."""
    tmp = tmp_path_factory.mktemp("remote")
    scenario = tmp / "scenario.yaml"
    scenario.write_text(SCENARIO)
    dirs = {rid: tmp / "robots" / rid / "formation-cbf" for rid in ROBOTS}
    a, b = sshd["ports"]
    ports = {"r1": a, "r2": a, "r3": b}
    router = f"tcp/127.0.0.1:{free_port()}"

    def inventory(robots: tuple[str, ...], name: str, **changes: object) -> Path:
        data: dict = {
            "connect_timeout": 5,
            "zenoh": {"router": router, "mode": "client", "access_control": False},
            "defaults": {"user": getpass.getuser(), "key": str(sshd["key"]),
                         "python": sys.executable},
            "env": robot_env(),
            "robots": [{"id": rid, "host": "127.0.0.1", "port": ports[rid],
                        "install_dir": str(dirs[rid])} for rid in robots],
        }
        data.update(changes)
        path = tmp / f"{name}.yaml"
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        return path

    full = inventory(ROBOTS, "all")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(deployer, "project_root", lambda: source_snapshot)
        t0 = time.monotonic()
        assert formation_main(["deploy", str(full), str(scenario)]) == 0
        print(f"\ndeploy of 3 robots: {time.monotonic() - t0:.1f} s", file=sys.__stderr__)
    try:
        yield {"scenario": scenario, "dirs": dirs, "inventory": inventory, "full": full,
               "router": router, "tmp": tmp, "ports": ports}
    finally:
        kill_agents(list(dirs.values()))


def run_folders(dirs: dict[str, Path]) -> list[Path]:
    """What runs left in the robots' install dirs (``runs/RUN``)."""
    return [p for d in dirs.values() for p in (d / "runs").glob("*")]


def test_a_lockstep_run_with_agents_on_other_hosts_writes_the_same_robots_csv_as_the_simulation(
        hosts: dict, tmp_path: Path) -> None:
    inv = hosts["inventory"](("r1", "r3"), "mixed")  # r2 stays here: mixed placement
    assert formation_main(["sim", str(hosts["scenario"]), "--out", str(tmp_path / "sim"),
                           "--quiet", "--no-plots"]) == 0
    assert formation_main(["run", str(hosts["scenario"]), "--out", str(tmp_path / "run"),
                           "--quiet", "--no-plots", "--hosts", str(inv)]) == 0
    run = tmp_path / "run"
    s = json.loads((run / "summary.json").read_text())
    assert s["mode"] == "multiprocess" and s["secure"]  # secure by default, also across hosts
    procs = s["remote"]["processes"]
    assert sorted(procs) == ["agent-r1", "agent-r3"]
    assert procs["agent-r3"]["host"].endswith(f":{hosts['ports']['r3']}")
    assert s["remote"]["endpoint"] == hosts["router"]
    assert s["agents"]["stale"] == 0 and s["world"]["missing_cmds"] == 0
    for rid in ROBOTS:  # the remote agents' counters came back, r2's was written here
        stats = json.loads((run / "agents" / f"{rid}.json").read_text())
        assert stats["robot"] == rid and stats["ticks"] == s["steps"]
    logs = (run / "logs" / "agent-r1.log").read_text()
    assert "Traceback" not in logs
    assert run_folders(hosts["dirs"]) == []  # each host's run folder (credentials) is gone
    assert_same(tmp_path / "sim" / "robots.csv", run / "robots.csv")


class CmdWatcher:
    """Every robot's commands on the run's router, read with the run's viewer credentials."""

    def __init__(self, auth: Path) -> None:
        found = zconf.read_auth_file(auth)
        self.session = zenoh.open(zconf.ZenohSettings(mode="client", connect=found.connect,
                                                      auth=found.auth).to_config())
        self.cmds: dict[str, list] = {r: [] for r in ROBOTS}
        self._lock = threading.Lock()
        self.sub = self.session.declare_subscriber(f"{keys.DEFAULT_PREFIX}/robot/*/cmd", self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        rid = str(sample.key_expr).split("/")[-2]
        with self._lock:
            self.cmds.setdefault(rid, []).append(decode_cmd(sample.payload.to_bytes()))

    def moving(self) -> bool:
        with self._lock:
            return all(any(math.hypot(c.ux, c.uy) > 0.02 for c in self.cmds[r]) for r in ROBOTS)

    def last(self, rid: str):
        with self._lock:
            return self.cmds[rid][-1]

    def close(self) -> None:
        self.sub.undeclare()
        self.session.close()


def start_run(out: Path, *args: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.Popen([sys.executable, "-m", "formation", "run", *args, "--out", str(out),
                             "--quiet", "--no-plots", "--realtime"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)


def wait_up(proc: subprocess.Popen, out: Path, timeout: float = 60.0) -> None:
    """Until the run's agents are all up (it writes ``out/endpoint`` then)."""
    deadline = time.monotonic() + timeout
    while not (out / "endpoint").exists():
        if proc.poll() is not None:
            raise AssertionError(proc.communicate()[1].decode())
        assert time.monotonic() < deadline, "the run did not come up"
        time.sleep(0.1)


def pids_there(dirs: dict[str, Path]) -> dict[str, int]:
    """The remote agent processes' pids, by child name (``runs/RUN/NAME.pid``)."""
    return {p.stem: int(p.read_text()) for d in dirs.values() for p in d.glob("runs/*/*.pid")}


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_sigterm_stops_the_remote_agents_with_a_zero_command_and_brings_their_counters_back(
        hosts: dict, tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc = start_run(out, str(hosts["scenario"]), "--hosts", str(hosts["full"]),
                     "--agents-per-process", "2")
    watcher = None
    try:
        wait_up(proc, out)
        pids = pids_there(hosts["dirs"])
        assert sorted(pids) == ["remote-host-0", "remote-host-1"]  # r1+r2 on one sshd, r3
        (there,) = (hosts["dirs"]["r1"] / "runs").glob("*")  # r1's install dir holds r1 and r2
        assert there.stat().st_mode & 0o777 == 0o700
        assert sorted(f.name for f in there.glob("*.credentials")) == ["r1.credentials",
                                                                       "r2.credentials"]
        assert all(f.stat().st_mode & 0o777 == 0o600 for f in there.glob("*.credentials"))
        watcher = CmdWatcher(out / "secure" / "viewer.json5")
        deadline = time.monotonic() + 30
        while not watcher.moving():
            assert time.monotonic() < deadline, "the remote agents did not drive"
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        err = proc.communicate(timeout=60)[1].decode()
        time.sleep(0.3)  # the last commands cross the router
        for rid in ROBOTS:
            last = watcher.last(rid)
            assert (last.v, last.omega, last.ux, last.uy) == (0.0, 0.0, 0.0, 0.0), rid
    finally:
        if watcher is not None:
            watcher.close()
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 130, err
    s = json.loads((out / "summary.json").read_text())
    assert s["aborted"].startswith("interrupted") and "aborted_counters_lost" not in s
    for rid in ROBOTS:
        stats = json.loads((out / "agents" / f"{rid}.json").read_text())
        assert stats["robot"] == rid and stats["ticks"] > 0 and stats["host_agents"] >= 1
    assert not any(alive(pid) for pid in pids.values())
    assert run_folders(hosts["dirs"]) == []


def test_a_remote_agent_that_dies_aborts_the_run_naming_its_host(hosts: dict,
                                                                 tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc = start_run(out, str(hosts["scenario"]), "--hosts",
                     str(hosts["inventory"](("r3",), "r3-only")), "--insecure")
    try:
        wait_up(proc, out)
        (pid,) = pids_there(hosts["dirs"]).values()
        time.sleep(0.5)
        os.kill(pid, signal.SIGKILL)
        err = proc.communicate(timeout=60)[1].decode()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 1, err
    where = f"@127.0.0.1:{hosts['ports']['r3']}"
    assert "aborted: agent-r3 on " in err and where in err and "Traceback" not in err, err
    s = json.loads((out / "summary.json").read_text())
    assert s["aborted"].startswith("agent-r3 on ") and s["aborted_counters_lost"] == ["r3"]
    assert s["steps"] > 0
    assert run_folders(hosts["dirs"]) == []


def test_a_launcher_killed_outright_still_stops_its_remote_agents(hosts: dict,
                                                                  tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc = start_run(out, str(hosts["scenario"]), "--hosts",
                     str(hosts["inventory"](("r1", "r3"), "killed")), "--insecure")
    try:
        wait_up(proc, out)
        pids = pids_there(hosts["dirs"])
        assert sorted(pids) == ["agent-r1", "agent-r3"]
        os.kill(proc.pid, signal.SIGKILL)  # no clean-up here: ssh's stdin closes with it
        proc.communicate(timeout=30)
        deadline = time.monotonic() + 15
        while any(alive(pid) for pid in pids.values()):
            assert time.monotonic() < deadline, "a remote agent outlived its launcher"
            time.sleep(0.1)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    for d in hosts["dirs"].values():  # each stopped through its SIGTERM: counters written there
        for folder in (d / "runs").glob("*"):
            assert [p.name for p in folder.glob("*.json")], folder
            subprocess.run(["rm", "-rf", str(folder)], check=True)


def test_the_fleet_stops_a_command_child_by_closing_its_stdin_and_notices_its_exit(
        tmp_path: Path) -> None:
    with Fleet(tmp_path) as fleet:
        waiting = fleet.start_command("waits", ["sh", "-c", "read _; echo got-eof; exit 0"])
        fleet.stop([waiting], timeout=5.0)
        assert waiting.proc.returncode == 0  # it ended by itself on end-of-file, not killed
        assert (tmp_path / "waits.log").read_text().strip() == "got-eof"
        dies = fleet.start_command("dies", ["sh", "-c", "exit 7"], where="pi@10.0.0.9:22")
        dies.proc.wait(5)
        with pytest.raises(ChildFailed, match=r"^dies on pi@10\.0\.0\.9:22 exited with status 7"):
            fleet.check()


@pytest.mark.parametrize("case", ["unreachable", "no-key", "not-deployed", "not-in-scenario",
                                  "peer-mode", "port", "zones", "kill"])
def test_a_bad_inventory_or_host_exits_2_in_one_line_before_anything_starts(
        hosts: dict, tmp_path: Path, capsys: pytest.CaptureFixture, case: str) -> None:
    inventory = hosts["inventory"]
    extra: list[str] = []
    if case == "unreachable":
        inv = inventory(("r1",), case)
        data = yaml.safe_load(inv.read_text())
        data["robots"][0]["port"] = free_port()  # nothing listens there
        inv.write_text(yaml.safe_dump(data))
        expect = "robot r1 (" + getpass.getuser() + "@127.0.0.1:"
    elif case == "no-key":
        inv = inventory(("r1",), case, defaults={"user": getpass.getuser(), "key": "nokey"})
        expect = "robot 'r1': SSH key"
    elif case == "not-deployed":
        inv = inventory(("r1",), case)
        data = yaml.safe_load(inv.read_text())
        data["robots"][0]["install_dir"] = str(tmp_path / "empty")
        inv.write_text(yaml.safe_dump(data))
        expect = "no agent deployed in"
    elif case == "not-in-scenario":
        inv = inventory(("r1",), case)
        data = yaml.safe_load(inv.read_text())
        data["robots"][0]["id"] = "r9"
        inv.write_text(yaml.safe_dump(data))
        expect = "robot 'r9' is not in the scenario"
    elif case == "peer-mode":
        inv = inventory(("r1",), case, zenoh={"router": hosts["router"], "mode": "peer",
                                              "access_control": False})
        expect = "zenoh.mode: formation run --hosts needs client"
    elif case == "port":
        inv = inventory(("r1",), case)
        extra = ["--port", str(free_port())]
        expect = "--port: not with --hosts"
    elif case == "zones":
        inv = inventory(("r1",), case)
        extra = ["--pose-zones", "2"]
        expect = "--pose-zones: the zone routers listen on loopback only; not with --hosts"
    else:
        inv = inventory(("r1",), case)
        extra = ["--kill", "r1@2"]
        expect = "--kill: r1 runs on another host"
    out = tmp_path / "run"
    code = formation_main(["run", str(hosts["scenario"]), "--out", str(out), "--quiet",
                           "--hosts", str(inv), *extra])
    err = capsys.readouterr().err.strip()
    assert code == 2 and expect in err and "\n" not in err, err
    if case == "unreachable":
        assert "unreachable" in err
    assert not out.exists()  # nothing started, nothing written


def test_a_host_whose_installed_agent_differs_from_this_checkout_is_refused(
        hosts: dict, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    inv = hosts["inventory"](("r2",), "changed")
    venv = hosts["dirs"]["r2"] / "venv"
    (installed,) = venv.glob("lib/python*/site-packages/agent/config.py")
    text = installed.read_text()
    try:
        installed.write_text(text + "\n# changed on the robot\n")
        code = formation_main(["run", str(hosts["scenario"]), "--out", str(tmp_path / "run"),
                               "--quiet", "--hosts", str(inv)])
    finally:
        installed.write_text(text)
    err = capsys.readouterr().err.strip()
    assert code == 2 and "is not this checkout's" in err and package_digest() in err, err


def test_the_counters_reply_is_split_per_robot_and_broken_files_are_left_out() -> None:
    reply = ("==formation-stats== r1.json\n{\"robot\": \"r1\"}\n\n"
             "==formation-stats== r2.json\n{\"robot\": \n\n")
    assert parse_stats(reply) == {"r1": "{\"robot\": \"r1\"}"}


def test_a_dry_run_prints_where_each_agent_would_run_and_reaches_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    scen = tmp_path / "scenario.yaml"
    scen.write_text(SCENARIO)
    (tmp_path / "key").write_text("not a real key\n")
    inv = tmp_path / "inventory.yaml"
    inv.write_text(yaml.safe_dump({
        "zenoh": {"router": "tcp/192.0.2.10:7447"},  # TEST-NET: nothing is reached
        "defaults": {"user": "ubuntu", "key": "key"},
        "robots": [{"id": "r1", "host": "192.0.2.21"}, {"id": "r3", "host": "192.0.2.21",
                                                        "install_dir": "/opt/f"}],
    }))
    out = tmp_path / "run"
    code = formation_main(["run", str(scen), "--out", str(out), "--hosts", str(inv),
                           "--agents-per-process", "2", "--dry-run"])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "router listening on tcp/192.0.2.10:7447" in text
    assert "remote-host-0: robots r1, r3 on ubuntu@192.0.2.21:22 in ~/formation-cbf" in text
    assert "-m agent.host --agent runs/" in text and "r3.credentials --lockstep" in text
    assert "here: robots r2" in text and "dry run: 3 robots, 2 on other hosts" in text
    assert not out.exists() and not (tmp_path / "known_hosts").exists()


@pytest.mark.parametrize("shell", ["dash", "bash"])
def test_the_remote_script_stops_its_agent_on_end_of_file_and_ends_with_its_status(
        tmp_path: Path, shell: str) -> None:
    if shutil.which(shell) is None:
        pytest.skip(f"no {shell} here")
    (tmp_path / "venv" / "bin").mkdir(parents=True)
    (tmp_path / "runs" / "RUN").mkdir(parents=True)
    fake = tmp_path / "venv" / "bin" / "python"  # an "agent" that says how it was stopped
    fake.write_text("#!/bin/sh\ntrap 'echo zero-and-counters; exit 0' TERM\n"
                    "echo started \"$@\"\ntest \"$1\" = dies && exit 9\n"
                    "while :; do sleep 0.05; done\n")
    fake.chmod(0o755)
    robot = RobotHost(id="r1", host="h", user="u", key=tmp_path / "k", install_dir=str(tmp_path))
    for argv, code, said in ((["-m", "agent"], 0, "zero-and-counters"), (["dies"], 9, "")):
        script = remote_script(robot, "runs/RUN", argv, "agent-r1")
        proc = subprocess.Popen([shell, "-c", script], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 5
        while not (tmp_path / "runs" / "RUN" / "agent-r1.pid").exists():
            assert time.monotonic() < deadline
            time.sleep(0.02)
        if code == 0:
            time.sleep(0.2)
            assert proc.poll() is None  # runs until told
        else:
            proc.wait(5)  # ends by itself, its stdin still open
        out = proc.communicate(timeout=5)[0].decode()  # closes its stdin: end-of-file there
        assert proc.returncode == code and said in out, out
        (tmp_path / "runs" / "RUN" / "agent-r1.pid").unlink()
