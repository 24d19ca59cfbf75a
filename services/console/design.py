"""A declared browser comparison, read from a data file (`services/console/designs/<name>.yaml`).

A design is committed before any of its runs; `python -m services.console compare --design NAME` runs it and
decides it by the test the file declares. The file holds what is compared (arms, people, pairs of maze layout and
seed), the measure, and the multiplicity rule:

    looks  the one primary test at alpha / looks (Bonferroni over the designs that tested the same claim)
    holm   one test per declared person (`tests_by: person`, over all its pairs, honest and misleading layouts
           alike) or per person and layout kind (`tests_by: person_kind`), Holm's step-down at alpha over them all

A design names the one commit all its runs come from (`commit: TAG`, before its first run); compare refuses to
run it from any other checkout or from a tree with uncommitted changes (`checkout_key`).

Older designs have one person, the uniform 0.3-1.5 s lag of `static/scripted_person.js` (`people` absent).
"""

from __future__ import annotations

import hashlib
import subprocess
import sys
from dataclasses import dataclass, field, fields
from pathlib import Path

import yaml

from common.envs.maze import LAYOUT_COUNT, layout_kind
from services.console.lags import check_lag_spec

DESIGN_DIR = Path(__file__).resolve().parent / "designs"
ROOT = DESIGN_DIR.parents[2]
MEASURES = ("first_good", "goals")
MULTIPLICITY = ("looks", "holm")
TESTS_BY = ("person", "person_kind")


@dataclass(frozen=True)
class Arm:
    name: str
    algo: str
    screen_delay: str = "uniform:0.2,4"
    screen_credit: str = "interval"


@dataclass(frozen=True)
class Design:
    """What is compared, fixed before the runs."""

    name: str
    pairs: tuple[tuple[int, int], ...]
    arms: tuple[Arm, ...]
    primary: tuple[str, str]  # the test is first minus second > 0 (fewer episodes for the second)
    summary: str = ""
    episodes: int = 10
    rate: float = 2.0
    episode_steps: int = 200  # bounds a run's wall time (an uncut maze episode may take 1000 steps = 500 s)
    good_factor: float = 2.0
    alpha: float = 0.05
    measure: str = "first_good"
    """first_good: the first episode within good_factor x the shortest path (never = episodes + 1); goals: the
    episode in which the agent reached the goal for the `goals`-th time (short of it: episodes + goals missing)."""
    goals: int = 10
    looks: int = 1
    """Designs tested so far for the same claim, this one included: with `looks`, the verdict is at alpha / looks."""
    multiplicity: str = "looks"
    tests_by: str = "person_kind"
    people: dict[str, str] = field(default_factory=dict)
    """Scripted people by name: their lag shape (services/console/lags.py); empty = uniform 0.3-1.5 s."""
    p_press: float = 0.5
    commit: str = ""
    """The one commit every run of the design comes from (a git tag, named before the first run): compare refuses
    any other checkout, or a tree with uncommitted changes. Empty in the designs declared before issue 35, whose
    runs are keyed by the checkout's commit (a dirty tree's as COMMIT-dirty-HASH of its changes)."""

    def tests(self) -> list[tuple[str | None, str | None]]:
        """The declared tests: (person, layout kind) for holm; one (None, None) test over every pair for looks."""
        if self.multiplicity == "looks":
            return [(None, None)]
        if self.tests_by == "person":
            return [(person, None) for person in self.people]
        return [(person, kind) for person in self.people for kind in self.kinds()]

    def kinds(self) -> list[str]:
        return sorted({layout_kind(lay) for lay, _ in self.pairs})

    def persons(self) -> list[str | None]:
        return list(self.people) or [None]


def _check(d: Design) -> Design:
    if d.measure not in MEASURES or d.multiplicity not in MULTIPLICITY or d.tests_by not in TESTS_BY:
        raise ValueError(
            f"design {d.name}: measure in {MEASURES}, multiplicity in {MULTIPLICITY}, tests_by in {TESTS_BY}"
        )
    names = [a.name for a in d.arms]
    if len(set(names)) != len(names) or not set(d.primary) <= set(names):
        raise ValueError(f"design {d.name}: arm names must be distinct and include the primary {d.primary}")
    if len(set(d.pairs)) != len(d.pairs) or not all(0 <= lay < LAYOUT_COUNT for lay, _ in d.pairs):
        raise ValueError(f"design {d.name}: pairs must be distinct, layouts in 0..{LAYOUT_COUNT - 1}")
    if d.multiplicity == "holm" and not d.people:
        raise ValueError(f"design {d.name}: holm tests one hypothesis per declared person")
    for spec in d.people.values():
        check_lag_spec(spec)
    return d


def design_from_dict(raw: dict) -> Design:
    known = {f.name for f in fields(Design)}
    unknown = set(raw) - known
    if unknown:
        raise ValueError(f"design {raw.get('name')}: unknown fields {sorted(unknown)}")
    arms = tuple(Arm(**a) for a in raw["arms"])
    pairs = tuple((int(lay), int(s)) for lay, s in raw["pairs"])
    return _check(
        Design(
            **{
                **raw,
                "arms": arms,
                "pairs": pairs,
                "primary": tuple(raw["primary"]),
                "people": dict(raw.get("people") or {}),
            }
        )
    )


def load_design(path: Path) -> Design:
    design = design_from_dict(yaml.safe_load(path.read_text()))
    if design.name != path.stem:
        raise ValueError(f"{path}: name {design.name!r} differs from the file's")
    return design


def load_designs(directory: Path = DESIGN_DIR) -> dict[str, Design]:
    """Every declared design, in the order they were declared (`order` in the directory's index.yaml)."""
    order = yaml.safe_load((directory / "index.yaml").read_text())["order"]
    designs = {name: load_design(directory / f"{name}.yaml") for name in order}
    extra = {p.stem for p in directory.glob("*.yaml")} - set(order) - {"index"}
    if extra:
        raise ValueError(f"{directory}: designs not in index.yaml's order: {sorted(extra)}")
    return designs


def _git(root: Path, *args: str) -> str:
    done = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, check=False)
    if done.returncode:
        raise ValueError(f"git {' '.join(args)} in {root}: {done.stderr.strip() or done.returncode}")
    return done.stdout


def code_key(root: Path = ROOT) -> tuple[str, bool]:
    """(key, dirty) of the code in the checkout at `root`: its commit, or, where files differ from it (changed,
    staged or untracked and not ignored), `COMMIT-dirty-HASH` with a hash of those changes, so that a dirty tree
    never passes for its commit and its runs are kept for that exact set of changes only."""
    head = _git(root, "rev-parse", "HEAD").strip()
    status = _git(root, "status", "--porcelain", "--untracked-files=all")
    if not status:
        return head, False
    digest = hashlib.sha256(_git(root, "diff", "HEAD", "--binary").encode())
    for line in sorted(status.splitlines()):
        if line.startswith("??"):
            path = root / line[3:]
            digest.update(line.encode() + (path.read_bytes() if path.is_file() else b""))
    return f"{head}-dirty-{digest.hexdigest()[:12]}", True


def checkout_key(design: Design, root: Path = ROOT) -> str:
    """The key of this checkout's runs of `design`; a ValueError saying why it may not run them, where the design
    names its commit (`commit:` in its file) and the checkout is another commit or has uncommitted changes."""
    key, dirty = code_key(root)
    if not design.commit:
        if dirty:
            print(
                f"[compare] design {design.name} names no commit and this tree has uncommitted changes: its runs "
                f"are keyed {key}, kept for exactly these changes, never counted as the commit's",
                file=sys.stderr,
            )
        return key
    try:
        declared = _git(root, "rev-parse", "--verify", "--quiet", f"{design.commit}^{{commit}}").strip()
    except ValueError:
        raise ValueError(
            f"design {design.name} runs on commit {design.commit}, which this checkout does not have (git fetch --tags)"
        ) from None
    if key.split("-dirty-")[0] != declared:
        raise ValueError(
            f"design {design.name} runs on commit {design.commit} ({declared[:12]}) only; this "
            f"checkout is {key[:12]}: git checkout {design.commit}"
        )
    if dirty:
        raise ValueError(
            f"design {design.name} runs on commit {design.commit} only, and this tree has uncommitted "
            f"changes, so it is not that commit (git status): commit or stash them"
        )
    return key
