"""`replay LOG retrain --screen-delay ...`: credit settings scored by the held-out log-likelihood of a person's presses.

The log is a real MCAP file (`LogWriter`) of a simulated person at 2 steps/s who rates each step by the task's rule
after a lognormal lag (median 1.2 s): the matched delay and the learned one must predict the later presses better
than Deep TAMER's 0.2-4 s, which in turn beats a delay that is plainly wrong (2.5-5.5 s)."""

from __future__ import annotations

import io
import json
from contextlib import redirect_stdout

import numpy as np

from common.logs.mcap_log import LogWriter
from common.protocol import Feedback, RunConfig, ShownStep, Step, feedback_key, step_key
from services.replay.heldout import compare_settings, presses_from_log
from services.replay.service import main as replay_main

RUN = "heldout"
TRUE_LAG = "lognorm:0.35,0,1.2"


def write_person_log(path, n_steps: int = 1200, rate: float = 2.0, seed: int = 3) -> int:
    """Steps of a random walker toward a target (info: distance before/after) and one person's presses."""
    import scipy.stats

    rng = np.random.default_rng(seed)
    lag = scipy.stats.lognorm(0.35, 0, 1.2)
    t0 = 1_700_000_000.0
    shown = t0 + np.arange(n_steps) / rate + rng.uniform(0.02, 0.05, n_steps)  # painted a little after the action
    closer = rng.random(n_steps) < 0.5
    presses = sorted((shown[k] + lag.rvs(random_state=rng), k) for k in range(n_steps) if rng.random() < 0.5)
    with LogWriter(path, RunConfig.create(RUN, {"env": "maze"}, t_created=t0)) as w:
        for k in range(n_steps):
            before = 10.0
            info = {"target_distance_before": before, "target_distance_after": before - 1 if closer[k] else before + 1}
            w.write(
                step_key(RUN),
                Step(
                    run=RUN,
                    incarnation="a1",
                    seq=k,
                    t_action=float(shown[k] - 0.02),
                    episode=0,
                    t_in_episode=k,
                    obs=[0.0],
                    action=0,
                    reward=0.0,
                    next_obs=[0.0],
                    terminated=False,
                    truncated=False,
                    weights_version=0,
                    info=info,
                ).encode(),
            )
        for n, (t, k) in enumerate(presses):
            window = [ShownStep(int(j), float(shown[j])) for j in range(n_steps) if t - 6.0 <= shown[j] <= t]
            fb = Feedback(
                run=RUN,
                teacher_id="web-1",
                seq=n,
                t_reaction=float(t),
                value=1 if closer[k] else -1,
                source="console",
                actor="a1",
                shown=window[-64:],
            )
            w.write(feedback_key(RUN, "web-1"), fb.encode())
    return len(presses)


def test_matched_and_learned_delays_predict_held_out_presses_better_than_deep_tamers_and_a_wrong_one(tmp_path):
    log = tmp_path / "session.mcap"
    n = write_person_log(log)
    presses = presses_from_log(log)
    assert len(presses["web-1"]) == n and all(len(p.starts) >= 10 for p in presses["web-1"][20:])
    scores = compare_settings(log, [TRUE_LAG, "learned", "uniform:0.2,4", "uniform:2.5,5.5"], ["onset"])
    by = {s.delay: s for s in scores}
    assert by[TRUE_LAG].scored == n - round(0.7 * n) and by[TRUE_LAG].fitted == round(0.7 * n)
    assert by[TRUE_LAG].mean_loglik > by["uniform:0.2,4"].mean_loglik + 0.05
    assert by["learned"].mean_loglik > by["uniform:0.2,4"].mean_loglik + 0.05
    assert by["uniform:0.2,4"].mean_loglik > by["uniform:2.5,5.5"].mean_loglik + 0.1
    assert abs(by["learned"].estimate["web-1"]["median_s"] - 1.2) < 0.25  # fitted on the first 70% only


def test_the_command_prints_every_setting_best_first_and_refuses_a_log_without_presses(tmp_path):
    log = tmp_path / "session.mcap"
    write_person_log(log, n_steps=300)
    out = io.StringIO()
    with redirect_stdout(out):
        rc = replay_main(
            [
                str(log),
                "retrain",
                "--screen-delay",
                "uniform:0.2,4",
                "--screen-delay",
                "learned",
                "--screen-credit",
                "onset",
                "--screen-credit",
                "interval",
                "--json",
            ]
        )
    assert rc == 0
    rows = json.loads(out.getvalue())
    assert len(rows) == 4 and {(r["delay"], r["credit"]) for r in rows} == {
        (d, c) for d in ("uniform:0.2,4", "learned") for c in ("onset", "interval")
    }
    assert [r["mean_loglik"] for r in rows] == sorted((r["mean_loglik"] for r in rows), reverse=True)
    empty = tmp_path / "empty.mcap"
    with LogWriter(empty, RunConfig.create(RUN, {"env": "maze"}, t_created=1.0)):
        pass
    assert replay_main([str(empty), "retrain", "--screen-delay", "learned"]) == 2
    assert replay_main([str(log), "retrain", "--screen-delay", "nonsense:1"]) == 2


def test_forward_chaining_scores_every_block_but_the_first_by_a_fit_on_the_blocks_before(tmp_path):
    log = tmp_path / "session.mcap"
    n = write_person_log(log, n_steps=600)
    scores = {s.delay: s for s in compare_settings(log, [TRUE_LAG, "uniform:2.5,5.5"], ["onset"], folds=4)}
    first_block = round(n / 4)
    assert scores[TRUE_LAG].scored == n - first_block
    assert scores[TRUE_LAG].fitted == sum(round(k * n / 4) for k in (1, 2, 3))
    assert scores[TRUE_LAG].mean_loglik > scores["uniform:2.5,5.5"].mean_loglik
    assert replay_main([str(log), "retrain", "--screen-delay", "learned", "--folds", "1"]) == 2
