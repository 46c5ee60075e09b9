"""Where a sweep's runs execute: this machine's processes, or a Dask distributed cluster.

``formation montecarlo --jobs J`` maps its runs over J local processes; ``--scheduler ADDR``
hands the same function and the same seeds to a Dask distributed scheduler (``dask scheduler`` on
one machine, ``dask worker ADDR`` on each machine that lends cores; every worker started from an
environment where this project is installed at the same version). Each run is seeded, so its
result does not depend on where or when it ran; results come back in seed order either way, and
the progress callback counts them as they finish.

Dask distributed is an optional extra (``pip install 'formation-cbf[cluster]'``); this module
imports it only when a scheduler is named.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, TypeVar

T = TypeVar("T")
R = TypeVar("R")
Progress = Callable[[int, int, float], None]

CONNECT_TIMEOUT_S = 15.0  # how long a named scheduler may take to answer before the sweep gives up
PROJECT = "formation-cbf"  # the distribution every worker must have, at this machine's version


class ClusterError(RuntimeError):
    """The named scheduler cannot run the sweep: unreachable, no workers, or a worker without
    this project at this version. The message is one line naming the address or worker."""


def project_version() -> str:
    """The installed version of this project ("unknown" from a bare checkout)."""
    from importlib import metadata

    try:
        return metadata.version(PROJECT)
    except metadata.PackageNotFoundError:
        return "unknown"


def run_local(fn: Callable[[T], R], items: Sequence[T], jobs: int,
              progress: Progress | None = None) -> list[R]:
    """``fn`` over ``items`` in ``jobs`` processes of this machine, results in input order; the
    progress callback counts runs as they finish, in any order (one long run does not hold the
    count of those after it back). A run that raises re-raises here."""
    results: list[Any] = [None] * len(items)
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        index = {pool.submit(fn, item): k for k, item in enumerate(items)}
        for done, future in enumerate(as_completed(index), start=1):
            results[index[future]] = future.result()
            if progress:
                progress(done, len(items), 0.0)
    return results


def connect(address: str) -> Any:
    """A Dask client of the scheduler at ``address``, checked: reachable, at least one worker,
    and every worker importing this project at this version."""
    try:
        from distributed import Client
    except ImportError as exc:
        raise ClusterError(f"--scheduler {address}: needs Dask distributed "
                           f"(pip install '{PROJECT}[cluster]')") from exc
    try:
        client = Client(address, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ClusterError(f"--scheduler {address}: no scheduler answers there ({exc})") from exc
    try:
        check_workers(client, address)
    except ClusterError:
        client.close()
        raise
    return client


def check_workers(client: Any, address: str) -> None:
    """Raise ClusterError unless the cluster has workers that all run this project's version."""
    versions = client.run(project_version)
    if not versions:
        raise ClusterError(f"--scheduler {address}: the scheduler has no workers")
    ours = project_version()
    for worker, theirs in sorted(versions.items()):
        if theirs != ours:
            raise ClusterError(f"--scheduler {address}: worker {worker} runs {PROJECT} "
                               f"{theirs}, this machine {ours}")


def run_on_cluster(client: Any, fn: Callable[[T], R], items: Sequence[T],
                   progress: Progress | None = None) -> list[R]:
    """``fn`` over ``items`` on the client's cluster, results in input order; the progress
    callback counts runs as they finish, in any order. A run that raises re-raises here."""
    from distributed import as_completed

    with client.as_current():
        futures = client.map(fn, list(items), pure=False)
        index = {f.key: k for k, f in enumerate(futures)}
        results: list[Any] = [None] * len(futures)
        for done, future in enumerate(as_completed(futures), start=1):
            results[index[future.key]] = future.result()
            if progress:
                progress(done, len(futures), 0.0)
    return results


def run_sweep(fn: Callable[[T], R], items: Sequence[T], jobs: int = 2,
              scheduler: str | None = None, progress: Progress | None = None) -> list[R]:
    """``fn`` over ``items``: on the Dask cluster of ``scheduler`` when one is named, else in
    ``jobs`` local processes. ``fn`` must be picklable (a module-level function or a partial)."""
    if scheduler is None:
        return run_local(fn, items, jobs, progress)
    client = connect(scheduler)
    try:
        return run_on_cluster(client, fn, items, progress)
    finally:
        client.close()
