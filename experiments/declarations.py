"""The declarations, by id: each says which claims a run decides and how, on which trials, before its runs.

A run records the declaration it runs under (timing.json's `declaration`, and claims.json's for every declaration
after the first); `python -m experiments report --from TABLE` decides under the one its run recorded, and a table
from before declarations were versioned (no `declaration` recorded) under 25 November's, the one it was run under.
`python -m experiments reproduce` runs the newest unless `--declaration ID` names another.

  2026-11-25  experiments/claims.py: ln steps and return co-primary, honest layouts primary, 60 layouts x 1 seed
  2026-11-28  experiments/claims_2026_11_28.py: ln steps alone decides, C1-C6 on every layout pooled, M1 against
              the paper's DQN-TAMER, D1-D3 against the paper's uniform 0..2 lags, 480 layouts x 2 seeds, two runs
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from common.envs.maze import LAYOUT_COUNT, layout_kind
from experiments import claims as first, claims_2026_11_28 as confirm
from experiments.claim_parts import Claim
from experiments.conditions import FULL, Condition, Scale


@dataclass(frozen=True)
class Declaration:
    id: str
    module: str
    """Where its design is written (the module's docstring) and its claims declared."""
    claims: tuple[Claim, ...]
    families: tuple[str, ...]
    """Holm families, in report order."""
    metrics: tuple[str, ...]
    """Computed and shown."""
    deciding: tuple[str, ...]
    """The metrics whose verdicts make the claim's: their common verdict, or mixed where they differ."""
    runs: tuple[Scale, ...]
    """The declared runs (replicate 1, 2, ...): their layouts, seeds and size."""
    outs: tuple[str, ...]
    """Each run's default output directory."""
    not_run: tuple[str, ...] = ()
    """Arms of the conditions that this declaration's runs leave out."""
    expected_unsettled: tuple[str, ...] = ()
    """Claims declared before the runs as expected not to settle (two runs unlikely to agree)."""

    def scale(self, replicate: int) -> Scale:
        if not 1 <= replicate <= len(self.runs):
            raise ValueError(f"declaration {self.id} declares {len(self.runs)} run(s); no replicate {replicate}")
        return self.runs[replicate - 1]

    def conditions(self, conds: list[Condition]) -> list[Condition]:
        """The conditions with the arms this declaration runs."""
        return [replace(c, arms=tuple(a for a in c.arms if a not in self.not_run)) for c in conds]


FIRST = Declaration(
    "2026-11-25",
    "experiments/claims.py",
    first.CLAIMS,
    first.FAMILIES,
    first.METRICS,
    first.METRICS,
    (FULL,),
    ("docs/results",),
    not_run=("deep-tamer/uniform2", "dqn-tamer/uniform2"),
)
CONFIRM = Declaration(
    confirm.ID,
    "experiments/claims_2026_11_28.py",
    confirm.CLAIMS,
    confirm.FAMILIES,
    confirm.METRICS,
    confirm.DECIDING,
    confirm.RUNS,
    confirm.OUTS,
    not_run=confirm.NOT_RUN,
    expected_unsettled=confirm.EXPECTED_UNSETTLED,
)
DECLARATIONS = {d.id: d for d in (FIRST, CONFIRM)}
NEWEST = CONFIRM.id
UNRECORDED = FIRST.id
"""The declaration of a run that recorded none: every run before declarations were versioned ran under it."""


def get(did: str | None = None) -> Declaration:
    """The declaration `did` (None: the newest)."""
    did = did or NEWEST
    if did not in DECLARATIONS:
        raise ValueError(f"unknown declaration {did!r}; declared: {', '.join(DECLARATIONS)}")
    return DECLARATIONS[did]


def of_run(record: dict) -> Declaration:
    """The declaration a run recorded (its timing.json or claims.json); 25 November's where it recorded none."""
    return get(record.get("declaration") or UNRECORDED)


def missing_layouts(scale: Scale) -> str | None:
    """Why the maze generator cannot supply the scale's layouts, or None where it can."""
    last = scale.first_layout + scale.layouts - 1
    honest = [L for L in range(scale.first_layout, LAYOUT_COUNT) if layout_kind(L) == "honest"]
    if last < LAYOUT_COUNT and len(honest) >= scale.delay_layouts:
        return None
    return (
        f"the run needs maze layouts {scale.first_layout}-{max(last, scale.first_layout + 2 * scale.delay_layouts - 2)}"
        f" and the generator (common/envs/maze.py) has 0-{LAYOUT_COUNT - 1}: it must be extended "
        "(LAYOUT_KIND_COUNT) before this run can start"
    )
