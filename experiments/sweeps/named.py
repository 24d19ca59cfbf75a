"""Named grids: sweeps that are not a product of field values, run by the same engine as any sweep.

`paper`: the reproduction. Its cells are the conditions (each a bundle of environment, observer, teacher
rule and layout set: `experiments/conditions.py`) crossed with each condition's own arms, and its trials
follow the reproduction's trial plan (layout and seed of trial k; clusters for resampling). Its results
are evaluated by the pre-registered claims (`experiments/claims.py`, `experiments/evaluate.py`) in
`experiments/reproduce.py`. The slots are (condition, arm, trial); each result is kept under
`cache/<condition>/<arm>/<trial>-<key>.json`, the layout `experiments/trialcache.py` and
`experiments/machines.py` read.
"""

from __future__ import annotations

import os

from experiments.conditions import Condition, Scale, n_trials, trial_spec
from experiments.runner import TrialSpec
from experiments.sweeps.execute import PathOf, Slot


def paper_slots(conds: list[Condition], scale: Scale) -> list[tuple[Slot, TrialSpec]]:
    """Every (condition, arm, trial) of the reproduction with its trial."""
    return [
        ((c.name, arm, k), trial_spec(c, arm, k, scale))
        for c in conds
        for arm in c.arms
        for k in range(n_trials(c, scale))
    ]


def paper_paths(cache_dir: str) -> PathOf:
    def path(slot: Slot, key: str) -> str:
        cond, arm, k = slot
        return os.path.join(cache_dir, cond, arm.replace("/", "-"), f"{k:03d}-{key}.json")

    return path


NAMED = {"paper": (paper_slots, paper_paths)}
