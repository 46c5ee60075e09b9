"""System packages a test needs (sshd, chromium): skip with one line naming the package, except
under ``.ci/run``, which installs them first and sets ``FORMATION_SYSTEM_PACKAGES=required``:
there a missing one fails the test, so CI never passes by skipping."""

from __future__ import annotations

import os

import pytest


def require(present: bool, what: str, package: str) -> None:
    """Skip (or, under ``.ci/run``, fail) unless ``present``: ``what`` is missing, ``package``
    is the Debian package that brings it."""
    if present:
        return
    line = f"{what} is not installed (apt-get install {package}; .ci/run installs it)"
    if os.environ.get("FORMATION_SYSTEM_PACKAGES") == "required":
        pytest.fail(line)
    pytest.skip(line)
