"""The services' pure parts: step clock, learner core (hold rule, credit, determinism), teacher timing."""

from __future__ import annotations

import dataclasses
from typing import Any, cast

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.envs import make_env
from common.core.observer import ObserverConfig, SimulatedObserver
from common.protocol import Feedback, Step
from common.core.seeding import derive_seed
from common.core.task import Task
from services.common.config import LearnerConfig, TeacherConfig
from services.learner.books import StepClock
from services.common.config import learner_config_from_record
from services.learner.core import LearnerCore
from services.teacher.oracle import OracleTeacher

from .live import actor_credentials

RUN = "t"


def make_steps(n: int, times, seed: int = 0, incarnation: str = "actor-1") -> list[Step]:
    """n maze steps with random actions, stamped with `times` (one per step)."""
    env, _ = make_env("maze", 0)
    rng = np.random.default_rng(seed)
    obs = env.reset(seed=seed)[0]
    out, episode, t_in = [], 0, 0
    for k in range(n):
        a = int(rng.integers(4))
        nxt, r, term, trunc, info = env.step(a)
        out.append(
            Step(
                run=RUN,
                incarnation=incarnation,
                seq=k,
                t_action=float(times[k]),
                episode=episode,
                t_in_episode=t_in,
                obs=obs.tolist(),
                action=a,
                reward=float(r),
                next_obs=nxt.tolist(),
                terminated=bool(term),
                truncated=bool(trunc),
                weights_version=0,
                info={k_: float(v) for k_, v in info.items()},
            )
        )
        obs, t_in = nxt, t_in + 1
        if term or trunc:
            obs, episode, t_in = env.reset()[0], episode + 1, 0
    return out


def fb(seq: int, t: float, value: int = 1, teacher: str = "oracle") -> Feedback:
    return Feedback(run=RUN, teacher_id=teacher, seq=seq, t_reaction=float(t), value=value, source="oracle")


# -- step clock ---------------------------------------------------------------------------------------------------


def test_step_clock_places_times_between_actions():
    c = StepClock(8)
    for k, t in enumerate([10.0, 10.5, 12.0]):
        c.push(k, t)
    assert c.to_steps(10.25) == pytest.approx(0.5)
    assert c.to_steps(11.25) == pytest.approx(1.5)
    assert not c.placeable(12.0) and not c.placeable(13.0)
    assert c.to_steps(9.0) == -1.0  # before everything held
    assert c.to_wall(1.5) == pytest.approx(11.25)
    assert c.to_wall(2.5) is None  # step 3 not seen yet
    c.push(5, 13.0)  # a gap restarts the clock
    assert len(c) == 1 and c.oldest_index == 5


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(1e-3, 2.0), min_size=3, max_size=20), st.floats(0.01, 0.99))
def test_step_clock_round_trip(durations, frac):
    c = StepClock(64)
    times = np.concatenate([[1e9], 1e9 + np.cumsum(durations)])
    for k, t in enumerate(times):
        c.push(k, float(t))
    for k in range(len(times) - 1):
        tau = k + frac
        wall = c.to_wall(tau)
        assert wall is not None and c.to_steps(wall) == pytest.approx(tau, abs=1e-3)  # float64 at 1e9 s: ~1e-7 s


# -- learner core -------------------------------------------------------------------------------------------------


def config(**kw) -> LearnerConfig:
    return LearnerConfig(run=RUN, **kw)


def test_feedback_is_held_until_a_newer_step_arrives():
    core = LearnerCore(config())
    steps = make_steps(5, [100.0 + k for k in range(5)])
    for s in steps[:3]:
        core.on_step(s)
    assert core.on_feedback(fb(0, 102.5)) == []  # after the newest action (102.0): held
    assert core.held == 1
    out = core.on_feedback(fb(1, 101.5))  # before it: credited at once, to steps 1, 0 (lags 0, 1) ...
    assert [r.status for r in out] == ["credited"] and out[0].steps == 2
    results, _ = core.on_step(steps[3])  # step 3 at 103.0 > 102.5: the held one is placed and credited
    assert [(r.seq, r.status, r.steps) for r in results] == [(0, "credited", 3)]
    assert core.on_feedback(fb(2, 103.7)) == []
    assert [(r.seq, r.status) for r in core.end()] == [(2, "after_end")]
    kinds = [(e.kind, e.seq, e.status) for e in core.take_entries()]
    assert kinds == [
        ("step", 0, "learned"),
        ("step", 1, "learned"),
        ("step", 2, "learned"),
        ("feedback", 0, ""),
        ("feedback", 1, ""),
        ("outcome", 1, "credited"),
        ("step", 3, "learned"),
        ("outcome", 0, "credited"),
        ("feedback", 2, ""),
        ("end", 0, ""),
        ("outcome", 2, "after_end"),
    ]


def test_a_feedback_between_two_steps_moves_the_weights_revision():
    """The H update of a feedback credited between two steps moves the revision (the version stays: no new step),
    and the result says which revision first holds it; a feedback the agent ignores (DQN) moves nothing."""
    from common.protocol import ShownStep
    from services.learner.books import credit_message

    core = LearnerCore(config())
    steps = make_steps(4, [100.0 + k for k in range(4)])
    for s in steps:
        core.on_step(s)
    version, revision = core.steps_learned, core.revision
    press = Feedback(
        run=RUN,
        teacher_id="web-1",
        seq=0,
        t_reaction=104.5,
        value=1,
        source="key",
        actor="actor-1",
        shown=[ShownStep(k, 100.05 + k) for k in range(4)],
    )
    [out] = core.on_feedback(press)
    assert out.status == "credited" and core.steps_learned == version
    assert core.revision == revision + 1 == out.revision
    assert credit_message(RUN, out, "actor-1", 105.0).revision == out.revision
    dqn = LearnerCore(config(algo="dqn"))  # an agent that does not learn from feedback: nothing moves
    for s in steps:
        dqn.on_step(s)
    before = dqn.revision
    [ignored] = dqn.on_feedback(press)
    assert ignored.status == "ignored" and ignored.revision is None and dqn.revision == before
    assert core.on_feedback(dataclasses.replace(press, seq=1)) and core.revision == revision + 2  # each press moves it


def test_a_late_press_is_credited_while_its_steps_are_held_and_counted_as_too_old_after():
    """A press that arrives late (the console was down, the learner lagged) is credited to the steps its person saw
    while they are still among the learner's held steps (those of the last 60 s, `history_s`); once they have all
    left, it is rejected by its reason, `too_old` (counted as `feedback_too_old`)."""
    from common.protocol import ShownStep

    core = LearnerCore(config())
    steps = make_steps(80, [100.0 + k for k in range(80)])

    def press(seq: int) -> Feedback:
        return Feedback(
            run=RUN,
            teacher_id="web-1",
            seq=seq,
            t_reaction=113.9,
            value=1,
            source="key",
            actor="actor-1",
            shown=[ShownStep(k, 100.05 + k) for k in range(10, 14)],
        )

    for s in steps[:40]:
        core.on_step(s)
    [late] = core.on_feedback(press(0))  # 26 steps later: steps 10-13 are still held
    assert late.status == "credited" and {q for q, _ in late.credited} <= {10, 11, 12, 13} and late.credited
    for s in steps[40:]:
        core.on_step(s)
    [too_old] = core.on_feedback(press(1))  # 66 steps later: they have left the history
    assert too_old.status == "too_old" and too_old.lost_mass == 1.0
    assert core.counters["feedback_too_old"] == 1 and core.counters["feedback_stale"] == 0


def test_stale_feedback_and_gaps_are_counted():
    core = LearnerCore(config())
    steps = make_steps(60, [100.0 + 2 * k for k in range(60)])
    for s in steps[:50]:
        core.on_step(s)
    assert core.on_feedback(fb(0, 100.5))[0].status == "stale"  # older than the 60 s of held steps
    assert core.on_feedback(fb(1, 140.5))[0].status == "credited"  # 58 s: still held
    core.on_step(steps[55])  # 5 steps lost
    assert core.counters["steps_lost"] == 5
    # A feedback about steps before the gap cannot be credited across it.
    assert core.on_feedback(fb(2, 100.0 + 2 * 53 + 0.5))[0].status == "stale"


def test_actor_restart_forgets_history():
    core = LearnerCore(config())
    for s in make_steps(5, [100.0 + k for k in range(5)]):
        core.on_step(s)
    core.on_feedback(fb(0, 104.5))
    results, _ = core.on_step(make_steps(1, [200.0], incarnation="actor-2")[0])
    assert [r.status for r in results] == ["actor_restarted"]
    assert core.counters["actor_restarts"] == 1


def run_core(steps, feedbacks, order) -> LearnerCore:
    core = LearnerCore(config(task=Task(seed=3)))
    for kind, i in order:
        if kind == "s":
            core.on_step(steps[i])
        else:
            core.on_feedback(feedbacks[i])
    core.end()
    return core


def interleave(n_steps: int, feedbacks_at: list[int]) -> list[tuple[str, int]]:
    order = []
    j = 0
    for k in range(n_steps):
        order.append(("s", k))
        while j < len(feedbacks_at) and feedbacks_at[j] == k:
            order.append(("f", j))
            j += 1
    return order


@pytest.mark.parametrize("scale", ["fast-jitter", "slow-uneven"])
def test_step_durations_do_not_matter_on_the_step_clock(scale):
    """Real timestamps with any step durations give bit-identical learning to the runner's virtual time,
    when reactions are stamped half-way between two actions (the teacher's steps clock)."""
    n = 120
    rng = np.random.default_rng(len(scale))
    durations = rng.uniform(2e-4, 2e-3, n) if scale == "fast-jitter" else rng.exponential(0.3, n) + 1e-3
    wall = 1.7e9 + np.concatenate([[0.0], np.cumsum(durations)[:-1]])
    virtual = np.arange(n, dtype=float)
    at = sorted(int(k) for k in rng.choice(np.arange(2, n - 1), 40, replace=False))  # feedback sent after step k
    results = []
    for times in (virtual, wall):
        steps = make_steps(n, times, seed=1)
        # Reaction stamped between steps k-1 and k (lag-0 reaction to step k-1), sent once step k is seen.
        fbs = [fb(j, (times[k - 1] + times[k]) / 2, 1 if j % 3 else -1) for j, k in enumerate(at)]
        results.append(run_core(steps, fbs, interleave(n, at)))
    a, b = (r.policy_weights() for r in results)
    assert all(a[k].tobytes() == b[k].tobytes() for k in a)
    assert results[0].counters == results[1].counters


def test_same_inputs_same_order_same_weights_and_entries():
    steps = make_steps(80, [10.0 + 0.01 * k for k in range(80)], seed=2)
    at = list(range(3, 78, 2))
    fbs = [fb(j, 10.0 + 0.01 * (k - 0.5), 1) for j, k in enumerate(at)]
    a, b = run_core(steps, fbs, interleave(80, at)), run_core(steps, fbs, interleave(80, at))
    wa, wb = a.policy_weights(), b.policy_weights()
    assert all(wa[k].tobytes() == wb[k].tobytes() for k in wa)
    key = lambda e: (e.kind, e.source, e.seq, e.status)  # noqa: E731
    assert [key(e) for e in a.take_entries()] == [key(e) for e in b.take_entries()]


def test_config_record_round_trips():
    core = LearnerCore(config(algo="deep-tamer", task=Task(seed=7), agent={"assumed_delay_probs": (0.2, 0.8)}))
    rebuilt = learner_config_from_record(core.config_record()["learner"])
    assert rebuilt == core.config


# -- teacher -------------------------------------------------------------------------------------------------------


def teacher(**kw) -> OracleTeacher:
    return OracleTeacher(TeacherConfig(run=RUN, **kw))


def test_steps_clock_reacts_after_step_k_plus_lag_plus_one_stamped_half_way():
    t = teacher(observer=ObserverConfig(p_feedback=1.0), task=Task(seed=5))
    times = [1000.0 + 0.37 * k**1.5 for k in range(40)]
    steps = make_steps(40, times)
    sent = []
    for k, s in enumerate(steps):
        for r in t.on_step(s):
            sent.append((k, r))
    assert len(sent) > 30
    for seen, r in sent:
        m = r.ref_seq + r.lag_steps
        assert seen == m + 1  # sent as soon as step k+d+1 is seen
        assert r.t_reaction == pytest.approx((times[m] + times[m + 1]) / 2)
    # The same draws as the core's observer on virtual time.
    _, rule = make_env("maze", 0)
    obs = SimulatedObserver(ObserverConfig(1.0), rule, derive_seed(5, "observer"))
    expected = [obs.react(float(k), s.info, s.episode, k) for k, s in enumerate(steps)]
    got = {r.ref_seq: r for _, r in sent}
    for k, e in enumerate(expected[:-3]):
        assert e is not None and got[k].value == e.value and got[k].lag_steps == e.lag_steps


def test_wall_clock_reacts_in_real_time():
    t = teacher(observer=ObserverConfig(p_feedback=1.0), clock="wall", step_unit=0.1, task=Task(seed=1))
    steps = make_steps(3, [50.0, 50.1, 50.2])
    for s in steps:
        assert t.on_step(s) == []
    due = t.due(50.2)
    assert all(r.t_reaction <= 50.2 for r in due)
    for r in due:
        assert r.t_reaction == pytest.approx(50.0 + 0.1 * r.ref_seq + 0.1 * (r.lag_steps + 0.5))
    following = t.next_due()
    assert following is None or following > 50.2
    left = t.finish(60.0)  # only reactions stamped before the last action (50.2) are still sent
    assert all(r.t_reaction <= 50.2 for r in left)


def test_teacher_config_rejects_bad_values():
    with pytest.raises(ValueError):
        TeacherConfig(run="bad run")
    with pytest.raises(ValueError):
        TeacherConfig(observer=cast(Any, {"p_feedback": 1.5}))  # (a nested config read from JSON is a dict)
    assert dataclasses.replace(TeacherConfig(), clock="wall").clock == "wall"


# -- actor's weights slot -------------------------------------------------------------------------------------------


def test_actor_never_goes_back_to_an_older_version():
    import time as _time

    from common.agents import TrialBatchAgent, agent_config
    from common.protocol import Weights, weights_key
    from common.wire.transport import Inbox, Received
    from services.common.gate import WeightsFollower
    from services.common.config import ActorConfig
    from services.common.runtime import ServiceRuntime

    agent = TrialBatchAgent([agent_config("dqn-tamer")], 2, 4, [0])
    spec = {k: tuple(v.shape) for k, v in agent.policy_weights(0).items()}
    rt = ServiceRuntime(
        "actor", ActorConfig(run=RUN, credentials=actor_credentials(RUN)), install_signals=False, process_default=False
    )
    slot = WeightsFollower(agent, spec, rt)
    slot.announced = ["learner-1", "learner-2"]  # their ServiceStatus / liveliness announced them
    inbox = Inbox(8, "block")

    def send(version: int, fill: float, learner: str = "learner-1", revision: int | None = None) -> None:
        tensors = {k: np.full(s, fill, np.float32) for k, s in spec.items()}
        w = Weights(
            run=RUN, incarnation=learner, version=version, t_published=_time.time(), tensors=tensors, revision=revision
        )
        inbox.put(Received(weights_key(RUN), w.encode(), _time.time(), None))

    send(5, 0.5)
    send(3, 0.3)  # older, arrives later: ignored
    assert slot.adopt(inbox) and slot.version == 5
    assert all(np.all(v == 0.5) for v in agent.policy_weights(0).values())
    assert rt.counters["weights_not_newer"] == 1
    send(7, 0.7)
    assert slot.adopt(inbox, timeout=1.0) and slot.version == 7
    send(1, 0.1, learner="learner-2")  # a restarted learner starts again from low versions
    assert slot.adopt(inbox) and slot.version == 1 and rt.counters["learner_restarts"] == 1
    send(99, 0.9, learner="mallory")  # nobody announced it: dropped
    assert not slot.adopt(inbox) and slot.version == 1 and rt.counters["weights_dropped_unknown_incarnation"] == 1
    # The same steps learned, then a press's H update between two steps: a new revision of version 1 is taken
    send(1, 0.2, learner="learner-2", revision=4)
    assert slot.adopt(inbox) and (slot.version, slot.revision) == (1, 4)
    send(1, 0.25, learner="learner-2", revision=5)
    send(1, 0.21, learner="learner-2", revision=3)  # an older revision arriving late: ignored
    assert slot.adopt(inbox) and (slot.version, slot.revision) == (1, 5)
    assert all(np.all(v == 0.25) for v in agent.policy_weights(0).values())
    assert rt.counters["weights_not_newer"] == 2
