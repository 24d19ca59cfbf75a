"""The base install (`pip install .`, no extras) as the set of top-level modules it provides.

`blocked_modules()` lists the top-level modules of every installed distribution that the base install would
not bring: those outside the closure of pyproject's `dependencies` (each dependency's own requirements
followed, markers evaluated without extras). site/sitecustomize.py turns that list into ImportErrors.
"""

from __future__ import annotations

import tomllib
from importlib import metadata
from pathlib import Path

from packaging.markers import default_environment
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[2]
SITE = Path(__file__).resolve().parent / "site"


def base_requirements() -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    return [Requirement(r) for r in project["dependencies"]]


def _applies(req: Requirement, extras: set[str]) -> bool:
    if req.marker is None:
        return True
    env = {key: str(value) for key, value in default_environment().items()}
    return any(req.marker.evaluate({**env, "extra": e}) for e in (extras or {""}))


def base_closure() -> set[str]:
    """Canonical names of the distributions the base install brings (the ones installed here)."""
    seen: set[str] = set()
    todo = [(r, set(r.extras)) for r in base_requirements()]
    while todo:
        req, extras = todo.pop()
        name = canonicalize_name(req.name)
        if not _applies(req, set()) or name in seen:
            continue
        seen.add(name)
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            continue
        for sub in dist.requires or []:
            r = Requirement(sub)
            if _applies(r, extras):
                todo.append((r, set(r.extras)))
    return seen


def blocked_modules() -> list[str]:
    """Top-level modules provided only by installed distributions outside the base closure."""
    keep = base_closure() | {"hitl-tamer", "pip", "setuptools", "wheel"}
    blocked = set()
    for module, dists in metadata.packages_distributions().items():
        if not any(canonicalize_name(d) in keep for d in dists):
            blocked.add(module)
    return sorted(blocked)
