"""The ``--out DIR`` of the commands that write a run's output, checked before anything runs
(issue 12): a path naming a file, a folder under a file, or a folder this process cannot write
is invalid input (exit status 2, one line), not a traceback after the work is done.

Nothing is left behind here: a missing folder is fine when its nearest existing ancestor is a
folder this process can create a folder in (probed with a folder made and removed at once); the
command creates ``--out`` when it writes.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

#: Subcommands whose ``--out`` is a folder of output files.
FOLDER_COMMANDS = ("sim", "run", "commcost", "montecarlo", "bench")


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
    """Raise :class:`formation.cli.UsageError` naming ``--out`` when it cannot be used."""
    if out is None or command not in FOLDER_COMMANDS:
        return
    problem = out_problem(out)
    if problem is not None:
        from formation.cli import UsageError

        raise UsageError(f"--out {str(out)[:200]!r} {problem}")
