"""The wheel carries the shipped scenarios (issue 29, item 5): a ``pip install`` names them
(``formation sim thesis-5.2.2``), lists them (``formation scenarios``), and ``formation bench``
finds its default scenario, with no checkout anywhere near."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from deploy.deployer import build_wheel
from scenario.shipped import SHIPPED_DIR, resolve, shipped_names

pytestmark = pytest.mark.integration  # builds a wheel (pip, an isolated build)

REPO = Path(__file__).resolve().parent.parent


def test_a_bare_name_resolves_to_the_shipped_scenario_and_a_real_path_wins(tmp_path):
    assert "thesis-5.2.2" in shipped_names() and "warehouse" in shipped_names()
    assert resolve("thesis-5.2.2") == SHIPPED_DIR / "thesis-5.2.2.yaml"
    assert resolve("scenarios/warehouse.yaml").is_file()
    own = tmp_path / "thesis-5.2.2.yaml"
    own.write_text("name: mine\n")
    assert resolve(own) == own
    assert resolve("no-such-scenario") == Path("no-such-scenario")
    assert resolve("elsewhere/thesis-5.2.2") == Path("elsewhere/thesis-5.2.2")  # not a bare name


def test_the_installed_wheel_holds_and_names_the_scenarios(tmp_path):
    wheels, site = tmp_path / "wheels", tmp_path / "site"
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check"]
    wheel = build_wheel(wheels, REPO)  # as formation deploy builds it: from a copy, pip wheel
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {f"scenarios/{n}.yaml" for n in shipped_names()} <= names
    subprocess.run([*pip, "install", "-q", "--no-deps", "--target", str(site), str(wheel)],
                   check=True, capture_output=True)
    env = {**os.environ, "PYTHONPATH": str(site)}

    def formation(*args: str) -> str:
        res = subprocess.run([sys.executable, "-m", "formation", *args], cwd=tmp_path, env=env,
                             capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, res.stdout + res.stderr
        return res.stdout

    listed = formation("scenarios")
    assert "thesis-5.2.2" in listed.split() and str(site / "scenarios") in listed
    assert formation("check", "thesis-5.2.2").startswith("thesis-5.2.2: ok")
    code = "import experiments.bench as b; print(b.DEFAULT_SCENARIO.resolve())"
    found = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, check=True,
                           capture_output=True, text=True).stdout.strip()
    assert Path(found) == (site / "scenarios" / "warehouse.yaml").resolve() and Path(found).is_file()
