"""The declaration of 28 November 2026 (issue 34 item 1): the confirmatory design, declared before any of its runs.

It follows the declaration of 25 November (experiments/claims.py, which still decides the results committed under
it) and the power analysis of 28 November (docs/notes/2026-11-28-power.md, docs/results/power.json), which sized it.
What is declared here (docs/notes/2026-11-28-declaration.md says what changed and why):

Metric. ln steps is the single primary metric: per trial the mean of ln(steps in the episode) over the test's
episode window, lower is better, MARGIN = ln 1.1 (10% fewer steps per episode, geometric mean). The mean return
per episode is computed and shown beside it (its own Holm within the family, its margins RETURN_MARGIN), and never
decides: a claim's verdict is its ln-steps verdict, so no verdict is "mixed".
  reproduced      Holm-adjusted p < ALPHA = 0.05 (Holm across the family's primary tests)
  not reproduced  some component's 95% interval lies wholly below its margin (greater) or below minus its margin
                  (noninferior)
  inconclusive    otherwise
Robustness (Wilcoxon instead of t, the per-trial median of ln steps) is shown, "fragile" where it flips the
ln-steps decision, never deciding.

Populations. The paper's claims C1-C6 are decided on the paper's population: every maze layout pooled (honest and
misleading alike; the paper describes no class of layouts). Gymnasium's Taxi has no layout classes: all its
trials, as before. The honest-only and misleading-only results are a declared secondary: each primary test is
also run on each class, with the layout-class x method interaction (the effect on honest minus on misleading
layouts; two-sided Welch t-test over the two classes' layout means; bootstrap resampling layouts within each
class), shown, never deciding. D1-D3 are decided on the learned-delay conditions' honest layouts, A1 and M1 on
the misleading layouts (their claims are about a misleading teacher), with the other classes shown.

Tests (experiments/evaluate.py, unchanged). An effect is a linear combination of (condition, arm) metrics paired by
trial (same layout and seed), signed so that positive means "as claimed". Resampling unit: the maze layout is
the cluster (its 2 seeds averaged within it); Gymnasium's Taxi: the seed. Estimate: the mean over trials (every
layout has 2 trials, so the mean of the layouts' means); interval: 95% percentile bootstrap resampling whole
clusters; p: one-sided t-test over the clusters' means (H1: effect > 0; noninferior: effect > -margin). A test of
several effects that must all hold (intersection-union) has p = the largest component p. Holm across the primary
tests of each family: the paper's claims C1-C6; ours D1-D3, A1, M1.

C1-C6: the tests of 25 November (experiments/claims.py, unchanged), decided on every layout pooled.

M1 tests the reliability mechanism: on misleading layouts, high frequency with delay, DQN-TAMER with the
teacher's reliability (`dqn-tamer/trusted`) does better than the paper's DQN-TAMER (`dqn-tamer`): greater, margin
ln 1.1. (On 25 November it was a non-inferiority test against DQN, which DQN-TAMER without the mechanism already
passed: it tested no mechanism.) The old test is shown as a secondary.

D1-D3 (learned delay) are tested against the paper's assumption, lags uniform over 0..2 steps (the new arms
`<algo>/uniform2`, experiments/arms.py; the `<algo>/uniform` arms of 25 November assume 0..6 steps and are not
run under this declaration), and against the true lags (`<algo>/true`): D1 Deep TAMER learned > uniform 0..2,
D2 DQN-TAMER learned > uniform 0..2, D3 learned not worse than the true lags (Deep TAMER, non-inferiority), each
averaged over the 4 observers as the primary (decided as on 25 November), and each observer's effect shown as a
secondary test.

A1 as on 25 November: on misleading layouts the adaptive alpha_h does better than the fixed schedule matched on
its mean alpha_h (`dqn-tamer/matched`).

Expected unsettled, declared before the runs: C1 and A1 (EXPECTED_UNSETTLED). The power analysis found no
candidate size up to 960 layouts x 2 seeds at which two runs agree at least 90% on them: in the later published
run (25 Nov 23:46) their effects lie between 0 and the margin (C1 pooled +0.069 ln steps, A1 +0.011, margin
0.095), where this verdict rule keeps splitting between reproduced, inconclusive and not reproduced. Their
verdicts are reported and marked "expected unsettled"; they are not re-sized or re-tested after the runs.

Size and trials (RUNS), from the power analysis: 480 maze layouts x 2 seeds per layout (every layout 2 seeds),
240 honest and 240 misleading; the learned-delay conditions' honest layouts in proportion, 16 -> 128; Gymnasium's
Taxi 64 seeds (at least 32 required); 100 maze and 200 Taxi episodes; the fixed-task Taxi only when named, as
before. Claims settle only where two runs of this same design agree (issue 34 item 4; the settlement table,
experiments/report_runs.py):
  run 1 (the confirmatory run)  layouts 180-659, seed block 4   `python -m experiments reproduce --replicate 1`
  run 2 (the second run)        layouts 660-1139, seed block 5  `python -m experiments reproduce --replicate 2`
Every layout is fresh (0-179 were used by every earlier run and pilot) and so is every seed (blocks 1-3 and the
pilots' 9000+ were used). The maze generator (common/envs/maze.py) had 180 layouts when this was declared; it
was extended to 1,140 before any run (the stream is prefix-stable: layouts 0-179 stay as they are, pinned in
tests/core/test_layouts.py). `reproduce` refuses a run whose layouts the generator does not have
(experiments/declarations.py, `missing_layouts`).
"""

from __future__ import annotations

from dataclasses import replace

from experiments import claims as before
from experiments.claim_parts import AGENT_NAMES, Claim, Effect, Test, averaged, better
from experiments.conditions import FULL, Scale

ID = "2026-11-28"
METRICS = before.METRICS
"""Computed and shown: ln steps and the return."""
DECIDING = ("ln steps",)
"""The single primary metric: the claim's verdict is its verdict."""
PAPER_POPULATION = "pooled"
EXPECTED_UNSETTLED = ("C1", "A1")
RUN_1 = replace(FULL, layouts=480, reps=2, first_layout=180, seed_block=4, taxi_trials=64, delay_layouts=128)
RUN_2 = replace(RUN_1, first_layout=660, seed_block=5)
RUNS: tuple[Scale, ...] = (RUN_1, RUN_2)
OUTS = ("docs/results/confirm/run-1", "docs/results/confirm/run-2")
"""Where each run writes by default."""
NOT_RUN = ("deep-tamer/uniform", "dqn-tamer/uniform")
"""Arms of the conditions no claim here uses (the 25 November prior over 0..6 steps): not run."""


def _pooled(t: Test) -> Test:
    return replace(t, layouts=PAPER_POPULATION)


def _paper_claims() -> list[Claim]:
    """C1-C6: the tests of 25 November, on every layout pooled."""
    return [
        replace(c, primary=_pooled(c.primary), secondary=tuple(_pooled(t) for t in c.secondary))
        for c in before.CLAIMS
        if c.family == "paper"
    ]


def _delay_claims() -> list[Claim]:
    """D1-D3: the delay learned online, against the paper's uniform 0..2 steps and the true lags, 4 observers."""
    from experiments.conditions import DELAY_CONDITIONS as D

    def pooled(algo: str, good: str, other: str) -> Effect:
        return averaged(
            f"{other} - {good} ({algo}), mean over the 4 observers",
            [better(c, f"{algo}/{good}", f"{algo}/{other}") for c in D],
        )

    def per_observer(algo: str, good: str, other: str, kind: str = "greater") -> tuple[Test, ...]:
        names = AGENT_NAMES[f"{algo}/{good}"], AGENT_NAMES[f"{algo}/{other}"]
        return tuple(
            Test("", f"{c}: {names[0]} vs {names[1]}", (better(c, f"{algo}/{good}", f"{algo}/{other}"),), kind=kind)
            for c in D
        )

    def learned_beats_paper(cid: str, algo: str, name: str) -> Claim:
        return Claim(
            cid,
            "beyond",
            f"{name} with the delay model learned online (per teacher, in seconds on the virtual clock) does better "
            "than with the paper's assumption, lags uniform over 0..2 steps (honest layouts, 4 observers).",
            Test(
                cid,
                f"{name}: learned minus the paper's uniform 0..2 lags, averaged over the 4 observers",
                (pooled(algo, "learned", "uniform2"),),
            ),
            per_observer(algo, "learned", "uniform2"),
        )

    return [
        learned_beats_paper("D1", "deep-tamer", "Deep TAMER"),
        learned_beats_paper("D2", "dqn-tamer", "DQN-TAMER"),
        Claim(
            "D3",
            "beyond",
            "Learning the delay online is not worse than knowing the true distribution "
            "(Deep TAMER; by more than the margin).",
            Test(
                "D3",
                "Deep TAMER: learned vs true lags, averaged over the 4 observers (non-inferiority)",
                (pooled("deep-tamer", "learned", "true"),),
                kind="noninferior",
            ),
            per_observer("deep-tamer", "learned", "true", "noninferior")
            + per_observer("dqn-tamer", "learned", "true", "noninferior")
            + per_observer("deep-tamer", "true", "uniform2")
            + per_observer("dqn-tamer", "true", "uniform2"),
        ),
    ]


def _reliability_claim() -> Claim:
    """M1: the teacher's reliability against the paper's DQN-TAMER, on misleading layouts."""
    hd = "maze-high-delay"
    old = next(c for c in before.CLAIMS if c.cid == "M1")
    return Claim(
        "M1",
        "beyond",
        "With a teacher who is systematically wrong (misleading layouts), DQN-TAMER with the teacher's reliability "
        "does better than the paper's DQN-TAMER.",
        Test(
            "M1",
            "misleading layouts, high frequency with delay: DQN-TAMER with the teacher's reliability does better "
            "than the paper's DQN-TAMER",
            (better(hd, "dqn-tamer/trusted", "dqn-tamer"),),
            "misleading",
        ),
        (old.primary, *old.secondary),  # 25 November's M1 and its secondaries, shown
    )


def _a1() -> Claim:
    """A1 as declared on 25 November."""
    return next(c for c in before.CLAIMS if c.cid == "A1")


CLAIMS: tuple[Claim, ...] = tuple(_paper_claims() + _delay_claims() + [_a1(), _reliability_claim()])
FAMILIES = before.FAMILIES
