"""Returning people (`--profiles DIR`, services/learner/teacher_delays.py): a named person's learned delay is written
atomically as a small JSON file and the next session starts from it; numbered people are not profiled; a damaged
profile is set aside and counted, never fatal and never overwritten unseen."""

from __future__ import annotations

import json
from typing import cast

import numpy as np
import pytest
import scipy.stats

from common.core.delay_model import LearnedDelay, delay_estimate
from common.protocol import Credit, DelayEstimate
from services.common.config import LearnerConfig
from services.learner.books import delay_message
from services.learner.teacher_delays import Profiles, profiled


def teach(model, lag: float = 1.4, n: int = 120, seed: int = 0) -> None:
    """A person at 2 steps/s who presses `lag` s (+-0.2) after the step they rate, which the rule tells apart."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        starts = np.arange(12) * 0.5
        rated = int(rng.integers(4, 10))
        t = starts[rated] + lag + rng.uniform(-0.2, 0.2)
        pol = np.where(np.arange(12) == rated, 1.0, -1.0)
        ok = starts <= t
        model.observe(float(t), starts[ok], likelihood=np.where(pol[ok] > 0, 0.9, 0.1))


def test_a_named_person_starts_from_their_last_estimate(tmp_path):
    first = Profiles(tmp_path, save_period=0.0)
    alice = first.load("web-alice", delay_estimate("learned"))
    assert isinstance(alice, LearnedDelay) and not first.returning
    assert alice.summary()["median_s"] == pytest.approx(2.1, abs=0.15)
    teach(alice)
    learned = alice.summary()
    assert learned["median_s"] == pytest.approx(1.4, abs=0.2)
    assert first.save({"web-alice": alice}) == 1
    assert first.save({"web-alice": alice}) == 0  # unchanged since: not written again
    stored = json.loads((tmp_path / "web-alice.json").read_text())
    assert "rows" not in stored and len(stored["probs"]) == 60  # a small file: the estimate, not the window
    assert not list(tmp_path.glob(".*.tmp"))  # written whole (services/common/statefiles.py)

    second = Profiles(tmp_path)
    again = second.load("web-alice", delay_estimate("learned"))
    assert second.returning == {"web-alice"}
    assert again.summary()["median_s"] == pytest.approx(learned["median_s"], abs=0.05)
    assert again.summary()["feedbacks"] == learned["feedbacks"]
    assert delay_message(again, True).returning and not delay_message(alice).returning
    bob = second.load("web-bob", delay_estimate("learned"))  # new: the prior
    assert bob.summary()["median_s"] == pytest.approx(2.1, abs=0.15)


def test_numbered_people_and_fixed_delays_leave_no_profile(tmp_path):
    profiles = Profiles(tmp_path, save_period=0.0)
    one = profiles.load("web-1", delay_estimate("learned"))
    teach(one)
    assert not profiled("web-1") and profiled("web-alice") and profiled("web-alice-2b") and not profiled("../x")
    fixed = profiles.load("web-alice", delay_estimate("uniform:0.2,4", "interval"))
    fixed.observe(3.0, [0.0, 0.5, 1.0])
    assert profiles.save({"web-1": one, "web-alice": fixed}) == 0 and not list(tmp_path.iterdir())
    assert delay_message(fixed).median_s == pytest.approx(2.1)
    assert Profiles(None).load("web-alice", one) is one and Profiles(None).save({"web-alice": one}) == 0


@pytest.mark.parametrize(
    "content",
    [
        b"{not json",
        b'{"kind": "learned", "probs": [1, 2]}',
        b"[]",
        b'{"kind": "learned", "probs": [NaN]}',
        b'{"kind": "fixed", "spec": "x"}',
    ],
)
def test_a_damaged_profile_is_set_aside_and_counted(tmp_path, content):
    (tmp_path / "web-alice.json").write_bytes(content)
    profiles = Profiles(tmp_path, save_period=0.0)
    model = profiles.load("web-alice", delay_estimate("learned"))
    assert model.summary()["median_s"] == pytest.approx(2.1, abs=0.15) and profiles.damaged == 1
    assert not profiles.returning
    assert (tmp_path / "web-alice.json.damaged").read_bytes() == content
    teach(model, n=10)
    assert profiles.save({"web-alice": model}) == 1
    assert json.loads((tmp_path / "web-alice.json").read_text())["kind"] == "learned"


def test_the_estimate_sent_to_the_console_is_the_models_density_and_fits_a_credit():
    model = LearnedDelay()
    teach(model, lag=0.9)
    est = delay_message(model)
    edges, probs = model.density()
    assert est.bin_s == pytest.approx(0.1) and len(est.probs) == len(probs) == 60
    assert np.allclose(est.probs, probs, atol=1e-5) and est.median_s == model.summary()["median_s"]
    import dataclasses

    def credit(n: int) -> Credit:
        return cast(
            Credit,
            Credit.from_json_obj(
                {
                    "run": "r",
                    "teacher_id": "web-alice",
                    "seq": 1,
                    "value": 1,
                    "status": "credited",
                    "t_reaction": 1.0,
                    "t_credited": 2.0,
                    "actor": "a",
                    "steps": [{"seq": 10**9 + i, "weight": 1 / 3} for i in range(n)],
                    "lost_mass": 0.0,
                }
            ),
        )

    n = 1
    while len(credit(n + 1).encode()) <= 8192:  # the largest credit that fit before the field
        n += 1
    big = dataclasses.replace(credit(n), delay=est)
    assert cast(Credit, Credit.decode(big.encode())).delay == est
    uniform = delay_message(delay_estimate("uniform:0.2,4", "interval"))
    want = np.diff(scipy.stats.uniform(0.2, 3.8).cdf(np.linspace(0, 6, 61)))
    assert np.allclose(uniform.probs, want, atol=1e-5) and isinstance(uniform, DelayEstimate)


def test_the_learner_and_the_launcher_take_a_profiles_directory(tmp_path):
    from common.config import parse_config
    from services.launcher.config import UpConfig

    assert LearnerConfig(run="r", profiles=str(tmp_path)).profiles == str(tmp_path)
    up = parse_config(UpConfig, ["--teacher", "web", "--profiles", str(tmp_path)])
    assert up.profiles == str(tmp_path)


def test_the_learner_starts_a_named_person_from_their_profile_and_a_checkpoint_remembers_it(tmp_path):
    """LearnerCore: Alice's first press finds her profile (her model starts from it, she is `returning`), a restored
    checkpoint keeps both; web-1 starts from the prior."""
    from common.core.task import Task
    from common.envs import make_env
    from common.protocol import Feedback, ShownStep, Step
    from services.learner.core import LearnerCore

    earlier = LearnedDelay()
    teach(earlier, lag=0.8)
    (tmp_path / "web-alice.json").write_text(json.dumps(earlier.state(window=False)))
    core = LearnerCore(LearnerConfig(run="r", task=Task(env="maze"), profiles=str(tmp_path)))
    env, _ = make_env("maze", 0)
    obs, t0 = env.reset(seed=0)[0], 1000.0
    shown = [ShownStep(k, t0 + 0.5 * k + 0.05) for k in range(12)]
    for n, who in enumerate(("web-alice", "web-1")):
        core.on_feedback(
            Feedback(
                run="r",
                teacher_id=who,
                seq=0,
                t_reaction=t0 + 5.8 + n * 0.1,
                value=1,
                source="key",
                actor="act-1",
                shown=shown,
            )
        )
    for k in range(12):
        nxt, r, term, _, _ = env.step(k % 4)
        core.on_step(
            Step(
                run="r",
                incarnation="act-1",
                seq=k,
                t_action=t0 + 0.5 * k,
                episode=0,
                t_in_episode=k,
                obs=obs.tolist(),
                action=k % 4,
                reward=float(r),
                next_obs=nxt.tolist(),
                terminated=bool(term),
                truncated=False,
                weights_version=k,
                info={},
            )
        )
        obs = nxt
    summary = core.delay_summary()
    assert core.profiles.returning == {"web-alice"}
    assert summary["web-alice"]["median_s"] == pytest.approx(earlier.summary()["median_s"], abs=0.15)
    assert summary["web-alice"]["feedbacks"] == earlier.feedbacks + 1
    assert summary["web-1"]["median_s"] == pytest.approx(2.1, abs=0.2)
    core.take_entries()
    tensors, meta = core.snapshot()
    again = LearnerCore(LearnerConfig(run="r", task=Task(env="maze"), profiles=str(tmp_path)))
    again.restore(tensors, json.loads(json.dumps(meta)))
    assert again.profiles.returning == {"web-alice"} and again.delay_summary() == summary
    assert again.profiles.save(again.delays, force=True) == 1  # Alice's estimate moved; web-1 has no profile
    assert json.loads((tmp_path / "web-alice.json").read_text())["feedbacks"] == earlier.feedbacks + 1
