"""The house around the code: one entry point per job, one command-line machinery, a short README, docs for users.

- At most 14 modules of the project (common/, services/, experiments/) can be run (`python -m ...`): the design
  card's service shells, `python -m services` and `python -m experiments`; every other tool is a subcommand.
- argparse is imported only by common/config.py (tests' helper scripts included): every command's config is a
  documented dataclass. (The tests' helper scripts run as processes are not counted as entry points.)
- The README is at most 80 lines, none over 160 characters.
- No page of docs/ (study logs, declared designs, bench tables and session history live in docs/notes/, dated)
  holds a dated study log, and no Markdown under docs/ names a path of one machine.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("common", "services", "experiments")
MAX_ENTRY_POINTS = 14


def project_files() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py") if "__pycache__" not in p.parts)


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__main__" else parts)


def runs_as_main(path: Path) -> bool:
    """A package's __main__.py, or a module with an `if __name__ == "__main__":` block."""
    if path.name == "__main__.py":
        return True
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.If) and isinstance(node.test, ast.Compare):
            names = {getattr(n, "id", None) for n in [node.test.left, *node.test.comparators]}
            values = {getattr(n, "value", None) for n in [node.test.left, *node.test.comparators]}
            if "__name__" in names and "__main__" in values and not moved_to(node):
                return True
    return False


def moved_to(block: ast.AST) -> str | None:
    """The new command a folded command's old module points to (`common.config.moved`), else None."""
    for node in ast.walk(block):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "moved":
            return node.args[0].value  # type: ignore[attr-defined]
    return None


def moved_modules() -> dict[str, str]:
    """module -> the command that replaced it, for every old module path that now only points the way."""
    found = {}
    for path in project_files():
        for node in ast.parse(path.read_text()).body:
            now = moved_to(node) if isinstance(node, ast.If) else None
            if now is not None:
                found[module_name(path)] = now
    return found


def entry_points() -> list[str]:
    return sorted({module_name(p) for p in project_files() if runs_as_main(p)})


def test_at_most_14_entry_points_each_a_job():
    found = entry_points()
    assert len(found) <= MAX_ENTRY_POINTS, f"{len(found)} entry points: {found}"
    # the design card's shells are among them
    assert {
        "services",
        "experiments",
        "services.actor",
        "services.learner",
        "services.teacher",
        "services.perception",
        "services.recorder",
        "services.replay",
        "services.console",
        "services.foxglove",
    } <= set(found), found


def imports_argparse(path: Path) -> bool:
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import) and any(a.name == "argparse" for a in node.names):
            return True
        if isinstance(node, ast.ImportFrom) and node.module == "argparse":
            return True
    return False


def test_argparse_only_in_common_config():
    """The project and its tests' helper scripts alike: every command line is a config dataclass."""
    tests = sorted(p for p in (ROOT / "tests").rglob("*.py") if "__pycache__" not in p.parts)
    users = [str(p.relative_to(ROOT)) for p in project_files() + tests if imports_argparse(p)]
    assert users == ["common/config.py"], users


def test_the_readme_is_short():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 80, f"README.md has {len(lines)} lines"
    long = [(n + 1, len(line)) for n, line in enumerate(lines) if len(line) > 160]
    assert not long, f"README.md lines over 160 characters (line, length): {long}"


MACHINE_PATH = re.compile(r"(?<![\w.<])(/work/|/root/|/tmp/|/home/)")
DATED = re.compile(
    r"Declared before the runs? of|\b20\d\d-[01]\d-[0-3]\d\b|"
    r"\b[0-3]?\d (January|February|March|April|May|June|July|August|September|October|November|"
    r"December) 20\d\d\b"
)


NOTE_LINK = re.compile(r"notes/[\w.-]+")  # a link to a dated note is how a page points at its history


def user_pages() -> list[Path]:
    return sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]


def test_no_machine_path_in_any_doc():
    pages = sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]
    hits = [
        f"{p.relative_to(ROOT)}:{n + 1}: {line.strip()[:100]}"
        for p in pages
        for n, line in enumerate(p.read_text().splitlines())
        if MACHINE_PATH.search(line)
    ]
    assert not hits, "\n".join(hits)


def test_no_dated_study_log_outside_docs_notes():
    hits = [
        f"{p.relative_to(ROOT)}:{n + 1}: {line.strip()[:100]}"
        for p in user_pages()
        for n, line in enumerate(p.read_text().splitlines())
        if DATED.search(NOTE_LINK.sub("", line))
    ]
    assert not hits, "move it to docs/notes/ (dated) and link it:\n" + "\n".join(hits)


def test_every_note_is_dated_and_linked_from_a_page():
    notes = sorted((ROOT / "docs" / "notes").glob("*.md"))
    assert notes
    linked = "\n".join(p.read_text() for p in user_pages())
    for note in notes:
        assert re.match(r"20\d\d-[01]\d-[0-3]\d-", note.name), note.name
        assert f"notes/{note.name}" in linked, f"{note.name} is linked from no page of docs/ nor the README"


def test_the_checks_catch_what_they_forbid(tmp_path):
    """The detectors themselves: a bare path and a dated declaration are found; <worktree> is not a path."""
    assert MACHINE_PATH.search("bench-compare --against /work/wt/base")
    assert not MACHINE_PATH.search("bench-compare --against <worktree>")
    assert DATED.search("**Declared before the runs of 25 November 2026, 16:54 UTC**")
    assert DATED.search("Run on 2026-11-23")
    assert not DATED.search(NOTE_LINK.sub("", "[notes/2026-11-21-live-bench.md](notes/2026-11-21-live-bench.md)"))
    script = tmp_path / "tool.py"
    script.write_text("import argparse\nif __name__ == '__main__':\n    pass\n")
    assert imports_argparse(script) and runs_as_main(script)


def test_an_old_command_path_says_where_it_moved(capsys):
    """`python -m services.console.measure` (folded into `python -m services.console measure`) used to import and
    exit 0 having done nothing; every old path of docs/commands.md's renamed table now exits 2 naming the new one."""
    import runpy
    import warnings

    import pytest

    moved = moved_modules()
    renamed = (ROOT / "docs" / "commands.md").read_text().split("## Renamed commands")[1]
    assert len(moved) >= 15 and "services.console.measure" in moved, moved
    for module, now in moved.items():
        assert now in renamed.replace("\\|", "|") or now.rsplit(" ", 1)[0] in renamed, (module, now)
        with pytest.raises(SystemExit) as exit_, warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # runpy: the package had imported the module already
            runpy.run_module(module, run_name="__main__")
        assert exit_.value.code == 2 and f"use `{now}`" in capsys.readouterr().err, module
