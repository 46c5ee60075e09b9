"""`formation montecarlo --scheduler`: the sweep on a real Dask distributed cluster (a scheduler
and two workers, each its own process on loopback) writes what a local run writes, and a
scheduler that is not there is one line and exit 2."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from formation.cli import main
from runtime.ports import free_tcp_port, wait_for_tcp_port

distributed = pytest.importorskip("distributed", reason="the optional extra formation-cbf[cluster]")

ROOT = Path(__file__).resolve().parent.parent


def dask(args: list[str], workdir: Path, log: Path) -> subprocess.Popen:
    """A ``dask`` command (scheduler or worker) as its own process, importing this checkout."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with log.open("w") as fh:
        return subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_" + args[0], *args[1:]],
                                cwd=workdir, env=env, stdout=fh, stderr=subprocess.STDOUT)


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[str]:
    port = free_tcp_port()
    address = f"tcp://127.0.0.1:{port}"
    procs = [dask(["scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                  tmp_path, tmp_path / "scheduler.log")]
    try:
        wait_for_tcp_port(port, timeout_s=60.0)
        for k in range(2):
            procs.append(dask(["worker", address, "--nthreads", "1", "--no-nanny",
                               "--no-dashboard", "--local-directory", str(tmp_path / f"w{k}")],
                              tmp_path, tmp_path / f"worker{k}.log"))
        with distributed.Client(address, timeout=60, set_as_default=False) as client:
            client.wait_for_workers(2, timeout=120)
        yield address
    finally:
        for p in reversed(procs):  # the workers first, each closing while the scheduler answers
            p.terminate()
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=30)


def test_a_sweep_on_two_dask_workers_writes_what_a_local_run_writes(cluster, tmp_path, capsys):
    argv = ["montecarlo", "--n", "4", "--seed", "5"]
    assert main([*argv, "--scheduler", cluster, "--out", str(tmp_path / "dask")]) == 0
    said = capsys.readouterr().out
    assert f"on the Dask cluster at {cluster} (2 workers, 2 threads)" in said
    assert main([*argv, "--jobs", "1", "--out", str(tmp_path / "local")]) == 0
    for name in ("montecarlo.json", "runs.jsonl"):
        assert (tmp_path / "dask" / name).read_bytes() == (tmp_path / "local" / name).read_bytes()
    with distributed.Client(cluster, timeout=60, set_as_default=False) as client:
        # a lambda travels by value: the workers need not import this test module
        counts = client.run(lambda dask_worker: dask_worker.state.executed_count)
    assert sorted(counts.values())[0] >= 1  # both workers ran some of the runs
    assert sum(counts.values()) == 4


def test_a_scheduler_that_is_not_there_is_one_line_and_exit_2(tmp_path, capsys):
    address = f"tcp://127.0.0.1:{free_tcp_port()}"
    out = tmp_path / "mc"
    assert main(["montecarlo", "--n", "2", "--scheduler", address, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and address in err[0] and "Traceback" not in err[0]
    assert not out.exists()  # nothing written before the cluster answered
