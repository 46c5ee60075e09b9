"""A disk that fills while a run writes its files (issue 28): ``summary.json`` goes first and
stays; a bulk file that does not fit is deleted and named in the summary's ``lost_files``; the
command's closing line says so and it exits 1. Failures are injected in-process (ENOSPC from one
writer) and, where this user may mount one, on a real tmpfs too small for the bulk files."""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from formation.cli import main
from scenario import load_scenario
from simulator import output
from simulator.inprocess import simulate

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "tests" / "scenarios" / "two-small.yaml"


@pytest.fixture(scope="module")
def run():
    s = load_scenario(SCENARIO)
    return s, simulate(s)


def _full(path: Path) -> OSError:
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


def _no_temporaries(out: Path) -> None:
    left = [p.name for p in out.iterdir() if p.name.startswith(".") and p.name != ".formation-output.json"]
    assert left == [], left


def test_a_bulk_file_that_does_not_fit_is_deleted_and_named_in_the_summary(run, tmp_path, monkeypatch):
    s, result = run
    write_csv = output.write_csv_rows

    def half_then_full(path, columns, rows):
        if path.name == "robots.csv":
            path.write_text("t,robot\n0.0,a")  # a cut file, as a full disk leaves it
            raise _full(path)
        write_csv(path, columns, rows)

    monkeypatch.setattr(output, "write_csv_rows", half_then_full)
    summary = dict(result.summary)
    lost = output.write_run(summary, result.series, s, tmp_path, plots=False)
    assert lost == [{"file": "robots.csv", "error": "disk full"}]
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    assert on_disk["lost_files"] == lost and on_disk["steps"] == result.summary["steps"]
    assert not (tmp_path / "robots.csv").exists()  # no cut file passes for the run's
    assert {p.name for p in tmp_path.iterdir()} == {"summary.json", "ellipses.csv", "obstacles.csv",
                                                   "run.mcap"}
    _no_temporaries(tmp_path)


def test_a_previous_runs_file_of_a_lost_name_does_not_survive(run, tmp_path, monkeypatch):
    s, result = run
    (tmp_path / "run.mcap").write_bytes(b"another run's recording")

    def full(summary, series, scenario, folder, board=None):
        (folder / "run.mcap").write_bytes(b"\x89MCAP0\r\n")
        raise _full(folder / "run.mcap")

    monkeypatch.setattr(output, "write_recording", full)
    lost = output.write_run(dict(result.summary), result.series, s, tmp_path, plots=False)
    assert lost == [{"file": "run.mcap", "error": "disk full"}]
    assert not (tmp_path / "run.mcap").exists()
    assert (tmp_path / "robots.csv").stat().st_size > 0
    _no_temporaries(tmp_path)


def test_no_room_for_the_summary_is_one_error_and_leaves_nothing(run, tmp_path, monkeypatch):
    s, result = run

    def full(path, data, rename=True):
        raise _full(path)

    monkeypatch.setattr(output, "write_json", full)
    with pytest.raises(output.OutputError, match="disk full: cannot write .* not saved"):
        output.write_run(dict(result.summary), result.series, s, tmp_path, plots=False)
    assert list(tmp_path.iterdir()) == []


def test_formation_sim_says_which_files_were_lost_and_exits_1(tmp_path, monkeypatch, capsys):
    def full(summary, series, scenario, folder, board=None):
        raise _full(folder / "run.mcap")

    monkeypatch.setattr(output, "write_recording", full)
    out = tmp_path / "sim"
    assert main(["sim", str(SCENARIO), "--out", str(out), "--quiet", "--no-plots"]) == 1
    closing = capsys.readouterr().out.strip().splitlines()[-1]
    assert closing == (f"wrote {out / 'summary.json'}; could not write run.mcap (disk full) "
                       f"(listed in its lost_files)")
    assert json.loads((out / "summary.json").read_text())["all_reached"] is True


# --- a real filesystem -------------------------------------------------------------------------

@pytest.fixture
def tiny_disk(tmp_path) -> Iterator[Path]:
    """A 200 kB tmpfs (needs root and mount permission; skipped otherwise)."""
    where = tmp_path / "tiny"
    where.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=200k", "tmpfs", str(where)],
                          capture_output=True, text=True)
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=False)


def test_a_disk_that_fills_part_way_keeps_the_summary_and_names_what_it_lost(tiny_disk):
    out = tiny_disk / "sim"
    proc = subprocess.run(
        [sys.executable, "-m", "formation", "sim", str(SCENARIO), "--out", str(out), "--quiet"],
        env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    lost = {e["file"]: e["error"] for e in summary["lost_files"]}
    assert lost and set(lost.values()) == {"disk full"}, lost
    assert "run.mcap" in lost  # 200 kB hold the summary and the CSVs, not the recording
    present = {p.name for p in out.iterdir()}
    assert not present & set(lost), present  # nothing cut is left beside the summary
    assert "could not write " + ", ".join(f"{f} (disk full)" for f in lost) in proc.stdout
    _no_temporaries(out)


def test_a_summary_that_does_not_fit_leaves_no_temporary_file(tiny_disk):
    filler = tiny_disk / "filler"
    with filler.open("wb", buffering=0) as fh, pytest.raises(OSError):
        while True:
            fh.write(b"\0" * 4096)
    with pytest.raises(OSError) as caught:
        output.write_json(tiny_disk / "summary.json", {"pad": "x" * 100_000})
    assert caught.value.errno == errno.ENOSPC
    assert sorted(p.name for p in tiny_disk.iterdir()) == ["filler"]


@pytest.fixture
def small_disk(tmp_path) -> Iterator[Path]:
    """A 9 MB tmpfs: room for `formation run`'s check before the run (8 MB), none to spare."""
    where = tmp_path / "small"
    where.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=9m", "tmpfs", str(where)],
                          capture_output=True, text=True)
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=False)


def _fill(disk: Path, leave_kb: int) -> None:
    """Fill ``disk`` until ``leave_kb`` kB are free."""
    free_kb = os.statvfs(disk).f_bavail * os.statvfs(disk).f_frsize // 1024
    with (disk / "filler").open("wb") as fh:
        fh.write(b"\0" * max(0, free_kb - leave_kb) * 1024)


def _wait_sim_time(endpoint: str, manager: Path, t: float) -> None:
    """Until a leader's status is stamped ``t`` [s] of simulated time or later (lock-step)."""
    import zenoh

    from formation.commands.goal import query_status
    from wire.zconf import ZenohSettings, read_auth_file

    conf = ZenohSettings(mode="client", connect=(endpoint,),
                         auth=read_auth_file(manager).auth).to_config()
    with zenoh.open(conf) as session:
        deadline = time.monotonic() + 300.0
        while time.monotonic() < deadline:
            if any(s.stamp >= t for s in query_status(session, "warehouse", timeout=1.0)):
                return
            time.sleep(0.5)
    raise AssertionError(f"the run did not reach {t} s")


def test_a_disk_that_fills_during_a_run_keeps_its_summary(small_disk, tmp_path):
    """`formation run --hold`: 30 s into the run, the disk is filled to 64 kB; Ctrl-C. The
    agents cannot write their counters nor the launcher robots.csv, but the summary fits: it is
    written with what the world measured and names every file it lost (before: "disk full ...
    run output not saved", nothing kept)."""
    import signal

    from tests.test_hold import SCENARIO, wait_endpoint

    out = small_disk / "run"
    log = tmp_path / "fleet.log"  # off the full disk: the launcher's own output must get out
    with log.open("wb") as fh:
        proc = subprocess.Popen(
            [sys.executable, "-m", "formation", "run", str(SCENARIO), "--out", str(out), "--hold",
             "--quiet", "--no-plots", "--duration", "600"],
            env=dict(os.environ, PYTHONPATH=str(ROOT)), stdin=subprocess.DEVNULL, stdout=fh,
            stderr=subprocess.STDOUT)
    try:
        _wait_sim_time(wait_endpoint(proc, out), out / "secure" / "manager.json5", 30.0)
        _fill(small_disk, 64)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(120) == 1, log.read_text(errors="replace")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    text = log.read_text(errors="replace")
    summary = json.loads((out / "summary.json").read_text())
    lost = {e["file"]: e["error"] for e in summary["lost_files"]}
    assert lost.get("robots.csv") == "disk full", lost
    assert {f for f in lost if f.startswith("agents/")}, lost  # a trace is tens of kB
    assert summary["steps"] > 0 and summary["collisions"] == 0
    assert "could not write " in text and "(listed in its lost_files)" in text, text
    assert not any((out / f).exists() for f in lost), lost  # none left cut
    _no_temporaries(out)


def test_a_full_disk_deep_inside_a_command_is_named_with_the_file_it_hit():
    from formation.cli import failure_words

    assert failure_words(OSError(errno.ENOSPC, "No space left on device"), "runs/x") == \
        "disk full: cannot write runs/x"
    assert failure_words(_full(Path("runs/x/endpoint")), "runs/x") == \
        "disk full: cannot write runs/x/endpoint"
    assert failure_words(ValueError("bad"), "runs/x") == "ValueError: bad"
