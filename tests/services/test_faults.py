"""Fault tolerance without processes: the learner's checkpoint restores bit for bit, the input gate rejects what
must not reach a model (property-based), the resend ring is bounded, state files are atomic."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import threading

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from common.protocol import Feedback, ServiceStatus, Step
from services.common.config import LearnerConfig
from services.common.gate import GATE_REASONS, InputGate
from common.wire.delivery import ResendRing
from services.common.statefiles import atomic_write, atomic_write_json, read_json
from services.common.progress import ProgressFile
from services.learner import checkpoint
from services.learner.core import LearnerCore

from .live import actor_credentials
from .test_cores import RUN, fb, make_steps

NOW = 1.7e9


def feed(core: LearnerCore, inputs) -> None:
    for x in inputs:
        if isinstance(x, Step):
            core.on_step(x)
        else:
            core.on_feedback(x)


def scenario(n: int = 240, seed: int = 3):
    """Steps with feedback between them (some held, some credited at once), as a live learner sees them."""
    steps = make_steps(n, [NOW + k for k in range(n)], seed=seed)
    rng = np.random.default_rng(seed)
    inputs, f = [], 0
    for k, s in enumerate(steps):
        inputs.append(s)
        if rng.random() < 0.5:
            inputs.append(fb(f, NOW + k + rng.choice([-1.5, -0.5, 0.5]), int(rng.choice([-1, 1]))))
            f += 1
    return inputs


def weights_bytes(core: LearnerCore) -> dict[str, bytes]:
    return {k: v.tobytes() for k, v in core.policy_weights().items()}


@pytest.mark.parametrize("algo, oracle_delay", [("dqn-tamer", "steps"), ("dqn-rs", "steps"), ("dqn-tamer", "learned")])
def test_checkpoint_restores_the_learner_bit_for_bit(tmp_path, algo, oracle_delay):
    """Learn, checkpoint mid-way (with held feedback), restore into a fresh core, continue: the same weights,
    entries and counters as a learner that never stopped (with a delay learned in seconds too: the agent's
    registry of its teachers' delays is in the checkpoint)."""
    inputs = scenario()
    cut = next(
        i
        for i in range(150, len(inputs))
        if isinstance(inputs[i], Feedback) and inputs[i].t_reaction > inputs[i - 1].t_action
    )  # a held feedback at the cut
    ref = LearnerCore(LearnerConfig(run=RUN, algo=algo, oracle_delay=oracle_delay))
    feed(ref, inputs)
    ref.end()

    a = LearnerCore(LearnerConfig(run=RUN, algo=algo, oracle_delay=oracle_delay))
    feed(a, inputs[: cut + 1])
    assert a.held >= 1 or algo == "dqn-rs"
    head = a.take_entries()
    tensors, meta = a.snapshot()
    rows = [k for k in checkpoint.flatten(tensors)[0] if k.endswith(".like")]  # a learned window: raw, not JSON
    assert len(rows) == (oracle_delay == "learned"), rows
    size = checkpoint.save(tmp_path / "learner.ckpt", tensors, meta)
    assert size > 0 and not list(tmp_path.glob(".*tmp"))
    tensors2, meta2 = checkpoint.load(tmp_path / "learner.ckpt")
    b = LearnerCore(LearnerConfig(run=RUN, algo=algo, oracle_delay=oracle_delay))
    b.restore(tensors2, meta2)
    assert b.position == len(head)
    feed(b, inputs[cut + 1 :])
    b.end()
    assert weights_bytes(b) == weights_bytes(ref)
    assert [dataclasses.astuple(e)[:4] for e in head + b.take_entries()] == [
        dataclasses.astuple(e)[:4] for e in ref.take_entries()
    ]
    assert b.counters == ref.counters
    assert b.delay_summary() == ref.delay_summary() and (oracle_delay == "steps") == (not b.delays)
    full_a, full_ref = a.agent.state_dict(), ref.agent.state_dict()  # noqa: F841 (a kept learning state)
    assert checkpoint.load(tmp_path / "missing.ckpt") is None


def test_checkpoint_is_not_a_pickle_and_rejects_other_files(tmp_path):
    core = LearnerCore(LearnerConfig(run=RUN))
    feed(core, scenario(20))
    core.take_entries()
    checkpoint.save(tmp_path / "c.ckpt", *core.snapshot())
    raw = (tmp_path / "c.ckpt").read_bytes()
    assert b"\x80\x04" not in raw[:16] and raw[8:9] == b"{"  # a safetensors JSON header, not a pickle
    (tmp_path / "bad.ckpt").write_bytes(b'\x10\x00\x00\x00\x00\x00\x00\x00{"__metadata__":{}}  ')
    with pytest.raises(Exception):  # noqa: B017  (whatever safetensors raises: it never unpickles)
        checkpoint.load(tmp_path / "bad.ckpt")


# -- input gate -------------------------------------------------------------------------------------------------------


def gate(**kw) -> InputGate:
    g = InputGate(8, 4, teachers=("oracle",), **kw)
    g.on_status(
        ServiceStatus(run=RUN, service="actor", pid=1, state="ready", t=NOW, counters={}, incarnation="actor-1")
    )
    return g


def step(seq=0, t=NOW, inc="actor-1", obs_len=8, action=1) -> Step:
    return Step(
        run=RUN,
        incarnation=inc,
        seq=seq,
        t_action=t,
        episode=0,
        t_in_episode=seq,
        obs=[0.0] * obs_len,
        action=action,
        reward=0.0,
        next_obs=[0.0] * obs_len,
        terminated=False,
        truncated=False,
        weights_version=0,
        info={},
    )


def test_gate_admits_announced_steps_in_order_and_drops_duplicates():
    g = gate()
    assert g.admit_step(step(0), NOW) is None and g.admit_step(step(1), NOW) is None
    assert g.admit_step(step(1), NOW) == "duplicate" and g.admit_step(step(0), NOW) == "duplicate"
    assert g.admit_step(step(3), NOW) is None  # a gap is the core's business (counted as lost there)
    assert g.admit_step(step(0, inc="actor-2"), NOW) == "unknown_incarnation"
    g.on_status(
        ServiceStatus(run=RUN, service="actor", pid=2, state="starting", t=NOW, counters={}, incarnation="actor-2")
    )
    assert g.admit_step(step(0, inc="actor-2"), NOW) is None  # the restarted actor replaces the old one
    assert g.admit_step(step(4, inc="actor-1"), NOW) == "retired_incarnation"
    assert g.rejected() == {"unknown_incarnation": 1, "retired_incarnation": 1}
    assert g.counters["duplicate"] == 2


def test_gate_rejects_wrong_shapes_actions_times_teachers_and_seq_jumps():
    g = gate(max_future=10, max_past=600, max_seq_jump=100, max_feedback_jump=100)
    assert g.admit_step(step(obs_len=3), NOW) == "obs_shape"
    assert g.admit_step(step(action=4), NOW) == "action_range"
    assert g.admit_step(step(t=NOW + 11), NOW) == "future_timestamp"
    assert g.admit_step(step(t=NOW - 601), NOW) == "stale_timestamp"
    assert g.admit_step(step(0), NOW) is None
    assert g.admit_step(step(102), NOW) == "bad_seq"
    assert g.admit_feedback(fb(0, NOW, teacher="mallory"), NOW) == "unknown_teacher"
    assert g.admit_feedback(fb(0, NOW + 60), NOW) == "future_timestamp"
    assert g.admit_feedback(fb(0, NOW), NOW) is None
    assert g.admit_feedback(fb(0, NOW), NOW) == "duplicate"
    assert g.admit_feedback(fb(500, NOW), NOW) == "bad_seq"
    g.on_status(ServiceStatus(run=RUN, service="teacher.bob", pid=3, state="ready", t=NOW, counters={}))
    assert g.admit_feedback(fb(0, NOW, teacher="bob"), NOW) is None


def test_gate_state_round_trips_through_json():

    g = gate()
    g.admit_step(step(0), NOW)
    g.admit_feedback(fb(0, NOW), NOW)
    h = InputGate(8, 4, teachers=("oracle",))
    h.load(json.loads(json.dumps(g.state())))
    assert h.admit_step(step(0), NOW) == "duplicate" and h.admit_step(step(1), NOW) is None
    assert h.admit_feedback(fb(0, NOW), NOW) == "duplicate"


finite = st.floats(allow_nan=False, allow_infinity=False)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["actor-1", "actor-2", "x"]),
            st.integers(0, 10**6),
            finite | st.sampled_from([math.nan, math.inf]),
            st.integers(1, 12),
            st.integers(0, 1023),
        ),
        max_size=40,
    )
)
def test_gate_never_admits_what_a_model_cannot_take(items):
    """Whatever mix of steps arrives, an admitted one has the env's shapes, an announced incarnation, a
    timestamp near its arrival, and a seq beyond every one admitted before from that incarnation."""
    g = gate(max_future=10, max_past=600, max_seq_jump=1000)
    last: dict[str, int] = {}
    for inc, seq, dt, n, action in items:
        s = dataclasses.replace(
            step(0, inc=inc, obs_len=n, action=min(action, 1023)),
            seq=seq,
            t_action=NOW + dt if math.isfinite(dt) else dt,
        )
        reason = g.admit_step(s, NOW)
        if reason is None:
            assert n == 8 and 0 <= action < 4 and inc == "actor-1"
            assert -600 <= s.t_action - NOW <= 10
            assert seq > last.get(inc, -1)
            last[inc] = seq
        else:
            assert reason in GATE_REASONS or reason == "duplicate"


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["oracle", "mallory"]), st.integers(0, 10**6), finite), max_size=40))
def test_gate_feedback_is_admitted_once_per_teacher_seq(items):
    g = gate(max_feedback_jump=1000)
    admitted = set()
    for teacher, seq, dt in items:
        f = fb(seq, NOW + max(-1e6, min(dt, 1e6)), teacher=teacher)
        if g.admit_feedback(f, NOW) is None:
            assert teacher == "oracle" and (teacher, seq) not in admitted
            assert seq <= max((s for _, s in admitted), default=-1) + 1 + 1000
            admitted.add((teacher, seq))


def test_gate_a_forged_seq_jump_silences_no_real_press():
    """Issue 25: one feedback at seq +4000 (signed with a stolen teacher credential, so it passes the
    authentication check) used to be admitted and move the window: the teacher's next 4000 real presses were
    then dropped as duplicates. Now it is `bad_seq`; a forged jump within the bound takes only its own seq."""
    g = gate()
    for seq in range(10):
        assert g.admit_feedback(fb(seq, NOW), NOW) is None
    assert g.admit_feedback(fb(10 + 4000, NOW), NOW) == "bad_seq"
    assert g.admit_feedback(fb(10 + 1000, NOW), NOW) is None  # within max_feedback_jump: admitted ...
    real = [g.admit_feedback(fb(seq, NOW), NOW) for seq in range(10, 1200)]
    assert real.count(None) == len(real) - 1 and real[1000] == "duplicate"  # ... it takes its own seq only
    assert g.rejected() == {"bad_seq": 1}
    for seq in range(1200, 1300):  # nothing left outstanding: the teacher goes on as before
        assert g.admit_feedback(fb(seq, NOW), NOW) is None
    assert g.admit_feedback(fb(5, NOW), NOW) == "duplicate" and not g.missing_feedback


def test_gate_seq_window_is_bounded_and_survives_a_restart():
    """Jumps may leave at most `feedback_window` seqs outstanding (a forger cannot walk the window away from the
    real teacher); the outstanding ones round-trip through the learner's checkpoint; a teacher restarted with
    its state file continues its seq, a new incarnation (a new teacher id) starts at 0."""
    g = gate(max_feedback_jump=100, feedback_window=250)
    assert g.admit_feedback(fb(0, NOW), NOW) is None
    assert [g.admit_feedback(fb(s, NOW), NOW) for s in (100, 200, 300)] == [None, None, "bad_seq"]
    assert g.admit_feedback(fb(250, NOW), NOW) is None  # 49 more outstanding: 247 in all
    assert g.admit_feedback(fb(255, NOW), NOW) == "bad_seq" and g.admit_feedback(fb(251, NOW), NOW) is None
    h = gate()
    h.load(json.loads(json.dumps(g.state())))
    assert h.admit_feedback(fb(1, NOW), NOW) is None and h.admit_feedback(fb(1, NOW), NOW) == "duplicate"
    assert h.admit_feedback(fb(252, NOW), NOW) is None  # the restarted teacher continues
    h.on_status(ServiceStatus(run=RUN, service="teacher.web-1-b", pid=4, state="ready", t=NOW, counters={}))
    assert h.admit_feedback(fb(0, NOW, teacher="web-1-b"), NOW) is None
    assert h.admit_feedback(fb(4000, NOW, teacher="web-1-b"), NOW) == "bad_seq"  # a new teacher starts at 0


# -- resend ring, state files ----------------------------------------------------------------------------------------


class Pub:
    def __init__(self):
        self.sent = []

    def put(self, data):
        self.sent.append(data)


def test_resend_ring_is_bounded_and_resends_in_order():
    ring, pub = ResendRing(window=60, max_items=5), Pub()
    for i in range(12):
        ring.add(pub, bytes([i]))
    assert len(ring) == 5
    assert ring.resend() == 5 and pub.sent == [bytes([i]) for i in range(7, 12)]
    pub.sent.clear()
    assert ring.resend(last=2) == 2 and pub.sent == [bytes([10]), bytes([11])]  # the newest, in order
    assert ring.resend(last=0) == 0 and ring.resend(last=99) == 5
    old = ResendRing(window=0.0, max_items=5)
    old.add(pub, b"x")
    assert old.resend() == 0


def test_atomic_json_state_file(tmp_path):
    p = tmp_path / "s" / "actor.json"
    assert read_json(p) is None
    atomic_write_json(p, {"episodes_done": 3})
    atomic_write_json(p, {"episodes_done": 4})
    assert read_json(p) == {"episodes_done": 4}
    assert sorted(os.listdir(p.parent)) == ["actor.json"]


def test_a_failed_state_file_write_leaves_no_temporary_file(tmp_path):
    """A write that fails after its temporary file was made (a full disk; here a directory in the way of the
    rename) leaves no temporary file behind (issue 25: 0-byte stats/*.json.tmp were left)."""
    (tmp_path / "stats").mkdir()
    with pytest.raises(OSError):
        atomic_write(tmp_path / "stats", b'{"counters": {}}')
    assert sorted(p.name for p in tmp_path.iterdir()) == ["stats"]


def test_summary_that_must_fit_its_reserve_keeps_every_count():
    """summary.json on a full disk: the bulky lists are left out first, every count and the outcome stay."""
    from services.launcher.rundir import SUMMARY_RESERVE, fit_reserve

    counts = {
        "run": "r",
        "outcome": "disk_full",
        "error": "disk full",
        "steps_sent": 123456,
        "steps_logged": 123450,
        "steps_learned": 123400,
        "feedback_sent": 999,
        "feedback_credited": 990,
        "feedback_rejected": {"stale": 9},
        "rejected_inputs": {"learner": {"bad_seq": 1}},
    }
    big = {
        **counts,
        "episodes": [{"actor": "actor-1", "episode": i, "return": 0.5, "steps": 20} for i in range(5000)],
        "returns": [0.5] * 5000,
    }
    text = fit_reserve(big)
    s = json.loads(text)
    assert len(text.encode()) <= SUMMARY_RESERVE
    assert {k: s[k] for k in counts} == counts and "episodes" in s["left_out"] and "episodes" not in s
    small = fit_reserve(counts)
    assert json.loads(small) == counts  # nothing left out when it fits


def test_progress_file_rewritten_in_place(tmp_path):
    p = tmp_path / "s" / "teacher.json"
    p.parent.mkdir()
    p.write_text('{"next_seq": 123456789, "left": "by an older incarnation, longer than the new record"}')
    f = ProgressFile(p)
    assert f.read()["next_seq"] == 123456789
    f.write({"next_seq": 5})  # the first write replaces the file atomically
    inode = p.stat().st_ino
    for seq in (6, 7, 1000):
        f.write({"next_seq": seq})
        assert ProgressFile(p).read() == {"next_seq": seq}
    assert p.stat().st_ino == inode  # in place: no new file
    f.write({"next_seq": 1, "note": "x" * 200})  # longer than the width: atomically again, wider
    assert read_json(p) == {"next_seq": 1, "note": "x" * 200}
    f.write({"next_seq": 2})
    assert read_json(p) == {"next_seq": 2} and sorted(os.listdir(p.parent)) == ["teacher.json"]
    f.close()


def test_progress_file_whole_after_sigkill(tmp_path):
    """A writer killed at a random moment leaves a record that parses (the old one or the new one)."""
    import signal
    import subprocess
    import sys
    import time

    p = tmp_path / "actor.json"
    code = (
        "import sys; from services.common.progress import ProgressFile\n"
        "f = ProgressFile(sys.argv[1]); n = 0\n"
        "while True:\n    n += 1; f.write({'episodes_done': n, 'pad': 'y' * (n % 40)})\n"
    )
    for delay in (0.01, 0.05, 0.2):
        p.unlink(missing_ok=True)
        proc = subprocess.Popen([sys.executable, "-c", code, str(p)], cwd=os.getcwd())
        deadline = time.monotonic() + 60
        while not p.exists() and time.monotonic() < deadline:  # (start-up on a loaded machine)
            time.sleep(0.005)
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        rec = read_json(p)
        assert rec["episodes_done"] > 0 and rec["pad"] == "y" * (rec["episodes_done"] % 40)


# -- the actor's weights check ------------------------------------------------------------------------------------

shapes = st.dictionaries(
    st.sampled_from(
        [
            "q.0.weight",
            "q.0.bias",
            "q.2.weight",
            "q.2.bias",
            "h.0.weight",
            "h.0.bias",
            "h.2.weight",
            "h.2.bias",
            "x.0.weight",
        ]
    ),
    st.lists(st.integers(1, 6), min_size=1, max_size=3).map(tuple),
    min_size=1,
    max_size=9,
)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(shapes, st.booleans(), st.sampled_from([0.0, 1e6, -1e6, 3600.0]))
def test_actor_adopts_only_weights_of_the_right_shape_from_an_announced_learner(tensors, announced, dt):
    """Whatever tensors arrive (names, shapes), the actor's networks change only for exactly its own names and
    shapes, from an announced learner, stamped near arrival; everything else is counted by reason."""
    import time as _time

    from common.agents import TrialBatchAgent, agent_config
    from common.protocol import Weights, weights_key
    from common.wire.transport import Inbox, Received
    from services.common.gate import WeightsFollower
    from services.common.config import ActorConfig
    from services.common.runtime import ServiceRuntime

    agent = TrialBatchAgent([agent_config("dqn-tamer")], 2, 4, [0])
    spec = {k: tuple(v.shape) for k, v in agent.policy_weights(0).items()}
    before = agent.policy_weights(0)  # copies
    rt = ServiceRuntime(
        "actor", ActorConfig(run=RUN, credentials=actor_credentials(RUN)), install_signals=False, process_default=False
    )
    slot = WeightsFollower(agent, spec, rt)
    if announced:
        slot.announced = ["learner-1"]
    inbox = Inbox(4, "drop_oldest")
    now = _time.time()
    for candidate in (tensors, spec):  # the generated tensors, then exactly the right ones
        data = Weights(
            run=RUN,
            incarnation="learner-1",
            version=1 if candidate is tensors else 2,
            t_published=max(0.0, now + dt),
            tensors={k: np.full(s, 0.25, np.float32) for k, s in candidate.items()},
        ).encode()
        inbox.put(Received(weights_key(RUN), data, now, None))
        adopted = slot.adopt(inbox)
        ok = announced and abs(dt) <= 10 and dict(candidate) == spec
        assert adopted == ok, (candidate, rt.counters)
        after = agent.policy_weights(0)
        changed = any(not np.array_equal(after[k], before[k]) for k in spec)
        assert changed == (ok or slot.version > 0)
    assert sum(v for k, v in rt.counters.items() if k.startswith("weights_dropped_")) >= 1 or (
        announced and abs(dt) <= 10 and dict(tensors) == spec
    )


def test_recorded_router_waits_for_the_run_record_and_gives_up_on_stop_or_timeout(tmp_path):
    from services.launcher.rundir import recorded_router

    (tmp_path / "config").mkdir()
    assert recorded_router(tmp_path, lambda: True) is None  # stopped before any record
    with pytest.raises(TimeoutError, match="no run record"):
        recorded_router(tmp_path, lambda: False, timeout=0.2)
    record = tmp_path / "config" / "run.json"
    timer = threading.Timer(0.3, lambda: atomic_write_json(record, {"launcher": {"endpoint": "tcp/127.0.0.1:1"}}))
    timer.start()
    try:
        assert recorded_router(tmp_path, lambda: False, timeout=30) == "tcp/127.0.0.1:1"
    finally:
        timer.cancel()
