"""The learner's snapshot policy: the log gets the first weights, every N steps, episode ends (numbers only),
requests (rate-limited) and the final weights; raw weights decode back."""

from __future__ import annotations

import numpy as np

from common.protocol import Request, Weights, WeightsSnapshot
from services.learner.books import Snapshots


class Item:
    def __init__(self, msg):
        self.msg = msg

    def decode(self):
        return self.msg


def test_bounded_rate_and_what_each_snapshot_holds():
    sent: list[WeightsSnapshot] = []
    snaps = Snapshots("r", "learner-1", 100, sent.append)
    tensors = {"q.0.weight": np.arange(6, dtype=np.float32).reshape(2, 3), "q.0.bias": np.zeros(2, np.float32)}
    raw = lambda v: Weights(run="r", incarnation="learner-1", version=v, t_published=1.0, tensors=tensors).encode()  # noqa: E731
    for v in range(1, 1001):  # the actor's weights after every step
        snaps.on_weights(v, tensors, raw(v))
        if v % 50 == 0:
            snaps.on_episode(v, tensors)
    req = Item(Request(run="r", what="snapshot", by="alice", t=1.0))
    snaps.on_requests([req, req], 1000, lambda: (tensors, raw(1000)))
    snaps.on_requests([req], 1000, lambda: (tensors, raw(1000)))  # within 0.5 s of the last: not again
    snaps.final(1001, tensors, raw(1001))
    reasons = [s.reason for s in sent]
    assert reasons.count("start") == 1 and reasons.count("every") == 9 and reasons.count("episode") == 20
    assert reasons.count("request") == 1 and reasons[-1] == "final" and len(sent) == 32
    for s in sent:
        WeightsSnapshot.decode(s.encode())  # valid on the wire
        assert (s.weights is None) == (s.reason == "episode")
    w = Weights.decode(sent[-1].weights)
    assert w.version == 1001 and np.array_equal(w.tensors["q.0.weight"], tensors["q.0.weight"])
    t = {x.name: x for x in sent[0].tensors}["q.0.weight"]
    assert t.shape == [2, 3] and t.mean == 2.5 and t.max == 5.0 and abs(t.norm - np.sqrt(55)) < 1e-9


def test_tensor_numbers_are_numpys_own_bit_for_bit():
    from services.learner.books import tensor_summaries

    rng = np.random.default_rng(7)
    for scale in (1e-3, 1.0, 1e3):
        tensors = {
            "w": (rng.normal(size=(19, 100)) * scale).astype(np.float32),
            "b": (rng.normal(size=(1, 6)) * scale + scale).astype(np.float32),
            "none": np.zeros((0, 4), np.float32),
        }
        for s, (name, t) in zip(tensor_summaries(tensors), tensors.items()):
            a = t.astype(np.float64)
            want = (a.mean(), a.std(), a.min(), a.max(), np.sqrt(np.sum(a * a))) if a.size else (0.0,) * 5
            assert (s.name, s.shape) == (name, list(t.shape))
            assert (s.mean, s.std, s.min, s.max, s.norm) == tuple(map(float, want))
