"""The reproduction pipeline: cached resume after an interruption, report generation, trial seeds."""

import collections
import dataclasses
import json
import os

import pytest

from experiments import reproduce as rep
from experiments import trialcache
from experiments.sweeps import execute
from experiments.conditions import BY_NAME, CONDITIONS, FULL, Scale, n_trials, trial_spec

TINY = Scale(
    layouts=4,
    reps=1,
    maze_episodes=3,
    taxi_episodes=2,
    taxi_random_episodes=2,
    taxi_trials=2,
    first_layout=0,
    seed_block=1,
)  # development layouts and seeds, never a deciding trial


class Stop(Exception):
    pass


def tiny(names=("maze-high-nodelay", "maze-low-nodelay")):
    return [BY_NAME[n] for n in names]


def returns_of(out, conds):
    cached, todo, _ = trialcache.plan(conds, TINY, os.path.join(out, "cache"))
    assert not todo
    return {k: v["return"] for k, v in cached.items()}


def test_interrupted_sweep_resumes_with_only_the_missing_trials(tmp_path, monkeypatch):
    conds = tiny()
    full = tmp_path / "full"
    full.mkdir()
    (full / "claims.json").write_text(json.dumps({"claims": {"C1": {"verdict": "inconclusive"}}}))  # an older run's
    rep.reproduce(conds, TINY, str(full), workers=1, progress=False, n_boot=50)
    reference = returns_of(str(full), conds)
    assert json.loads((full / "claims.json").read_text())["previous"] == {"C1": "inconclusive"}

    out = tmp_path / "resumed"

    def interrupt(done, total):
        if done >= 5:
            raise Stop

    with pytest.raises(Stop):
        rep.reproduce(conds, TINY, str(out), workers=1, progress=False, on_progress=interrupt, n_boot=50)
    cached, todo, _ = trialcache.plan(conds, TINY, str(out / "cache"))
    assert len(cached) >= 5 and todo

    ran = []
    real = execute.run_trials

    def spy(specs, **kw):
        ran.extend(specs)
        return real(specs, **kw)

    monkeypatch.setattr(execute, "run_trials", spy)
    missing = {t.key for t in todo}
    # the report of this run's first part (an `--only` part leaves one): its verdicts are not a previous run's
    (out / "claims.json").write_text(json.dumps({"claims": {"C1": {"verdict": "not evaluated"}}, "previous": {}}))
    stats = rep.reproduce(conds, TINY, str(out), workers=1, progress=False, n_boot=50)
    assert json.loads((out / "claims.json").read_text())["previous"] == {}
    assert {trialcache.trial_key(s) for s in ran} == missing and len(ran) == len(missing)
    assert stats.trials_run == sum(len(t.slots) for t in todo)
    assert returns_of(str(out), conds) == reference

    resumed = json.loads((out / "timing.json").read_text())
    assert not resumed["from_scratch"] and resumed["trials_cached"] >= 5  # a resumed run is no scratch timing
    assert "NOT a from-scratch timing" in (out / "REPORT.md").read_text()

    ran.clear()
    scratch = json.loads((full / "timing.json").read_text())
    assert scratch["from_scratch"] and scratch["last_from_scratch"]["total_s"] == scratch["total_s"]
    again = rep.reproduce(conds, TINY, str(full), workers=1, progress=False, n_boot=50)
    assert ran == [] and again.trials_run == 0  # a second run only re-plots
    assert json.loads((full / "claims.json").read_text())["previous"] == {"C1": "inconclusive"}  # kept by a re-plot
    timing_after = json.loads((full / "timing.json").read_text())
    assert timing_after["trials_cached"] == timing_after["trials"] and not timing_after["from_scratch"]
    assert timing_after["last_from_scratch"] == scratch["last_from_scratch"]  # the scratch figure is kept
    report = (full / "REPORT.md").read_text()
    assert "NOT a from-scratch timing" in report and "The last from-scratch run" in report


def test_dqn_trials_are_shared_between_observers_and_teacher_rules(tmp_path):
    conds = tiny(("maze-high-nodelay", "maze-sp-high-delay"))
    stats = rep.reproduce(conds, TINY, str(tmp_path), workers=1, progress=False, n_boot=50)
    assert stats.trials_shared == 4  # DQN's 4 trials of the second condition
    a = json.load(open(next((tmp_path / "cache" / "maze-high-nodelay" / "dqn").glob("000-*.json"))))
    b = json.load(open(next((tmp_path / "cache" / "maze-sp-high-delay" / "dqn").glob("000-*.json"))))
    assert a == b
    res = execute.run_trials([trial_spec(conds[1], "dqn", 0, TINY)])[0]
    assert list(res.returns) == b["return"]


def test_report_outputs(tmp_path):
    conds = tiny(("maze-flip", "maze-high-delay"))
    rep.reproduce(
        conds,
        TINY,
        str(tmp_path),
        workers=1,
        progress=False,
        n_boot=50,
        argv=["reproduce", "--test"],
        declaration="2026-11-25",  # its form: two co-primary metrics, honest layouts (the newest: test_declarations)
    )
    for c in conds:
        assert (tmp_path / f"{c.name}.png").stat().st_size > 5000
    assert (tmp_path / "who-decides.png").stat().st_size > 5000
    claims = json.loads((tmp_path / "claims.json").read_text())
    assert claims["claims"]["C1"]["verdict"] == "not evaluated"  # its conditions were not run
    assert claims["claims"]["C6"]["verdict"] in ("reproduced", "not reproduced", "inconclusive")
    assert set(claims["panels"]["maze-flip"]) == {"pooled", "honest", "misleading"}
    timing = json.loads((tmp_path / "timing.json").read_text())
    assert timing["trials"] == 4 * 4 + 7 * 4 and timing["total_s"] > 0
    report = (tmp_path / "REPORT.md").read_text()
    assert "| C6 | **" in report and "maze-flip.png" in report and "python -m experiments reproduce --test" in report
    assert "## Who decides" in report and "Holm" in report
    c6 = claims["claims"]["C6"]
    assert c6["layouts"] == "honest" and set(c6["metrics"]) == {"ln steps", "return"}
    assert "Layout class x method" in report and "| honest (primary) | return |" in report
    assert (tmp_path / ".gitignore").read_text().strip() == "cache/"


def test_trial_seeds_come_from_layout_and_repetition():
    for c in CONDITIONS:
        n = n_trials(c, FULL)
        specs = [trial_spec(c, c.arms[-1], k) for k in range(n)]
        assert len({s.seed for s in specs}) == n  # no two trials share streams
        if c.env.startswith("maze"):
            layouts = {s.layout for s in specs}
            assert layouts == (set(range(120, 152, 2)) if c.layouts == "honest" else set(range(120, 180)))
    # the same (layout, repetition) is the same trial in every condition of a layout set
    a, b = trial_spec(BY_NAME["maze-high-delay"], "dqn", 7), trial_spec(BY_NAME["maze-flip"], "dqn", 7)
    assert (a.layout, a.seed) == (b.layout, b.seed)
    bigger = dataclasses.replace(FULL, reps=2)
    assert trial_spec(BY_NAME["maze-flip"], "dqn", 67, bigger).layout == 127  # repetition 1 of the 8th layout
    assert trial_spec(BY_NAME["maze-flip"], "dqn", 67, bigger).seed != a.seed


def test_the_deciding_trials_are_fresh():
    """Layouts 120-179 and seed block 3: no layout and no seed of an earlier run (layouts 0-119, blocks 1 and 2,
    up to 3 repetitions) or of a pilot (seeds 9000-9999) is a deciding trial's."""
    from experiments.conditions import QUICK, trial_layout, trial_seed

    old = {trial_seed(L, r, b) for L in range(120) for r in range(3) for b in (1, 2)} | set(range(9000, 10000))
    for c in CONDITIONS:
        specs = [trial_spec(c, c.arms[-1], k) for k in range(n_trials(c, FULL))]
        assert not {s.seed for s in specs} & old, c.name
        if not c.is_taxi:
            assert min(s.layout for s in specs) >= 120, c.name
            assert max(trial_layout(c, QUICK, k)[0] for k in range(n_trials(c, QUICK))) < 60  # --quick: old ones


def test_machines_comparison_of_identical_runs_finds_no_difference(tmp_path):
    from experiments import machines

    conds = tiny(("maze-high-delay",))
    rep.reproduce(conds, TINY, str(tmp_path / "a"), workers=1, progress=False, n_boot=50)
    rep.reproduce(conds, TINY, str(tmp_path / "b"), workers=1, progress=False, n_boot=50)
    out = machines.compare(str(tmp_path / "a"), str(tmp_path / "b"), n_boot=50)
    assert sum(r["trials"] for r in out["rows"]) == 7 * 4 and sum(r["differ"] for r in out["rows"]) == 0
    assert out["changed"] == {} and "no verdict changes" in out["summary"]


def test_full_run_jobs_are_small_longest_first_and_never_mix_batch_groups(tmp_path):
    """The full reproduction's trials are cut into about 4 jobs per worker, handed out longest first, each
    job one batch group (same environment family and structural agent settings), every trial once."""
    _, todo, _ = trialcache.plan(list(CONDITIONS), FULL, str(tmp_path / "cache"))
    jobs = trialcache.make_jobs(todo, workers=2)
    costs = [trialcache.job_cost(j) for j in jobs]
    assert costs == sorted(costs, reverse=True)
    assert sorted(t.key for j in jobs for t in j) == sorted(t.key for t in todo)
    assert all(len({trialcache._batch_group(t.spec) for t in j}) == 1 for j in jobs)
    assert 6 <= len(jobs) <= 14 and max(costs) <= sum(costs) / 2 / 3  # no job is more than a third of a worker's share
    # a family whose trials differ in a structural setting (replay size) is never batched together
    mixed = [
        dataclasses.replace(
            t, spec=dataclasses.replace(t.spec, agent=dataclasses.replace(t.spec.agent, replay_size=50_000))
        )
        if k % 2
        else t
        for k, t in enumerate(todo)
    ]
    assert all(len({t.spec.agent.replay_size for t in j}) == 1 for j in trialcache.make_jobs(mixed, workers=2))
    # one worker: one job per batch group, unless the group is larger than its family's MAX_PART_TRIALS
    groups = collections.Counter(trialcache._batch_group(t.spec) for t in todo)
    cap = trialcache.MAX_PART_TRIALS
    assert len(trialcache.make_jobs(todo, workers=1)) == sum(-(-n // cap.get(g[0], n)) for g, n in groups.items())


def test_a_large_maze_group_is_cut_into_parts_of_at_most_max_part_trials(tmp_path, monkeypatch):
    """A Maze batch stops paying per trial-step above about 1,000 trials (and holds its replay): the declaration of
    28 November's 30,000 Maze trials are cut into parts of at most MAX_PART_TRIALS, each trial once."""
    monkeypatch.setitem(trialcache.MAX_PART_TRIALS, "maze", 5)
    _, todo, _ = trialcache.plan([BY_NAME["maze-high-delay"]], TINY, str(tmp_path / "cache"))
    jobs = trialcache.make_jobs(todo, workers=2)
    assert len(todo) > 10 and max(len(j) for j in jobs) <= 5 and len(jobs) == -(-len(todo) // 5)
    assert sorted(t.key for j in jobs for t in j) == sorted(t.key for t in todo)


def test_gymnasium_taxi_runs_its_own_episode_count():
    """Gymnasium's Taxi (random passenger and destination) runs REPRO_TAXI_RANDOM_EPISODES, the fixed task
    REPRO_TAXI_EPISODES, the Maze REPRO_MAZE_EPISODES (declared in experiments/conditions.py)."""
    from experiments.conditions import REPRO_MAZE_EPISODES, REPRO_TAXI_EPISODES, REPRO_TAXI_RANDOM_EPISODES

    assert trial_spec(BY_NAME["taxi-stop"], "dqn", 0, FULL).episodes == REPRO_TAXI_RANDOM_EPISODES == 200
    assert trial_spec(BY_NAME["taxi-fixed-stop"], "dqn", 0, FULL).episodes == REPRO_TAXI_EPISODES
    assert trial_spec(BY_NAME["maze-stop"], "dqn", 0, FULL).episodes == REPRO_MAZE_EPISODES
    assert trial_spec(BY_NAME["taxi-stop"], "dqn", 0, TINY).episodes == 2


def test_a_small_lone_group_is_still_split_over_the_workers(tmp_path):
    """Fewer Maze trials than MIN_PART_TRIALS per worker (a benchmark): still one part per worker."""
    conds = [BY_NAME["maze-high-delay"]]
    _, todo, _ = trialcache.plan(conds, TINY, str(tmp_path / "cache"))
    jobs = trialcache.make_jobs(todo, workers=2)
    assert len(jobs) == 2 and sorted(t.key for j in jobs for t in j) == sorted(t.key for t in todo)
