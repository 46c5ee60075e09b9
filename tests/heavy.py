"""Which tests are `integration`: those that start a process, open a Zenoh session, bind a socket
or run a whole scenario. ``make check`` leaves them out, so it stays a quick loop.

Two halves, both used by tests/conftest.py:

* :func:`heavy_reason` reads a test before it runs (its source, its fixtures' and the helpers it
  calls in the tests package, as far as they go): a call of :data:`entry points <entry_points>`
  (``simulate``, ``summary_of``, ``subprocess.run``, ``zenoh.open``, ``RouterProcess``...) or a
  ``formation`` command that runs a scenario or opens a session marks it ``integration``.
* :class:`Guard` watches a test as it runs: a test not marked ``integration`` that still starts
  a process, opens a session, binds a socket or finishes a simulation fails, naming what it did,
  so a test the reading misses is caught instead of slowing ``make check`` unnoticed.
"""

from __future__ import annotations

import ast
import functools
import importlib
import inspect
import multiprocessing.process
import os
import socket
import subprocess
import sys
import threading
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

from formation.exits import EXIT_INVALID
from runtime.ports import free_tcp_port

TESTS = Path(__file__).resolve().parent

# `formation` commands that run a scenario, start processes or open a Zenoh session (a test that
# only asks one for --help stays quick)
HEAVY_COMMANDS = frozenset({"sim", "run", "commcost", "montecarlo", "bench", "view", "record", "replay",
                            "deploy", "camera", "goal", "status", "order", "orders"})


@functools.cache
def entry_points() -> dict[int, str]:
    """``id(object)`` -> what calling it does, for the calls that make a test `integration`."""
    import zenoh

    from agent.node import AgentNode
    from experiments.engines import run_both
    from experiments.method_bench import bench_method, bench_methods
    from formation.commands.bench import bench_command
    from runtime.testing import RouterProcess, fleet_acl_router, open_as
    from simulator.inprocess import simulate
    from simulator.lifelong import simulate_lifelong
    from tests.scenario_runs import summary_of
    from viewer.server import PageServer, View

    named: list[tuple[object, str]] = [
        (simulate, "runs a whole scenario (simulate)"),
        (simulate_lifelong, "runs a whole scenario (simulate_lifelong)"),
        (summary_of, "runs a whole scenario (summary_of)"),
        (bench_method, "runs a whole scenario (bench_method)"),
        (bench_methods, "runs whole scenarios (bench_methods)"),
        (bench_command, "runs `formation bench`"),
        (run_both, "starts `formation sim` processes (run_both)"),
        (RouterProcess, "starts a Zenoh router process"),
        (fleet_acl_router, "starts a Zenoh router process (under access control)"),
        (open_as, "opens a Zenoh session (open_as)"),
        (AgentNode, "builds an agent node (a real-time one starts its plan worker process)"),
        (PageServer, "serves the viewer's page on a socket"),
        (View, "serves the viewer on sockets"),
        (zenoh.open, "opens a Zenoh session"),
        (multiprocessing.Process, "starts a process"),
    ]
    named += [(getattr(subprocess, n), f"starts a process (subprocess.{n})")
              for n in ("Popen", "run", "call", "check_call", "check_output")]
    return {id(_unwrapped(obj)): what for obj, what in named}


def _unwrapped(obj: object) -> object:
    """The function under :class:`Guard`'s watch (its wrapper has ``__wrapped__``)."""
    return inspect.unwrap(obj) if inspect.isfunction(obj) else obj


def heavy_reason(module: ModuleType, function: Callable[..., Any], fixtures: list[str]) -> str | None:
    """Why the test ``function`` of ``module`` (with the fixtures named) is `integration`, read
    from its source; ``None`` when the reading finds nothing."""
    qualname = getattr(function, "__qualname__", function.__name__)
    return _reason(module.__name__, qualname, tuple(fixtures))


@functools.cache
def _reason(module: str, qualname: str, fixtures: tuple[str, ...]) -> str | None:
    todo = [(module, qualname)] + [(module, f) for f in fixtures]
    todo += [(name, f) for name in _conftests() for f in fixtures]
    seen: set[tuple[str, str]] = set()
    while todo:
        key = todo.pop()
        if key in seen:
            continue
        seen.add(key)
        reason, uses = _facts(*key)
        if reason is not None:
            return reason
        todo += uses
    return None


def _in_tests(module: object) -> bool:
    """Whether ``module`` is a file of the tests folder (imported as ``test_x`` or ``tests.x``),
    this reader itself left out."""
    file = getattr(module, "__file__", None)
    return isinstance(file, str) and _folder(file) == TESTS and Path(file).name != "heavy.py"


@functools.cache
def _folder(file: str) -> Path:
    return Path(file).resolve().parent


@functools.cache
def _conftests() -> list[str]:
    return [name for name, m in list(sys.modules.items())
            if _in_tests(m) and name.rsplit(".", 1)[-1] == "conftest"]


@functools.cache
def _definitions(module_name: str) -> dict[str, ast.AST]:
    """The functions and classes a tests module defines at its top level (and its classes'
    methods, as ``Class.method``)."""
    module = sys.modules.get(module_name)
    if module is None or not _in_tests(module):
        return {}
    try:
        tree = ast.parse(inspect.getsource(module))
    except (OSError, TypeError, SyntaxError):
        return {}
    out: dict[str, ast.AST] = {}
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            out[node.name] = node
        if isinstance(node, ast.ClassDef):
            for sub in node.body:
                if isinstance(sub, ast.FunctionDef | ast.AsyncFunctionDef):
                    out[f"{node.name}.{sub.name}"] = sub
    return out


def _local_names(node: ast.AST) -> dict[str, object]:
    """What the imports inside a function bind (``import zenoh`` in a test's body)."""
    out: dict[str, object] = {}
    for sub in ast.walk(node):
        if isinstance(sub, ast.Import):
            for alias in sub.names:
                top = alias.name.split(".")[0]
                out[alias.asname or top] = _module(alias.name if alias.asname else top)
        elif isinstance(sub, ast.ImportFrom) and sub.module and sub.level == 0:
            mod = _module(sub.module)
            for alias in sub.names:
                out[alias.asname or alias.name] = getattr(mod, alias.name, None) if mod else None
    return out


def _module(name: str) -> ModuleType | None:
    try:
        return importlib.import_module(name)
    except ImportError:
        return None


@functools.cache
def _facts(module_name: str, name: str) -> tuple[str | None, tuple[tuple[str, str], ...]]:
    """What the definition ``name`` of a tests module does itself that makes a test
    `integration` (or ``None``), and the tests package's definitions it uses."""
    node = _definitions(module_name).get(name)
    if node is None:
        return None, ()
    module = sys.modules[module_name]
    names = dict(vars(module))
    names.update(_local_names(node))
    heavy = entry_points()
    own = _definitions(module_name)
    uses: list[tuple[str, str]] = []
    refused = _refusals(node)
    for sub in _walk_body(node):
        obj: object = None
        if isinstance(sub, ast.Name):
            if sub.id in own:
                uses.append((module_name, sub.id))
                continue
            obj = names.get(sub.id)
        elif isinstance(sub, ast.Attribute) and isinstance(sub.value, ast.Name):
            base = names.get(sub.value.id)
            obj = getattr(base, sub.attr, None) if isinstance(base, ModuleType) else None
        elif isinstance(sub, ast.Call):
            reason = None if id(sub) in refused else _command_reason(sub, names)
            if reason is not None:
                return reason, ()
            continue
        else:
            continue
        if id(_unwrapped(obj)) in heavy:
            return heavy[id(_unwrapped(obj))], ()
        home = getattr(obj, "__module__", None)
        if isinstance(home, str) and _in_tests(sys.modules.get(home)) and hasattr(obj, "__name__"):
            uses.append((home, getattr(obj, "__name__", "")))
    return None, tuple(uses)


def _walk_body(node: ast.AST) -> Iterator[ast.AST]:
    """Every node of a definition's body, its decorators left out (a ``parametrize`` list names
    what the test is handed, not what it runs)."""
    for part in getattr(node, "body", [node]):
        yield from ast.walk(part)


def _refusals(node: ast.AST) -> set[int]:
    """The calls in ``node`` compared ``== 2`` (``assert main([...]) == 2``): a command refused
    as invalid input before it runs anything."""
    out = set()
    for sub in ast.walk(node):
        if (isinstance(sub, ast.Compare) and isinstance(sub.left, ast.Call) and len(sub.ops) == 1
                and isinstance(sub.ops[0], ast.Eq) and isinstance(sub.comparators[0], ast.Constant)
                and sub.comparators[0].value == EXIT_INVALID):
            out.add(id(sub.left))
    return out


def _command_reason(call: ast.Call, names: dict[str, object]) -> str | None:
    """``formation COMMAND`` for a call ``main(["COMMAND", ...])`` of the CLI whose command runs a
    scenario or opens a session."""
    from formation.cli import main

    func = call.func
    target = names.get(func.id) if isinstance(func, ast.Name) else None
    if isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name):
        base = names.get(func.value.id)
        target = getattr(base, func.attr, None) if isinstance(base, ModuleType) else None
    if _unwrapped(target) is not main or not call.args or not isinstance(call.args[0], ast.List | ast.Tuple):
        return None
    elts = call.args[0].elts
    words = [e.value for e in elts if isinstance(e, ast.Constant)]
    if "--help" in words or "-h" in words or not elts:
        return None
    if not isinstance(elts[0], ast.Constant):  # for mode in ("sim", "run"): main([mode, ...])
        return "runs a `formation` command named at run time"
    return f"runs `formation {words[0]}`" if words[0] in HEAVY_COMMANDS else None


class Guard:
    """What the test under way did that only an `integration` test may: each event one line,
    naming the test file's line that led to it."""

    def __init__(self) -> None:
        self.events: list[str] = []
        self._lock = threading.Lock()
        self._undo: list[Callable[[], None]] = []

    def note(self, what: str) -> None:
        if len(self.events) >= 5:
            return
        where = next((f"{Path(f.filename).name}:{f.lineno}" for f in reversed(traceback.extract_stack())
                      if Path(f.filename).parent == TESTS and Path(f.filename).name != "heavy.py"), "")
        with self._lock:
            if len(self.events) < 5:
                self.events.append(f"{what} ({where})" if where else what)

    def clear(self) -> None:
        with self._lock:
            self.events = []

    def install(self) -> None:
        """Watch every way a test starts a process, a session, a socket or a whole run."""
        import zenoh

        from simulator.inprocess import SimResult

        self._wrap(subprocess.Popen, "__init__", _started)
        self._wrap(multiprocessing.process.BaseProcess, "start", lambda a: "starts a process")
        self._wrap(os, "fork", lambda a: "forks a process")
        self._wrap(socket.socket, "bind", _bound)
        self._wrap(zenoh, "open", lambda a: "opens a Zenoh session")
        self._wrap(SimResult, "__init__", lambda a: "runs a whole scenario (simulate)")

    def uninstall(self) -> None:
        for undo in reversed(self._undo):
            undo()
        self._undo = []

    def _wrap(self, owner: object, name: str, what: Callable[[tuple], str | None]) -> None:
        original = getattr(owner, name)

        @functools.wraps(original)
        def watched(*args: Any, **kwargs: Any) -> Any:
            event = what(args)
            if event is not None:
                self.note(event)
            return original(*args, **kwargs)

        setattr(owner, name, watched)
        self._undo.append(lambda: setattr(owner, name, original))

    def report(self) -> Iterator[str]:
        with self._lock:
            yield from self.events


def _bound(args: tuple) -> str | None:
    """The event of ``socket.bind``; ``None`` for :func:`runtime.ports.free_tcp_port`, which binds
    port 0 only to learn a free port and closes the socket at once."""
    frame = inspect.currentframe()
    for _ in range(2):  # _bound <- watched <- the caller of bind
        frame = frame.f_back if frame is not None else None
    if frame is not None and frame.f_code is free_tcp_port.__code__:
        return None
    return f"binds a socket ({args[1] if len(args) > 1 else ''})"


def _started(args: tuple) -> str | None:
    """The event of ``subprocess.Popen``; ``None`` for ``fc-list``, which matplotlib runs to list
    the system's fonts when it builds its font cache (once, in a fresh environment, in whichever
    test draws first)."""
    argv = args[1] if len(args) > 1 else ""
    program = argv[0] if isinstance(argv, list | tuple) and argv else argv
    if isinstance(program, str) and Path(program).name == "fc-list":
        return None
    return f"starts a process ({_argv(args)})"


def _argv(args: tuple) -> str:
    argv = args[1] if len(args) > 1 else ""
    if isinstance(argv, list | tuple):
        return " ".join(str(a) for a in argv[:4])
    return str(argv)[:60]
