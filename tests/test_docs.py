"""The docs stand alone and their commands work as written.

Every command in a fenced ``sh`` or ``bash`` block of README.md and docs/*.md is checked:

* cheap ones (``formation check``, anything with ``--help``, ``--dry-run``) run as written, from
  a scratch folder that holds the project's scenarios and docs, with ``.venv/bin/`` meaning the
  bin folder of the interpreter running the tests;
* long ones (simulations, benchmarks, ``make``) are parsed by the real argument parser, scripts
  must exist and answer ``--help``, modules must import, make targets must exist;
* blocks marked ``sh hardware`` (they need robots or a lab network) are parsed, not run, and a
  ``formation`` command in them needs a dry run of the same subcommand in the same file that runs;
* every project path a command names exists (paths under ``runs/`` are what commands write).
"""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

from formation import clidoc
from formation.cli import build_parser

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BIN = Path(sys.executable).parent
BLOCK = re.compile(r"^```(sh|bash)([^\n]*)\n(.*?)^```", re.M | re.S)
PATHLIKE = re.compile(r"^(scenarios|docs|benchmarks|tests|deploy|runs)/|\.(ya?ml|py|md|json|mcap)$")
PLAIN_TOOLS = {"cp", "mkdir", "ls", "cat"}  # shell tools a long block may use around a command


@dataclass(frozen=True)
class Command:
    doc: str
    argv: tuple[str, ...]
    marks: frozenset[str]

    def __str__(self) -> str:
        return f"{self.doc}: {shlex.join(self.argv)}"


def _commands() -> list[Command]:
    found = []
    for doc in DOCS:
        for match in BLOCK.finditer(doc.read_text(encoding="utf-8")):
            marks = frozenset(match.group(2).split())
            text = match.group(3).replace("\\\n", " ")
            for line in text.splitlines():
                argv = shlex.split(line, comments=True)
                if argv:
                    found.append(Command(doc.relative_to(ROOT).as_posix(), tuple(argv), marks))
    return found


COMMANDS = _commands()


def _program(cmd: Command) -> tuple[str, list[str]]:
    """(what runs, its arguments): ``formation``, ``python``, ``make`` or a plain tool."""
    head, *args = cmd.argv
    if head in (".venv/bin/formation",):
        return "formation", args
    if head in (".venv/bin/python", ".venv/bin/python3"):
        if args[:2] == ["-m", "formation"]:
            return "formation", args[2:]
        return "python", args
    if head == "make" or head in PLAIN_TOOLS:
        return head, args
    if "hardware" in cmd.marks:
        return "hardware-tool", args
    pytest.fail(f"{cmd}: write `.venv/bin/formation` or `.venv/bin/python` (the project's "
                f"environment), or mark the block `sh hardware`")


def _cheap(cmd: Command) -> bool:
    program, args = _program(cmd)
    if "hardware" in cmd.marks or "long" in cmd.marks:
        return False
    if program == "formation":
        return bool({"--help", "-h", "--dry-run"} & set(args)) or args[:1] == ["check"]
    return program == "python" and "--help" in args


def _parse(args: list[str]) -> None:
    if {"--help", "-h"} & set(args):
        return  # the run itself checks it
    try:
        build_parser().parse_args(args)
    except SystemExit as exc:
        pytest.fail(f"formation {shlex.join(args)}: not accepted by the parser ({exc})")


def _sandbox(tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """A scratch folder with the project's inputs, and an environment with the key of deploy.md."""
    work = tmp_path / "work"
    work.mkdir()
    for name in ("scenarios", "docs", "benchmarks", "tests", "Makefile"):
        (work / name).symlink_to(ROOT / name)
    home = tmp_path / "home"
    (home / ".ssh").mkdir(parents=True)
    (home / ".ssh" / "turtlebots").write_text("not a real key\n")  # deploy.md, step 2
    env = dict(os.environ, HOME=str(home), PYTHONPATH=str(ROOT))
    return work, env


def test_the_docs_hold_commands_and_mark_hardware():
    assert len(COMMANDS) >= 15
    assert any(_cheap(c) for c in COMMANDS)
    assert any("hardware" in c.marks for c in COMMANDS)


@pytest.mark.integration
@pytest.mark.parametrize("cmd", [c for c in COMMANDS if _cheap(c)], ids=str)
def test_a_cheap_command_in_the_docs_runs_as_written(cmd: Command, tmp_path: Path):
    work, env = _sandbox(tmp_path)
    argv = [str(BIN / Path(cmd.argv[0]).name), *cmd.argv[1:]]
    done = subprocess.run(argv, cwd=work, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, f"{cmd}\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"


@pytest.mark.parametrize("cmd", [c for c in COMMANDS if not _cheap(c)], ids=str)
def test_a_long_or_hardware_command_in_the_docs_is_valid(cmd: Command):
    program, args = _program(cmd)
    if program == "formation":
        _parse(args)
    elif program == "python":
        if args[0] == "-m":
            assert importlib.util.find_spec(args[1]) is not None, f"{cmd}: no module {args[1]}"
        else:
            script = ROOT / args[0]
            assert script.is_file(), f"{cmd}: no script {args[0]}"
            done = subprocess.run([sys.executable, str(script), "--help"], cwd=ROOT,
                                  capture_output=True, text=True, timeout=120)
            assert done.returncode == 0, f"{cmd} --help\n{done.stderr[-2000:]}"
    elif program == "make":
        makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
        for target in args:
            assert re.search(rf"^{re.escape(target)}:", makefile, re.M), f"{cmd}: no target"


@pytest.mark.parametrize("cmd", COMMANDS, ids=str)
def test_every_project_path_a_command_names_exists(cmd: Command):
    if "hardware" in cmd.marks and _program(cmd)[0] == "hardware-tool":
        return  # paths on a robot or the camera PC
    for token in cmd.argv[1:]:
        if token.startswith(("runs/", "-", "~", "/", "http")) or not PATHLIKE.search(token):
            continue
        assert (ROOT / token).exists(), f"{cmd}: {token} does not exist"


def test_every_formation_command_that_needs_hardware_has_a_tested_dry_run():
    for cmd in COMMANDS:
        program, args = _program(cmd)
        if "hardware" not in cmd.marks or program != "formation":
            continue
        assert any(_cheap(c) and c.doc == cmd.doc and "--dry-run" in c.argv
                   and _program(c)[1][:1] == args[:1] for c in COMMANDS), f"{cmd}: no dry run"


def test_no_doc_points_outside_the_project():
    for doc in DOCS:
        text = doc.read_text(encoding="utf-8")
        assert "../shared" not in text, doc
        assert "DESIGN.md" not in text, doc  # the contracts live in docs/ now


README_MAX_LINES = 250
PACKAGES = ("geometry", "agent", "leader", "camera_service", "deploy", "scenario", "wire", "runtime",
            "simulator", "experiments", "formation", "viewer")
# a commit hash: 7-12 or 40 hex digits with a letter and a digit, not part of a number (2.21e-03)
COMMIT = re.compile(r"(?<![.\w-])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*\d)(?:[0-9a-f]{40}|[0-9a-f]{7,12})"
                    r"(?![\w-])")
# a tracker's issue: "issue 27", "issues 25-27", "#26" (not a colour such as #222, nor PR #388)
ISSUE = re.compile(r"\b[Ii]ssues? \d+|(?<![&\w\"])#\d{2}(?![\w])")
NOT_HASHES = {"ed25519"}
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def _history_refs(path: Path, skip=lambda line: False) -> list[str]:
    found = []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if skip(line):
            continue
        hits = [m.group(0) for m in COMMIT.finditer(line) if m.group(0) not in NOT_HASHES]
        hits += [m.group(0) for m in ISSUE.finditer(line)]
        found += [f"{path.relative_to(ROOT)}:{number}: {hit}" for hit in hits]
    return found


def test_the_readme_is_a_front_door_of_under_250_lines():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) < README_MAX_LINES, f"README.md has {len(lines)} lines: move detail to docs/"


def test_every_relative_link_of_the_docs_resolves():
    for doc in [*DOCS, ROOT / "CHANGELOG.md"]:
        for target in LINK.findall(doc.read_text(encoding="utf-8")):
            if target.startswith(("http://", "https://", "mailto:", "#")):
                continue
            path = (doc.parent / target.split("#")[0]).resolve()
            assert path.exists(), f"{doc.relative_to(ROOT)}: link to {target} finds nothing"


def test_the_docs_hold_no_commit_hashes_or_issue_numbers():
    """History lives in CHANGELOG.md and git; results.md names commits on its provenance lines."""
    found = []
    for doc in DOCS:
        provenance = (lambda line: line.startswith("- main ")) if doc.name == "results.md" else (
            lambda line: False)
        found += _history_refs(doc, provenance)
    assert not found, "history in the docs:\n" + "\n".join(found)


def test_production_code_holds_no_commit_hashes_or_issue_numbers():
    """Code says what and why; which issue or commit made it so is git's to say."""
    files = [p for package in PACKAGES for p in sorted((ROOT / package).rglob("*.py"))]
    files += sorted((ROOT / "scenarios").glob("*.yaml"))
    found = [hit for path in files for hit in _history_refs(path)]
    assert not found, "history in the code:\n" + "\n".join(found)


def test_the_thesis_is_cited_by_its_title():
    readme = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    assert "Coordination of Multi Robot Systems for Warehouse Automation" in readme


def test_the_command_line_reference_matches_the_parser():
    text = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    assert text == clidoc.updated(text), (
        "docs/cli.md is out of date: run .venv/bin/python -m formation.clidoc --write docs/cli.md")
    for sub in ("check", "sim", "run", "commcost", "montecarlo", "bench", "deploy", "view",
                "record", "replay"):
        assert f"### `formation {sub}`" in text


def test_the_scenario_example_in_the_docs_is_a_valid_scenario(tmp_path: Path):
    from scenario import load_scenario

    text = (ROOT / "docs" / "scenarios.md").read_text(encoding="utf-8")
    example = re.search(r"^```yaml\n(.*?)^```", text, re.M | re.S).group(1)
    path = tmp_path / "example.yaml"
    path.write_text(example, encoding="utf-8")
    scenario = load_scenario(path)
    assert scenario.name == "two_formations_crossing" and len(scenario.robot_ids) == 2


def test_the_example_inventory_is_the_one_deploy_md_shows():
    text = (ROOT / "docs" / "deploy.md").read_text(encoding="utf-8")
    shown = re.search(r"^```yaml\n(.*?)^```", text, re.M | re.S).group(1)
    assert shown == (ROOT / "docs" / "examples" / "lab.yaml").read_text(encoding="utf-8")


def test_the_calibration_example_in_camera_md_loads():
    from camera_service.calibration import calibration_from_dict

    text = (ROOT / "docs" / "camera.md").read_text(encoding="utf-8")
    example = re.search(r"^```yaml\n(.*?)^```", text, re.M | re.S).group(1)
    calibration = calibration_from_dict(yaml.safe_load(example))
    assert calibration.image_size == (1280, 960)


@pytest.mark.integration
def test_the_first_calibration_in_camera_md_runs_end_to_end(tmp_path: Path):
    """camera.md's first calibration: render the floor markers, calibrate on the frame; the
    calibration maps every floor marker's true pixel centre back within 3 mm of its survey."""
    from camera_service.calibration import floor_to_pixel, load_calibration, pixel_to_floor
    from camera_service.config import load_floor

    work, env = _sandbox(tmp_path)
    (work / "runs").mkdir()
    steps = [c for c in COMMANDS if c.doc == "docs/camera.md" and
             ("camera_service.floorframe" in c.argv or c.argv[1:2] == ("calibrate",))]
    assert len(steps) == 2
    for cmd in steps:
        argv = [str(BIN / Path(cmd.argv[0]).name), *cmd.argv[1:]]
        done = subprocess.run(argv, cwd=work, env=env, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, f"{cmd}\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"
    runs = work / "runs"
    truth, found = load_calibration(runs / "truth.yaml"), load_calibration(runs / "calib.yaml")
    for x, y in load_floor(ROOT / "docs" / "examples" / "floor.yaml").markers.values():
        back = pixel_to_floor(found, floor_to_pixel(truth, [[x, y]]))[0]
        assert abs(back[0] - x) < 3e-3 and abs(back[1] - y) < 3e-3
