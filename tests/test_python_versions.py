"""One Python minimum, 3.10, for everything: what `formation deploy` runs on a robot works on the
robot's stock Python (Ubuntu 22.04 / ROS 2 Humble has 3.10, 24.04 / Jazzy 3.12), and so does
`formation deploy` itself on a camera PC of the same Ubuntu. The agent imports only the robot
packages (checked below), a minimum-version checker (vermin) finds nothing newer than 3.10 in
them nor in deploy, and every interpreter of those versions this machine has compiles them."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from deploy import pyproject

REPO = Path(__file__).resolve().parent.parent
ROBOT_PACKAGES = ("agent", "leader", "scenario", "wire")  # what `python -m agent` imports
CHECKED = (*ROBOT_PACKAGES, "deploy")  # and the camera PC's deploy, which reads no tomllib
OURS = ("agent", "leader", "scenario", "wire", "deploy", "camera_service", "simulator", "formation")


@pytest.mark.integration
def test_the_agent_imports_nothing_of_ours_beyond_the_robot_packages():
    code = ("import sys, agent.__main__, agent.node; print(' '.join(sorted({m.split('.')[0] "
            f"for m in sys.modules if m.split('.')[0] in {OURS!r}}})))")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True,
                         check=True).stdout.split()
    assert set(out) <= set(ROBOT_PACKAGES), out


WORKSTATION_ONLY = ("qpsolvers", "osqp", "cv2", "matplotlib", "foxglove", "scipy", "mcap")


@pytest.mark.integration
def test_the_agent_starts_with_the_workstations_packages_blocked():
    """The robot installs only eclipse-zenoh, numpy and PyYAML (docs/deploy.md): importing the
    agent must not load qpsolvers, osqp, OpenCV, matplotlib or foxglove (an import hook refuses
    them), and what it loads from outside the standard library is exactly those three."""
    code = f"""
import importlib.abc, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split('.')[0] in {WORKSTATION_ONLY!r}:
            raise ImportError('blocked on a robot: ' + name)
sys.meta_path.insert(0, Block())
import agent.__main__, agent.node, agent.base
ours = {OURS!r} + ('geometry', 'runtime')
print(' '.join(sorted({{m.split('.')[0] for m in sys.modules if not m.startswith('_')}}
                      - set(sys.stdlib_module_names) - set(ours))))
"""
    res = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert set(res.stdout.split()) - {"cython_runtime"} == {"numpy", "yaml", "zenoh"}, res.stdout


def test_pyproject_readme_and_deploy_doc_name_one_python_range_and_the_robots_versions():
    meta = pyproject.table((REPO / "pyproject.toml").read_text(), "project")
    assert meta["requires-python"] == ">=3.10"
    assert "numpy>=1.21" in meta["dependencies"] and "pyyaml>=5.4" in meta["dependencies"]
    assert "Python >= 3.10" in (REPO / "README.md").read_text()
    deploy = (REPO / "docs" / "deploy.md").read_text()
    assert "--system-site-packages" in deploy and "pip install --user" not in deploy


@pytest.mark.integration
def test_a_minimum_version_checker_finds_nothing_newer_than_python_3_10_in_the_robot_code_or_deploy():
    pytest.importorskip("vermin")
    run = "import sys, vermin; sys.argv[0] = 'vermin'; sys.exit(vermin.main())"
    res = subprocess.run([sys.executable, "-c", run, "--no-tips", "--violations",
                          "--eval-annotations", "-t=3.10-", *CHECKED], cwd=REPO,
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr


def _interpreter(version: str) -> str | None:
    """A working ``python{version}``: on the PATH, or one pyenv holds but has not enabled."""
    candidates = [shutil.which(f"python{version}"), f"/usr/bin/python{version}",
                  *map(str, sorted(Path.home().glob(f".pyenv/versions/{version}*/bin/python{version}")))]
    for found in filter(None, candidates):
        try:
            ok = subprocess.run([found, "-c", "import sys; print(sys.version_info[:2])"],
                                capture_output=True, text=True, timeout=20)
        except OSError:
            continue
        if ok.returncode == 0 and f"({version.replace('.', ', ')})" in ok.stdout:
            return found
    return None


@pytest.mark.integration
@pytest.mark.parametrize("version", ["3.10", "3.12"])
def test_the_robot_code_and_deploy_compile_with_each_robot_python_this_machine_has(version, tmp_path):
    python = _interpreter(version)
    if python is None:
        pytest.skip(f"no python{version} on this machine")
    for package in CHECKED:
        res = subprocess.run([python, "-m", "compileall", "-q", "-d", package, str(REPO / package)],
                             capture_output=True, text=True,
                             env={"PYTHONPYCACHEPREFIX": str(tmp_path), "PATH": "/usr/bin:/bin"})
        assert res.returncode == 0, res.stdout + res.stderr


def test_deploys_pyproject_reader_reads_what_tomllib_reads():
    tomllib = pytest.importorskip("tomllib")  # Python 3.11 or newer: the reference
    text = (REPO / "pyproject.toml").read_text()
    meta = tomllib.loads(text)
    project = pyproject.table(text, "project")
    assert {k: v for k, v in meta["project"].items() if isinstance(v, str | list)} == project
    assert pyproject.strings(text, "tool.setuptools", "packages") == meta["tool"]["setuptools"]["packages"]


def test_deploys_pyproject_reader_takes_comments_both_quotes_and_says_what_it_lacks():
    text = """# a comment
[project]
name = 'formation-cbf'  # the distribution
version = "1.2.3"
dependencies = [
    "a>=1",  # a comment with a ] in it
    'b',
]
count = 3
[tool.setuptools]
packages = ["x", "y"]
"""
    assert pyproject.table(text, "project") == {"name": "formation-cbf", "version": "1.2.3",
                                                "dependencies": ["a>=1", "b"]}
    assert pyproject.strings(text, "tool.setuptools", "packages") == ["x", "y"]
    with pytest.raises(pyproject.PyprojectError, match=r"\[project\] has no count as a plain string"):
        pyproject.string(text, "project", "count")
    with pytest.raises(pyproject.PyprojectError, match="no packages as an array"):
        pyproject.strings(text, "project", "packages")
