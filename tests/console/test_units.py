"""The console's parts without a browser: the page gate, a screen's timeline, the scene, and the learner's credit
of a person's feedback in seconds over on-screen intervals."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from common.envs import make_env
from common.envs.scene import SceneTracker, static_scene
from common.protocol import Feedback, ShownStep, Step
from common.core.screen import ScreenTimeline
from common.core.task import Task
from services.common.config import LearnerConfig
from services.console.people import PageError, PageGate, Person, RateLimit
from services.learner.core import LearnerCore

NOW = 1_800_000_000.0


def person() -> Person:
    return Person("web-1", RateLimit(8, 16), RateLimit(15))


def reason(fn, *args) -> str:
    with pytest.raises(PageError) as e:
        fn(*args)
    return e.value.reason


def test_page_gate_accepts_good_input_and_names_the_reason_for_bad():
    gate, p = PageGate(5.0, 1000, clock=lambda: NOW), person()
    fb = gate.text(json.dumps({"type": "feedback", "value": -1, "t_page": NOW - 0.4, "offset": 0.1, "rtt": 0.001}), p)
    assert fb["t_sys"] == pytest.approx(NOW - 0.3) and fb["value"] == -1 and p.offset == 0.1
    cases = {
        "{oops": "malformed",
        "[]": "malformed",
        json.dumps({"type": "hack"}): "unknown_kind",
        json.dumps({"type": "feedback", "value": 2, "t_page": NOW, "offset": 0, "rtt": 0}): "bad_value",
        json.dumps({"type": "feedback", "value": True, "t_page": NOW, "offset": 0, "rtt": 0}): "bad_value",
        json.dumps({"type": "feedback", "value": 1, "t_page": NOW + 60, "offset": 0, "rtt": 0}): "absurd_timestamp",
        json.dumps({"type": "feedback", "value": 1, "t_page": "now", "offset": 0, "rtt": 0}): "wrong_type",
        '{"type": "ping", "t0": NaN}': "non_finite",
        json.dumps({"type": "control", "command": "pace", "rate": 0}): "bad_value",
        json.dumps({"type": "control", "command": "reboot"}): "bad_value",
        json.dumps({"type": "shown", "seq": -1, "actor": "a", "t_page": NOW, "offset": 0, "rtt": 0}): "bad_value",
        "x" * 5000: "oversized",
    }
    # a paint stamped ahead of the console's clock is placed at its arrival; one absurdly far is refused
    ahead = {"type": "shown", "seq": 3, "actor": "a", "t_page": NOW + 2, "offset": 0, "rtt": 0}
    assert gate.text(json.dumps(ahead), p)["t_sys"] == NOW
    assert (
        reason(
            gate.text,
            json.dumps({"type": "shown", "seq": 4, "actor": "a", "t_page": NOW + 60, "offset": 0, "rtt": 0}),
            p,
        )
        == "absurd_timestamp"
    )
    assert gate.text(json.dumps({"type": "ping", "t0": NOW, "ready": True}), p)["ready"] is True
    assert gate.text(json.dumps({"type": "ping", "t0": NOW, "ready": "yes"}), p)["ready"] is False
    for text, why in cases.items():
        assert reason(gate.text, text, p) == why, text[:60]
    frame = struct.pack("<d", NOW - 0.1) + b"\xff\xd8" + b"\0" * 100
    assert gate.frame(frame, p)[1][:2] == b"\xff\xd8"
    assert reason(gate.frame, b"\0" * 50, p) == "bad_frame"
    assert reason(gate.frame, struct.pack("<d", NOW) + b"\xff\xd8" + b"\0" * 2000, p) == "oversized_frame"
    flood = [
        gate.text(json.dumps({"type": "feedback", "value": 1, "t_page": NOW, "offset": 0, "rtt": 0}), p)
        for _ in range(15)
    ]  # the burst (16, one used above) ...
    assert len(flood) == 15
    assert (
        reason(gate.text, json.dumps({"type": "feedback", "value": 1, "t_page": NOW, "offset": 0, "rtt": 0}), p)
        == "flood"
    )  # ... and then no more


def test_screen_timeline_lists_what_a_feedback_may_refer_to():
    tl = ScreenTimeline()
    for k in range(20):
        assert tl.add("a", k, 100.0 + 0.5 * k)
    assert not tl.add("a", 5, 200.0)  # an older step
    actor, shown = tl.window(106.3, 4.0)
    assert actor == "a" and [s.seq for s in shown] == list(range(4, 13))  # on screen at 102.3 .. newest by 106.3


def test_scene_follows_the_maze_and_the_taxi():
    assert static_scene("maze", 2)["walls"][0][0] in (0, 1)
    env, _ = make_env("maze-pomdp", 2)
    env.reset(seed=0)
    track = SceneTracker("maze-pomdp", 2)
    for t, a in enumerate([0, 1, 1, 2, 3, 0, 1]):
        nxt = env.step(a)[0]
        assert track.after(t, a, nxt)["agent"] == list(env.pos)
    taxi = SceneTracker("taxi").after(0, 0, np.eye(19)[[1, 6, 12, 17]].sum(axis=0))
    assert taxi == {"taxi": [1, 1], "passenger": 2, "dest": 2}


def _credit_of_one_press(config: LearnerConfig):
    """Twelve steps shown 0.5 s apart (each 0.05 s after it was taken) and one press at t0 + 5.8 s."""
    core = LearnerCore(config)
    env, _ = make_env("maze", 0)
    obs, t0 = env.reset(seed=0)[0], 1000.0
    shown = [ShownStep(k, t0 + 0.5 * k + 0.05) for k in range(12)]
    fb = Feedback(
        run="r",
        teacher_id="web-1",
        seq=0,
        t_reaction=t0 + 5.8,
        value=1,
        source="key",
        t_page=5.0,
        actor="act-1",
        shown=shown,
    )
    assert core.on_feedback(fb) == []  # held: the newest step it lists is not learned yet
    results = []
    for k in range(12):
        nxt, r, term, _, _ = env.step(k % 4)
        results += core.on_step(
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
        )[0]
        obs = nxt
    (res,) = results
    return res, core


def test_learner_credits_a_persons_feedback_with_their_learned_delay_by_default():
    """No delay option: the person's delay is learned (from Deep TAMER's uniform 0.2-4 s), each press credited by
    its posterior over the steps that appeared before it, and reported per person."""
    config = LearnerConfig(run="r", task=Task(env="maze"))
    assert (config.screen_delay, config.screen_credit) == ("learned", "onset")
    res, core = _credit_of_one_press(config)
    credited = dict(res.credited)
    assert res.status == "credited" and sum(credited.values()) == pytest.approx(1.0)
    # onsets 0.2-4 s before t0 + 5.8 (steps 4..11 appeared at t0 + 2.05 ... t0 + 5.55): nearly all the mass
    assert sum(credited.get(k, 0) for k in range(4, 12)) > 0.95 and all(k < 12 for k in credited)
    assert core.delay_summary()["web-1"]["feedbacks"] == 1
    again = LearnerCore(config)  # a checkpoint keeps each person's delay
    core.take_entries()
    tensors, meta = core.snapshot()
    again.restore(tensors, json.loads(json.dumps(meta)))
    assert again.delay_summary() == core.delay_summary()


def test_learner_credits_a_persons_feedback_in_seconds_over_the_screen_intervals():
    res, core = _credit_of_one_press(
        LearnerConfig(run="r", task=Task(env="maze"), screen_delay="uniform:0.2,4", screen_credit="interval")
    )
    # uniform 0.2-4 s: each step gets the share of [t - 4, t - 0.2] = [1001.8, 1005.6] it was on screen
    want = {3: 0.25 / 3.8, **{k: 0.5 / 3.8 for k in range(4, 11)}, 11: 0.05 / 3.8}
    assert res.status == "credited" and dict(res.credited) == pytest.approx(want)
    assert res.lost_mass == pytest.approx(0.0, abs=1e-9)


def test_learner_credits_at_each_steps_onset_when_told_and_refuses_onset_with_a_step_counted_delay():
    res, core = _credit_of_one_press(
        LearnerConfig(run="r", task=Task(env="maze"), screen_delay="uniform:0.3,1.5", screen_credit="onset")
    )
    # of the steps that appeared before t0 + 5.8, those 0.3-1.5 s before it: step 9 (t0 + 4.55) and step 10
    # (t0 + 5.05), equally; step 8 appeared 1.75 s before, step 11 only 0.25 s before
    assert res.status == "credited" and dict(res.credited) == pytest.approx({9: 0.5, 10: 0.5})
    with pytest.raises(ValueError, match="onset"):
        LearnerConfig(run="r", task=Task(env="maze"), screen_delay="steps:0.5,0.5", screen_credit="onset")
    with pytest.raises(ValueError, match="screen-credit"):
        LearnerConfig(run="r", task=Task(env="maze"), screen_credit="middle")


def test_security_login_and_tls_and_loopback_only_without_it(tmp_path):
    from aiohttp.test_utils import make_mocked_request

    from common.security import SECURITY_FILE, init, load_security
    from services.console.config import ConsoleConfig
    from services.console.service import check_login, main, tls_context

    init(tmp_path, ["web", "alice"])
    sec_path = str(tmp_path / SECURITY_FILE)
    security = load_security(sec_path)
    cfg = ConsoleConfig(run="r", security=sec_path)
    good = security.password("alice")
    assert check_login(cfg, make_mocked_request("GET", f"/ws?teacher=alice&password={good}")) == "alice"
    assert check_login(cfg, make_mocked_request("GET", "/ws?teacher=alice&password=wrong")) is None
    assert check_login(cfg, make_mocked_request("GET", f"/ws?teacher=mallory&password={good}")) is None
    assert check_login(cfg, make_mocked_request("GET", "/ws")) is None
    assert tls_context(cfg) is not None  # HTTPS with the router's certificate
    assert tls_context(ConsoleConfig(run="r")) is None
    assert main(ConsoleConfig(run="r", host="0.0.0.0")) == 2  # other machines only with --security


def test_an_actor_started_paused_waits_for_a_resume_and_counts_the_wait():
    from collections import Counter

    from common.wire.delivery import Inbox, Received
    from common.protocol import Control, control_key
    from services.actor.control import RunControl

    counters, said = Counter(), []
    control = RunControl(2.0, counters, said.append, paused=True)
    inbox = Inbox(8)
    assert control.paused and not control.take(inbox) and "paused until a resume" in said[0]
    msg = Control(run="r", source="web-1", seq=0, t=NOW, command="resume")
    inbox.put(Received(control_key("r"), msg.encode(), NOW, None))
    assert control.take(inbox) and not control.paused
    assert counters["control_resume"] == 1 and counters["paused_ms"] >= 0 and said[-1] == "resumed by web-1"


def test_measure_names_a_missing_or_foreign_log_in_one_line(tmp_path, capsys):
    from services.console import measure

    with pytest.raises(SystemExit):
        measure.cli([str(tmp_path / "nope")])
    assert "no log at" in capsys.readouterr().err
    (tmp_path / "x.mcap").write_text("not a log")
    assert measure.cli([str(tmp_path / "x.mcap")]) == 2
    assert "not an MCAP file" in capsys.readouterr().err


def test_rule_agreement_is_the_share_of_a_press_on_steps_the_rule_rates_alike():
    from common.protocol import Credit, CreditedStep
    from services.console.measure import rule_agreement

    closer = {"target_distance_before": 5.0, "target_distance_after": 4.0}
    away = {"target_distance_before": 4.0, "target_distance_after": 5.0}
    infos = {("act-1", 7): closer, ("act-1", 8): away}
    credit = Credit(
        run="r",
        teacher_id="web-1",
        seq=0,
        value=1,
        status="credited",
        t_reaction=NOW,
        t_credited=NOW,
        actor="act-1",
        steps=[CreditedStep(7, 0.3), CreditedStep(8, 0.1)],
        lost_mass=0.6,
    )
    assert rule_agreement(credit, infos) == pytest.approx(0.75)
    assert rule_agreement(credit, {("act-1", 7): closer, ("act-1", 8): {}}) is None  # no distances: no rule
