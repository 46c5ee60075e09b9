"""Goals sent over real Zenoh to a running ``formation run --hold`` fleet (router, one agent per
robot, the simulated world: separate processes on loopback)."""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from formation.commands import goal as navcmd
from wire.zconf import ZenohSettings, read_auth_file

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "tests" / "scenarios" / "nav-hold.yaml"
GOALS = {"A": (2.25, 0.25, None), "B": (2.25, -0.6, math.pi / 2)}


def start_fleet(out: Path, *extra: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out.mkdir(parents=True)
    with open(out.parent / "fleet.log", "wb") as log:  # the child keeps its own descriptor
        return subprocess.Popen(
            [sys.executable, "-m", "formation", "run", str(SCENARIO), "--out", str(out), "--hold",
             "--quiet", "--no-plots", *extra],
            env=env, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT)


def wait_endpoint(proc: subprocess.Popen, out: Path, timeout: float = 90.0) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if (out / "endpoint").is_file():
            return (out / "endpoint").read_text().strip()
        assert proc.poll() is None, (out.parent / "fleet.log").read_text(errors="replace")
        time.sleep(0.2)
    raise TimeoutError("the fleet did not come up")


def wait_reached(endpoint: str, timeout: float, auth_file: Path) -> dict:
    conf = ZenohSettings(mode="client", connect=(endpoint,),
                         auth=read_auth_file(auth_file).auth).to_config()
    with zenoh.open(conf) as session:
        deadline = time.monotonic() + timeout
        last = {}
        while time.monotonic() < deadline:
            last = {s.formation: s for s in navcmd.query_status(session, "warehouse", timeout=1.0)}
            if all(f in last and last[f].state == "reached" and (last[f].gx, last[f].gy) == g[:2]
                   for f, g in GOALS.items()):
                return last
            time.sleep(0.5)
    raise AssertionError(f"not every formation reached its goal: {last}")


@pytest.mark.parametrize("mode", [["--realtime"], []], ids=["realtime", "lockstep"])
def test_goals_sent_to_a_running_fleet_are_reached_around_the_shelf(tmp_path, mode, capsys):
    out = tmp_path / "run"
    proc = start_fleet(out, *mode, "--duration", "600")
    try:
        endpoint = wait_endpoint(proc, out)
        # access control is on by default: goals come from the fleet manager's credentials
        manager = out / "secure" / "manager.json5"
        if mode:  # once: anyone else's goal (here the read-only viewer's) is refused
            viewer = ["goal", "A", "0.5", "0.5", "--connect", endpoint, "--timeout", "4",
                      "--auth", str(out / "secure" / "viewer.json5")]
            assert navcmd.main(viewer) != 0
            capsys.readouterr()
            # no credentials at all: one line naming --auth, not zenoh's own error
            assert navcmd.main(["goal", "A", "0.5", "0.5", "--connect", endpoint]) == 1
            err = capsys.readouterr().err
            assert "--auth" in err and len(err.strip().splitlines()) == 1 and ".rs:" not in err, err
            # --run finds the endpoint and the credentials; an unknown formation: exit 2 at once
            assert navcmd.main(["goal", "NOPE", "1", "1", "--run", str(out)]) == 2
            assert "known: A, B" in capsys.readouterr().err
        for fid, (x, y, heading) in GOALS.items():
            where = (["--run", str(out)] if fid == "A" and mode else
                     ["--connect", endpoint, "--auth", str(manager)])
            argv = ["goal", fid, str(x), str(y), "--timeout", "30", *where]
            if heading is not None:
                argv += ["--heading", repr(heading)]
            assert navcmd.main(argv) == 0
        # the leader planned around the shelf: the status navcmd printed on acceptance shows the
        # route (the route at the end may be a later replan from near the goal: one waypoint)
        said = re.search(r"^A: moving goal .* waypoint 1/(\d+) ", capsys.readouterr().out, re.M)
        assert said and int(said.group(1)) > 1, said
        status = wait_reached(endpoint, timeout=90.0, auth_file=manager)
        assert status["B"].heading == pytest.approx(math.pi / 2)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(60) == 0, (tmp_path / "fleet.log").read_text(errors="replace")
        log = (tmp_path / "fleet.log").read_text(errors="replace")
        # the printed hint carries the credentials it needs
        assert f"--connect {endpoint} --auth {manager}" in log, log
        # one ending: the held run stopped, never "NOT all goals reached at t=<first arrival>"
        assert "held until t=" in log and "goals reached at t=" not in log, log
        # judged at the goals the formations were sent, which they reached (not the scenario's)
        assert "every robot at its last goal" in log and "UNSAFE OR INCOMPLETE" not in log, log
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["hold"] is True and summary["collisions"] == 0
    assert min(summary["min_clearance_shape_m"].values()) >= -0.005
    assert summary["formation_error_max_m"] <= 1.5 * 0.05
    assert summary["formations_status"]["A"]["state"] == "reached"
    assert summary["formations_status"]["B"]["goal"] == [2.25, -0.6]
    assert summary["all_reached"] is True and summary["time_to_goal_s"] is not None
    assert summary["goals_sent"]["A"] == {"goal": [2.25, 0.25], "heading": None}
    assert summary["goals_sent"]["B"]["heading"] == pytest.approx(math.pi / 2)
    assert all(t is not None for t in summary["time_to_goal_by_formation_s"].values())
    assert summary["comm"]["classes"]["goal"]["recv"]["messages"] >= 2
    assert summary["comm"]["classes"]["plan"]["recv"]["messages"] >= 2
