"""Which agent a machine runs: a digest of the agent's source as that machine's Python imports it.

Kept free of the project's heavier imports: ``formation run --hosts`` runs it on every host before
a run (``python -c "from deploy.digest import package_digest; ..."``) and compares it with this
machine's (:mod:`deploy.remote`).
"""

from __future__ import annotations

import hashlib
import importlib.util
from collections.abc import Sequence
from pathlib import Path

AGENT_PACKAGES = ("geometry", "wire", "scenario", "leader", "agent")  # what an agent runs


def package_digest(names: Sequence[str] = AGENT_PACKAGES) -> str:
    """Digest of the source of the packages ``names`` as this interpreter imports them (names,
    sizes and bytes of their ``.py`` files): equal here and on a host when both run the same
    agent."""
    h = hashlib.sha256()
    for name in names:
        spec = importlib.util.find_spec(name)
        if spec is None or spec.origin is None:
            h.update(f"{name}\0missing\0".encode())
            continue
        for path in sorted(Path(spec.origin).parent.glob("*.py")):
            data = path.read_bytes()
            h.update(f"{name}/{path.name}\0{len(data)}\0".encode())
            h.update(data)
    return h.hexdigest()[:16]
