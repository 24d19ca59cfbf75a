"""The reproduction pipeline: cached resume after an interruption, report generation, CLI wiring."""
import dataclasses
import json
import os

import numpy as np
import pytest

from experiments import reproduce as rep
from experiments.conditions import CONDITIONS, BY_NAME, trial_spec


class Stop(Exception):
    pass


def tiny(names=("maze-high-nodelay", "maze-high-delay"), episodes=3):
    return [dataclasses.replace(BY_NAME[n], episodes=episodes) for n in names]


def returns_of(out, conds, trials):
    cached, todo, _ = rep.plan(conds, trials, os.path.join(out, "cache"))
    assert not todo
    return {k: v["return"] for k, v in cached.items()}


def test_interrupted_sweep_resumes_with_only_the_missing_trials(tmp_path, monkeypatch):
    conds, trials = tiny(), 2
    full = tmp_path / "full"
    rep.reproduce(conds, trials, str(full), workers=1, progress=False, n_boot=50)
    reference = returns_of(str(full), conds, trials)

    out = tmp_path / "resumed"

    def interrupt(done, total):
        if done >= 5:
            raise Stop

    with pytest.raises(Stop):
        rep.reproduce(conds, trials, str(out), workers=1, progress=False, on_progress=interrupt, n_boot=50)
    cached, todo, _ = rep.plan(conds, trials, str(out / "cache"))
    assert len(cached) >= 5 and todo  # some finished and were kept, some are missing

    ran = []
    real = rep.run_trials

    def spy(specs, **kw):
        ran.extend(specs)
        return real(specs, **kw)

    monkeypatch.setattr(rep, "run_trials", spy)
    missing = {t.key for t in todo}
    stats = rep.reproduce(conds, trials, str(out), workers=1, progress=False, n_boot=50)
    assert {rep.trial_key(s) for s in ran} == missing and len(ran) == len(missing)
    assert stats.trials_run == sum(len(t.slots) for t in todo)
    assert returns_of(str(out), conds, trials) == reference

    ran.clear()
    timing_before = json.loads((out / "timing.json").read_text())
    again = rep.reproduce(conds, trials, str(out), workers=1, progress=False, n_boot=50)
    assert ran == [] and again.trials_run == 0  # a second run only re-plots
    timing_after = json.loads((out / "timing.json").read_text())
    assert timing_after["total_s"] == timing_before["total_s"] and timing_after["replot_s"] > 0


def test_dqn_trials_are_shared_between_conditions_that_differ_only_in_the_observer(tmp_path):
    conds = tiny()
    stats = rep.reproduce(conds, 2, str(tmp_path), workers=1, progress=False, n_boot=50)
    assert stats.trials_shared == 2  # DQN's 2 trials of the second condition
    a = json.load(open(next((tmp_path / "cache" / "maze-high-nodelay" / "dqn").glob("000-*.json"))))
    b = json.load(open(next((tmp_path / "cache" / "maze-high-delay" / "dqn").glob("000-*.json"))))
    assert a == b
    # and it is not a shortcut: running it under the other observer gives the same numbers
    res = rep.run_trials([trial_spec(conds[1], "dqn", 0, 3)])[0]
    assert list(res.returns) == b["return"]


def test_report_outputs(tmp_path):
    conds = tiny(("maze-stop", "maze-flip"), episodes=3)
    conds = [dataclasses.replace(c, observer=dataclasses.replace(c.observer, stop_episode=1)
                                 if c.observer.stop_episode is not None else c.observer) for c in conds]
    rep.reproduce(conds, 3, str(tmp_path), workers=1, progress=False, n_boot=50, argv=["reproduce", "--test"])
    for c in conds:
        png = tmp_path / f"{c.name}.png"
        assert png.stat().st_size > 5000
    claims = json.loads((tmp_path / "claims.json").read_text())
    assert set(claims["claims"]) == {"C1", "C2", "C3", "C4", "C5", "C6"}
    assert claims["claims"]["C1"]["verdict"] == "not evaluated"  # its conditions were not run
    assert claims["claims"]["C6"]["verdict"] in ("reproduced", "not reproduced", "inconclusive")
    timing = json.loads((tmp_path / "timing.json").read_text())
    assert timing["trials"] == 2 * 4 * 3 and timing["total_s"] > 0 and timing["trials_per_s"] > 0
    assert set(timing["conditions"]) == {c.name for c in conds}
    report = (tmp_path / "REPORT.md").read_text()
    assert "| C6 | **" in report and "maze-flip.png" in report and "python -m experiments reproduce --test" in report
    assert (tmp_path / ".gitignore").read_text().strip() == "cache/"
    with np.load(tmp_path / "curves.npz") as z:
        assert z["maze-flip/dqn-tamer"].shape == (3, 3)


def test_every_condition_has_all_four_agents_and_thirty_distinct_trials():
    assert len(CONDITIONS) == 8
    for c in CONDITIONS:
        specs = [trial_spec(c, "dqn-tamer", k) for k in range(30)]
        assert len({(s.layout, s.seed) for s in specs}) == 30
        if c.env.startswith("maze"):
            assert sorted({s.layout for s in specs}) == list(range(10))
