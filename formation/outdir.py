"""The ``--out DIR`` of the commands that write a run's output: a run owns its folder.

* Checked before anything runs: a path naming a file, a folder under a file, or a folder this
  process cannot write is invalid input (exit status 2, one line), not a traceback after the work
  is done (:func:`check_out`). A missing folder is fine when its nearest existing ancestor is a
  folder this process can create a folder in (probed with a folder made and removed at once).
* One run at a time: :class:`OutputFolder` holds ``DIR/.formation.lock`` (the pid and host of
  the run) while the command runs; a second run into the same folder is refused (exit 2). A lock
  whose process is gone (a killed run) is stale and taken over.
* Re-running replaces the output cleanly: ``DIR/.formation-output.json`` lists what the run
  wrote; the next run into the folder removes exactly that before it writes, so no stale file
  survives (``make demo`` is repeatable). It does so only once its input is valid
  (:func:`begin_output`), so an invalid scenario loses nothing. A folder holding anything else
  (files no formation run wrote) is refused unless ``--force``; with ``--force`` those files
  are left as they are and the output is written beside them.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import socket
import tempfile
from pathlib import Path
from types import TracebackType
from typing import Any

from formation.exits import UsageError

#: Subcommands whose ``--out`` is a folder of output files (``record``: its ``run.mcap``).
FOLDER_COMMANDS = ("sim", "run", "commcost", "montecarlo", "bench", "record")


def out_problem(out: str | os.PathLike[str]) -> str | None:
    """Why ``out`` cannot be an output folder, or ``None`` when it can."""
    p = Path(out)
    if str(out) == "" or "\0" in str(out):
        return "is not a path"
    if p.exists():
        if not p.is_dir():
            return "exists and is not a folder"
        return _unwritable(p)
    ancestor = p.parent
    while not ancestor.exists():
        if ancestor == ancestor.parent:
            return "has no existing parent folder"
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        return f"cannot be created: {ancestor} is not a folder"
    problem = _unwritable(ancestor)
    return None if problem is None else f"cannot be created: {ancestor} {problem}"


def _unwritable(folder: Path) -> str | None:
    """A real write probe, a folder made and removed at once (permission bits do not tell
    about read-only mounts, pseudo file systems or ACLs, nor about root)."""
    try:
        name = tempfile.mkdtemp(prefix=".formation-out-check-", dir=folder)
    except OSError as exc:
        return f"is not writable ({exc.strerror or exc})"
    try:
        os.rmdir(name)
    except OSError:
        pass
    return None


def check_out(command: str, out: str | os.PathLike[str] | None) -> None:
    """Raise :class:`formation.exits.UsageError` naming ``--out`` when it cannot be used."""
    if out is None or command not in FOLDER_COMMANDS:
        return
    problem = out_problem(out)
    if problem is not None:
        raise UsageError(f"--out {str(out)[:200]!r} {problem}")


LOCK = ".formation.lock"
MARKER = ".formation-output.json"

#: What the commands write at the top of ``--out`` (a folder without :data:`MARKER` holding only
#: these is taken as the output of a run from before the marker existed).
KNOWN_OUTPUT = frozenset({
    "summary.json", "robots.csv", "ellipses.csv", "obstacles.csv", "trajectories.png",
    "safety.png", "run.mcap", "agents", "logs", "configs", "secure", "processes.json",
    "commcost.csv", "commcost.md", "commcost.png", "commcost.json", "scenarios", "runs",
    "montecarlo.json", "runs.jsonl", "bench.json", "bench.txt",
})


def _known(name: str) -> bool:
    return name in KNOWN_OUTPUT or (name.startswith("failure-") and name.endswith(".yaml"))


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's process
    return True


class OutputFolder:
    """The ``--out`` folder of one run: locked while the command runs, cleared of the previous
    run's output by :meth:`begin`, its own output listed in :data:`MARKER` at the end.

    Use as a context manager around the command (``formation.cli.main`` does); refusals raise
    :class:`formation.exits.UsageError` (exit status 2) before anything is written."""

    def __init__(self, out: str | os.PathLike[str], force: bool = False) -> None:
        self.path = Path(out)
        self.force = force
        self.created = False  # this run made the folder
        self.locked = False
        self.begun = False
        self.owned: list[str] = []  # the previous run's entries, removed by begin()
        self.foreign: list[str] = []  # entries no run wrote, kept (with --force)

    # --- claim: lock, then look at what is there ------------------------------------------

    def __enter__(self) -> OutputFolder:
        self.claim()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.release()

    def claim(self) -> None:
        if not self.path.exists():
            self.path.mkdir(parents=True)
            self.created = True
        self._lock()
        try:
            self.owned, self.foreign = self._survey()
            if self.foreign and not self.force:
                shown = ", ".join(repr(n) for n in sorted(self.foreign)[:3])
                more = f" and {len(self.foreign) - 3} more" if len(self.foreign) > 3 else ""
                raise UsageError(
                    f"--out {str(self.path)[:200]!r} holds files that are not a formation run's "
                    f"output ({shown}{more}): choose another folder, or --force to write beside them")
        except BaseException:
            self.release()
            raise

    def _lock(self) -> None:
        lock = self.path / LOCK
        mine = f"{os.getpid()} {socket.gethostname()}\n"
        for _ in range(3):
            try:
                fd = os.open(lock, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileExistsError:
                holder = self._holder(lock)
                if holder is not None:
                    raise UsageError(
                        f"--out {str(self.path)[:200]!r} is in use by another formation run "
                        f"({holder}; lock file {lock})") from None
                with contextlib.suppress(FileNotFoundError):
                    lock.unlink()  # stale: its run is gone
                continue
            except OSError as exc:
                raise UsageError(f"--out {str(self.path)[:200]!r}: cannot lock "
                                 f"({exc.strerror or exc})") from None
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(mine)
            self.locked = True
            return
        raise UsageError(f"--out {str(self.path)[:200]!r}: another run keeps taking its lock {lock}")

    @staticmethod
    def _holder(lock: Path) -> str | None:
        """Who holds ``lock`` (``"pid N on HOST"``), or ``None`` when its run is gone."""
        try:
            pid_text, _, host = lock.read_text(encoding="utf-8").strip().partition(" ")
            pid = int(pid_text)
        except FileNotFoundError:
            return None
        except (OSError, ValueError):
            return None  # unreadable or half-written by a run killed at once: stale
        if host and host != socket.gethostname():
            return f"pid {pid} on {host}"  # another machine's: cannot tell, so in use
        if pid == os.getpid() or not _pid_alive(pid):
            return None
        return f"pid {pid}"

    def _survey(self) -> tuple[list[str], list[str]]:
        """(the previous run's entries, entries no run wrote)."""
        names = sorted(n for n in os.listdir(self.path) if n not in (LOCK, MARKER))
        marker = self._read_marker()
        if marker is None:
            owned = [n for n in names if _known(n)]
        elif isinstance(marker.get("entries"), list):  # a run that finished
            listed = set(marker["entries"])
            owned = [n for n in names if n in listed]
        else:  # a run that did not finish: everything but what it kept
            kept = set(marker.get("foreign") or ())
            owned = [n for n in names if n not in kept]
        foreign = [n for n in names if n not in set(owned)]
        return owned, foreign

    def _read_marker(self) -> dict[str, Any] | None:
        try:
            data = json.loads((self.path / MARKER).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        return data if isinstance(data, dict) else None

    # --- begin: the input is valid, the run writes ------------------------------------------

    def begin(self) -> Path:
        """Remove the previous run's output (once: later calls do nothing) and mark the folder
        as this run's; returns the folder."""
        if self.begun:
            return self.path
        for name in self.owned:
            p = self.path / name
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                with contextlib.suppress(FileNotFoundError):
                    p.unlink()
        self._write_marker(None)
        self.begun = True
        return self.path

    def _write_marker(self, entries: list[str] | None) -> None:
        body: dict[str, Any] = {"written_by": "formation", "foreign": self.foreign}
        if entries is not None:
            body["entries"] = entries
        tmp = self.path / (MARKER + ".tmp")
        try:
            tmp.write_text(json.dumps(body, indent=1) + "\n", encoding="utf-8")
            os.replace(tmp, self.path / MARKER)
        except OSError:
            tmp.unlink(missing_ok=True)  # a full disk leaves no temporary file behind
            raise

    def release(self) -> None:
        """List what this run wrote (when it began), drop the lock; a folder this run made and
        never wrote into is removed again."""
        try:
            if self.begun:
                kept = set(self.foreign) | {LOCK, MARKER}
                with contextlib.suppress(OSError):
                    self._write_marker(sorted(n for n in os.listdir(self.path) if n not in kept))
        finally:
            if self.locked:
                with contextlib.suppress(FileNotFoundError):
                    (self.path / LOCK).unlink()
                self.locked = False
            if self.created and not self.begun:
                with contextlib.suppress(OSError):
                    self.path.rmdir()


def begin_output(ns: argparse.Namespace) -> Path:
    """The command's ``--out`` folder, emptied of the previous run's output: call it once the
    input is valid, just before the first write. Without a claimed folder (a command called
    from Python, not through ``formation``), the folder is only created."""
    folder = getattr(ns, "out_folder", None)
    if isinstance(folder, OutputFolder):
        return folder.begin()
    out = Path(ns.out)
    out.mkdir(parents=True, exist_ok=True)
    return out
