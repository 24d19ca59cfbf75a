"""Loaded at start-up by every Python process whose PYTHONPATH begins with this folder (children included).

It makes the installed distributions outside the base install unimportable, as if only `pip install .` had run:
BASE_ONLY_BLOCKED names their top-level modules (comma-separated; tests/install/base_only.py computes them).
"""

import os
import sys
from importlib.abc import MetaPathFinder

_BLOCKED = frozenset(filter(None, os.environ.get("BASE_ONLY_BLOCKED", "").split(",")))


class _NotInBaseInstall(MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        if fullname.partition(".")[0] in _BLOCKED:
            raise ModuleNotFoundError(f"No module named {fullname!r} (not in the base install)", name=fullname)
        return None


if _BLOCKED:
    sys.meta_path.insert(0, _NotInBaseInstall())
