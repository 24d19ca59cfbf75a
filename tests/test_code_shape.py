"""The project's shape rule: no file over 400 lines, no function over 80 lines.

Tests and data are aside; everything else the project tracks (Python packages, the console's JavaScript)
counts. Run it as a script (`python tests/test_code_shape.py`) to list every offender.
"""

from __future__ import annotations

import ast
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_FILE_LINES = 400
MAX_FUNCTION_LINES = 80
_SOURCE_SUFFIXES = (".py", ".js")


def project_sources() -> list[Path]:
    """The tracked (and untracked, not ignored) .py and .js files outside tests/."""
    listed = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    return sorted(
        ROOT / name
        for name in listed
        if name.endswith(_SOURCE_SUFFIXES) and not name.startswith("tests/") and (ROOT / name).is_file()
    )


def long_files(paths: list[Path]) -> list[str]:
    """`path: N lines` for each file over MAX_FILE_LINES."""
    found = []
    for path in paths:
        count = len(path.read_text(encoding="utf-8").splitlines())
        if count > MAX_FILE_LINES:
            found.append(f"{path.relative_to(ROOT)}: {count} lines")
    return found


def long_functions(paths: list[Path]) -> list[str]:
    """`path:line name: N lines` for each Python function (decorators included) over MAX_FUNCTION_LINES."""
    found = []
    for path in paths:
        if path.suffix != ".py":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                first = min([node.lineno] + [d.lineno for d in node.decorator_list])
                count = node.end_lineno - first + 1
                if count > MAX_FUNCTION_LINES:
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}: {count} lines")
    return found


def test_no_file_over_400_lines():
    assert long_files(project_sources()) == []


def test_no_function_over_80_lines():
    assert long_functions(project_sources()) == []


if __name__ == "__main__":
    sources = project_sources()
    for line in long_files(sources) + long_functions(sources):
        print(line)
