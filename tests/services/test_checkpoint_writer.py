"""The learner's checkpoint is written on a thread of its own: what it writes is the learner as it was when the loop
captured it (the loop goes on learning meanwhile), writes come one at a time, and a failed write is raised in the
loop, as it was when the loop wrote the file itself."""

from __future__ import annotations

import collections

import pytest

from services.common.config import LearnerConfig
from services.learner import checkpoint
from services.learner.core import LearnerCore

from .test_cores import RUN
from .test_faults import feed, scenario, weights_bytes


class Runtime:
    """What the writer uses of a service's runtime: its counters and latency samples."""

    incarnation = "learner-test"

    def __init__(self):
        self.counters: collections.Counter[str] = collections.Counter()
        self.samples: dict[str, list] = collections.defaultdict(list)


class NoGate:
    def state(self) -> dict:
        return {}


def core() -> LearnerCore:
    return LearnerCore(LearnerConfig(run=RUN, algo="dqn-tamer", oracle_delay="learned"))


def test_the_written_checkpoint_is_the_learner_when_captured_while_it_goes_on_learning(tmp_path):
    inputs = scenario()
    cut = len(inputs) // 2
    ref = core()
    feed(ref, inputs)
    ref.end()

    live, rt = core(), Runtime()
    feed(live, inputs[:cut])
    head = live.take_entries()
    writer = checkpoint.CheckpointWriter(rt)
    writer.submit(tmp_path / "learner.ckpt", live, NoGate())
    feed(live, inputs[cut:])  # the loop learns on while the file is written
    writer.wait()
    assert rt.counters["checkpoints"] == 1
    assert len(rt.samples["checkpoint_cost_s"]) == len(rt.samples["checkpoint_write_s"]) == 1

    loaded = checkpoint.load(tmp_path / "learner.ckpt")
    assert loaded is not None
    tensors, meta = loaded
    assert meta["service"]["incarnation"] == "learner-test" and meta["gate"] == {}
    restored = core()
    restored.restore(tensors, meta["core"])
    assert restored.position == len(head)
    feed(restored, inputs[cut:])
    restored.end()
    assert weights_bytes(restored) == weights_bytes(ref)
    assert restored.counters == ref.counters


def test_writes_come_one_at_a_time_in_order(tmp_path):
    inputs, live, rt = scenario(), core(), Runtime()
    writer = checkpoint.CheckpointWriter(rt)
    for part in range(3):
        feed(live, inputs[part * 40 : (part + 1) * 40])
        live.take_entries()
        writer.submit(tmp_path / "learner.ckpt", live, NoGate())  # waits for the write before it
    writer.wait()
    assert rt.counters["checkpoints"] == 3
    loaded = checkpoint.load(tmp_path / "learner.ckpt")
    assert loaded is not None and loaded[1]["core"]["position"] == live.position  # the last one stays
    assert not list(tmp_path.glob(".*tmp"))


def test_a_failed_write_is_raised_in_the_loop_and_counted_as_no_checkpoint(tmp_path):
    blocker = tmp_path / "not-a-directory"
    blocker.write_text("a file where the checkpoint's folder should be")
    live, rt = core(), Runtime()
    feed(live, scenario()[:30])
    live.take_entries()
    writer = checkpoint.CheckpointWriter(rt)
    writer.submit(blocker / "learner.ckpt", live, NoGate())
    with pytest.raises(OSError):
        writer.wait()
    assert rt.counters["checkpoints"] == 0
    writer.wait()  # raised once: the next checkpoint may try again
    writer.submit(tmp_path / "learner.ckpt", live, NoGate())
    writer.wait()
    assert rt.counters["checkpoints"] == 1
