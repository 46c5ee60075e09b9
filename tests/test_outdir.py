"""A run owns its ``--out`` (issue 12): a re-run replaces the previous run's output and leaves
no stale file, a folder holding anything else is refused unless ``--force``, two runs at once
into one folder are refused, and a bad ``--out`` is exit 2 before anything runs, for every
command that writes a folder."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from formation import cli
from formation.cli import main
from formation.outdir import LOCK, MARKER, OutputFolder

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = str(ROOT / "tests" / "scenarios" / "two-small.yaml")
OTHER = str(ROOT / "tests" / "scenarios" / "rotating-triangle.yaml")
NOWHERE = "tcp/127.0.0.1:9"  # no router: a command that got this far would try to connect


def _sim(out: Path, *extra: str, scenario: str = SCENARIO) -> int:
    return main(["sim", scenario, "--out", str(out), "--quiet", "--no-plots", *extra])


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    return err


@pytest.mark.integration
def test_a_rerun_replaces_the_previous_runs_output_and_no_stale_file_survives(tmp_path):
    out = tmp_path / "o"
    assert _sim(out) == 0
    # what the first run wrote that the second will not (a run's logs, another kind's files)
    (out / "agents").mkdir()
    (out / "agents" / "a1.json").write_text("{}")
    (out / "trajectories.png").write_bytes(b"old")
    marker = json.loads((out / MARKER).read_text())
    marker["entries"] += ["agents", "trajectories.png"]
    (out / MARKER).write_text(json.dumps(marker))
    assert _sim(out, scenario=OTHER) == 0
    names = {p.name for p in out.iterdir()}
    assert names == {"summary.json", "robots.csv", "ellipses.csv", "obstacles.csv", "run.mcap",
                     MARKER}  # no lock left, nothing stale
    assert json.loads((out / "summary.json").read_text())["scenario"] == "rotating-triangle"
    assert sorted(json.loads((out / MARKER).read_text())["entries"]) == sorted(names - {MARKER})


def test_a_folder_from_before_the_marker_holding_only_known_output_is_replaced(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    for name in ("summary.json", "safety.png", "processes.json"):
        (out / name).write_text("old")
    (out / "logs").mkdir()
    assert _sim(out) == 0
    assert not (out / "safety.png").exists() and not (out / "logs").exists()
    assert json.loads((out / "summary.json").read_text())["scenario"] == "two-small"


def test_a_folder_holding_other_files_is_refused_unless_force_which_keeps_them(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("precious")
    assert _sim(out) == 2
    line = _one_line(capsys)
    assert "notes.txt" in line and "--force" in line
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]  # nothing written, no lock
    assert _sim(out, "--force") == 0
    assert (out / "notes.txt").read_text() == "precious"
    assert (out / "summary.json").exists()
    # the output is the run's; the note is still not: a re-run without --force is refused again,
    # one with --force replaces the output and keeps the note
    assert json.loads((out / MARKER).read_text())["foreign"] == ["notes.txt"]
    assert _sim(out) == 2
    capsys.readouterr()
    assert _sim(out, "--force", scenario=OTHER) == 0
    assert (out / "notes.txt").read_text() == "precious"


def test_an_invalid_scenario_loses_nothing_of_the_previous_output(tmp_path):
    out = tmp_path / "o"
    assert _sim(out) == 0
    before = (out / "robots.csv").read_bytes()
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\n")
    assert _sim(out, scenario=str(bad)) == 2
    assert (out / "robots.csv").read_bytes() == before
    assert not (out / LOCK).exists()


def test_a_new_folder_is_not_left_behind_when_the_input_is_invalid(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\n")
    assert _sim(tmp_path / "new", scenario=str(bad)) == 2
    assert not (tmp_path / "new").exists()


@pytest.mark.integration
def test_two_runs_into_one_folder_at_once_are_refused_and_a_stale_lock_is_taken_over(
        tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (out / LOCK).write_text(f"{holder.pid} {os.uname().nodename}\n")
        assert _sim(out) == 2
        line = _one_line(capsys)
        assert "in use by another formation run" in line and str(holder.pid) in line
        assert not (out / "summary.json").exists()
        assert (out / LOCK).read_text().startswith(str(holder.pid))  # not ours to remove
    finally:
        holder.kill()
        holder.wait()
    # its process is gone: the lock is stale and the next run takes it over
    assert _sim(out) == 0
    assert (out / "summary.json").exists() and not (out / LOCK).exists()


@pytest.mark.integration
def test_a_second_formation_process_is_refused_while_the_first_runs(tmp_path):
    out = tmp_path / "o"
    first = subprocess.Popen([sys.executable, "-m", "formation", "run", SCENARIO, "--out", str(out),
                              "--quiet", "--no-plots"], cwd=ROOT, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 30
        while not (out / LOCK).exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        second = subprocess.run([sys.executable, "-m", "formation", "sim", SCENARIO, "--out",
                                 str(out), "--quiet", "--no-plots"], cwd=ROOT, capture_output=True,
                                text=True, timeout=60)
        assert second.returncode == 2
        assert "in use by another formation run" in second.stderr
        assert str(first.pid) in second.stderr
    finally:
        first.terminate()
        first.wait(timeout=30)


def test_a_lock_that_cannot_be_read_is_stale(tmp_path):
    (tmp_path / LOCK).write_text("garbage")
    with OutputFolder(tmp_path) as folder:
        assert folder.begin() == tmp_path
        assert (tmp_path / LOCK).read_text().split()[0] == str(os.getpid())
    assert not (tmp_path / LOCK).exists()


@pytest.mark.parametrize("argv", [
    ["sim", SCENARIO], ["run", SCENARIO], ["commcost", "--formations", "2"],
    ["montecarlo", "--n", "1"], ["bench", "--quick"], ["record", "--connect", NOWHERE],
])
def test_an_out_naming_a_file_is_exit_2_in_one_line_before_anything_runs(tmp_path, capsys, argv,
                                                                         monkeypatch):
    taken = tmp_path / "taken"
    taken.write_text("x")
    ran: list[str] = []
    monkeypatch.setitem(cli.COMMANDS, argv[0], lambda ns: ran.append(ns.command) or 0)
    assert main([*argv, "--out", str(taken)]) == 2
    assert ran == []  # refused at once: the command's work never started
    line = _one_line(capsys)
    assert "--out" in line and "not a folder" in line
    assert taken.read_text() == "x" and sorted(p.name for p in tmp_path.iterdir()) == ["taken"]


def test_an_unwritable_out_is_exit_2_for_every_command(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        try:
            (locked / "probe").mkdir()
            (locked / "probe").rmdir()
            out = Path("/proc/formation-out-check")  # root writes anyway: try /proc
        except OSError:
            out = locked / "sub"
        for argv in (["sim", SCENARIO], ["run", SCENARIO], ["commcost"], ["montecarlo"],
                     ["bench", "--quick"], ["record", "--connect", NOWHERE]):
            assert main([*argv, "--out", str(out)]) == 2
            assert "--out" in _one_line(capsys)
    finally:
        locked.chmod(0o700)


@pytest.mark.integration
def test_a_recording_owns_its_out_like_a_run(tmp_path, capsys):
    from runtime.testing import RouterProcess

    out = tmp_path / "o"
    assert _sim(out) == 0  # a run's output, then a recording into the same folder replaces it
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("precious")
    with RouterProcess() as router:
        def record(folder: Path, *extra: str) -> int:
            return main(["record", "--connect", router.endpoint, "--out", str(folder),
                         "--duration", "0.3", *extra])

        assert record(out) == 0
        assert {p.name for p in out.iterdir()} == {"run.mcap", MARKER}  # no stale file, no lock
        assert json.loads((out / MARKER).read_text())["entries"] == ["run.mcap"]
        capsys.readouterr()
        # a folder holding anything else is refused before connecting, unless --force
        assert record(mine) == 2
        line = _one_line(capsys)
        assert "notes.txt" in line and "--force" in line
        assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
        assert record(mine, "--force") == 0
        assert {p.name for p in mine.iterdir()} == {"notes.txt", "run.mcap", MARKER}
        assert (mine / "notes.txt").read_text() == "precious"
