"""The agent's parts, each alone: value networks (gradients against torch autograd, stacked fits, shapes that
differ), replay, explorer and mixture, and an agent assembled from parts passed in."""

import math

import numpy as np
import pytest
import torch

from common.agents import AgentParts, TrialBatchAgent, agent_config, build_parts
from common.agents.explorer import EpsilonGreedy, Mixture, UniformBlocks, to_integers, uniforms
from common.agents.memory import TransitionReplay
from common.agents.mlp import init_mlp, mlp_backward, mlp_forward, with_ones
from common.agents.networks import HUBER_MEAN, SQUARED_MEAN, SQUARED_SUM, FitJob, FlatRMSProp, StackedMLP, fit_together


@pytest.mark.parametrize("seed", [0, 5, 2**31 - 1, 2**32 + 7, 12345678901234, 2**63 - 1])
@pytest.mark.parametrize("dims", [(2, 100, 4), (519, 100, 6), (1, 1, 1), (17, 33, 5)])
def test_the_numpy_initialisation_is_torchs_bit_for_bit(seed, dims):
    """`init_mlp` draws torch's numbers without torch: the same bits as a seeded torch generator with nn.Linear's
    default bounds (1/sqrt(fan_in)), in the order torch draws them."""
    in_dim, hidden, out_dim = dims
    g = torch.Generator().manual_seed(seed % (2**63))
    layers = [
        ("w1", (in_dim, hidden), in_dim),
        ("b1", (1, hidden), in_dim),
        ("w2", (hidden, out_dim), hidden),
        ("b2", (1, out_dim), hidden),
    ]
    got = init_mlp(in_dim, hidden, out_dim, seed)
    for name, shape, fan_in in layers:
        want = (torch.rand(*shape, generator=g) * 2 - 1) * (1.0 / math.sqrt(fan_in))
        assert got[name].dtype == np.float32 and got[name].shape == shape
        assert np.array_equal(got[name].view(np.uint32), want.numpy().view(np.uint32)), name


def one_hot_rows(rng, n, N, width, hot):
    """[n, N, width] float32 rows with `hot` ones each (Taxi's kind of input); a few rows also hold other values."""
    x = np.zeros((n, N, width), np.float32)
    for i in range(n):
        for j in range(N):
            x[i, j, rng.choice(width, hot, replace=False)] = 1.0
    x[:, 0, :3] = rng.standard_normal((n, 3))
    return x


@pytest.mark.parametrize("dims", [(3, 5, 4), (519, 100, 6)])
def test_mlp_gradient_is_autograds(dims):
    """Dense inputs (the maze) and wide one-hot ones taken as row lookups and scatter-adds (`mlp.rows_forward`)."""
    in_dim, hidden_dim, out_dim = dims
    net = StackedMLP(in_dim, hidden_dim, out_dim, [1, 2])
    rng = np.random.default_rng(0)
    x = rng.standard_normal((2, 6, 3)).astype(np.float32) if in_dim == 3 else one_hot_rows(rng, 2, 6, in_dim, 5)
    x[1, 2] = 0.0  # (a row with no input set: only its bias)
    d_out = rng.standard_normal((2, 6, out_dim)).astype(np.float32)
    hidden, out = mlp_forward(net.params, x)
    grad = mlp_backward(net.params, x, hidden, d_out)
    for i in range(2):
        p = {k: torch.tensor(net.params[k][i], requires_grad=True) for k in ("w1", "b1", "w2", "b2")}
        y = torch.tanh(torch.from_numpy(x[i]) @ p["w1"] + p["b1"]) @ p["w2"] + p["b2"]
        np.testing.assert_allclose(y.detach().numpy(), out[i], rtol=1e-5, atol=1e-6)
        (y * torch.from_numpy(d_out[i])).sum().backward()
        expected = torch.cat([p[k].grad.reshape(-1) for k in ("w1", "b1", "w2", "b2")]).numpy()
        np.testing.assert_allclose(grad[i], expected, rtol=1e-4, atol=1e-5)


def fresh_pair(shape_h=(3, 5, 4)):
    q = StackedMLP(3, 5, 4, [1, 2, 3], FlatRMSProp(1e-2))
    h = StackedMLP(*shape_h, [4, 5, 6], FlatRMSProp(1e-2))
    return q, h


def jobs_for(q, h, rng):
    x = rng.standard_normal((2, 8, 3)).astype(np.float32)
    a = rng.integers(0, 4, (2, 8))
    t = rng.standard_normal((2, 8)).astype(np.float32)
    w = rng.random((2, 8)).astype(np.float32)
    return [
        FitJob(q, np.array([0, 2]), x, a, t, None, HUBER_MEAN),
        FitJob(h, np.array([1, 2]), x, a, t, w, SQUARED_MEAN),
    ]


def test_fitting_q_and_h_together_equals_fitting_them_apart():
    rng = np.random.default_rng(1)
    q1, h1 = fresh_pair()
    q2, h2 = fresh_pair()
    for _ in range(3):
        state = rng.bit_generator.state
        fit_together(jobs_for(q1, h1, rng))
        rng.bit_generator.state = state
        for job in jobs_for(q2, h2, rng):
            job.net.fit(job)
    assert np.array_equal(q1.flat, q2.flat) and np.array_equal(h1.flat, h2.flat)
    untouched = StackedMLP(3, 5, 4, [1, 2, 3])
    assert np.array_equal(q1.flat[1], untouched.flat[1])  # row 1 of Q was never asked to step


def test_q_and_h_of_different_shapes_fit_side_by_side():
    rng = np.random.default_rng(2)
    q, h = fresh_pair(shape_h=(3, 7, 4))
    before = q.flat.copy(), h.flat.copy()
    fit_together(jobs_for(q, h, rng))
    assert not np.array_equal(q.flat, before[0]) and not np.array_equal(h.flat, before[1])
    assert h.values(None, np.zeros((3, 1, 3), np.float32)).shape == (3, 1, 4)


def test_squared_sum_loss_is_the_weighted_sum():
    net = StackedMLP(2, 4, 3, [7], FlatRMSProp(1e-2))
    x = np.array([[[0.5, -1.0], [1.0, 0.0]]], np.float32)
    f, w = np.array([[1.0, -1.0]], np.float32), np.array([[0.25, 0.75]], np.float32)
    pred = net.values(None, x)[0, [0, 1], [1, 2]]
    d = SQUARED_SUM.grad(pred[None].astype(np.float32), f, w)
    np.testing.assert_allclose(d[0], 2 * w[0] * (pred - f[0]), rtol=1e-6)
    np.testing.assert_allclose(SQUARED_MEAN.grad(pred[None].astype(np.float32), f, w), d / 2, rtol=1e-6)
    assert np.all(
        np.abs(HUBER_MEAN.grad(np.array([[5.0, -5.0]], np.float32), np.zeros((1, 2), np.float32), None)) == 0.5
    )


def test_replay_rows_are_independent_and_sample_their_own_stream():
    r = TransitionReplay(2, 4, 1)
    for k in range(6):
        r.add_rows(np.array([0]), obs=[[k]], action=[k % 2], reward=[k], next_obs=[[k + 1]], terminated=[0.0])
    assert r.size.tolist() == [4, 0] and sorted(r.data["reward"][0].tolist()) == [2.0, 3.0, 4.0, 5.0]
    blocks = UniformBlocks(np.array([11, 12], np.uint64), 5, block=8)
    u = blocks.get(np.array([0, 1]), np.array([3, 3]))
    assert np.array_equal(u, uniforms(np.array([[11], [12]], np.uint64), 3 * 5 + np.arange(5)))  # same values
    assert np.array_equal(blocks.get(np.array([1]), np.array([3]))[0], u[1])  # trial 1 alone: its own draws
    idx = to_integers(u[:1], r.size[:1, None])
    rec = r.gather_records(np.array([0]), idx)
    assert rec.shape == (1, 5, r.width) and idx.max() < 4


def test_replay_holds_each_observation_with_its_bias_input_and_fits_use_it_unchanged():
    r = TransitionReplay(1, 8, 3)
    rng = np.random.default_rng(2)
    for k in range(8):
        r.add_rows(
            np.array([0]),
            obs=rng.standard_normal((1, 3)),
            action=[k % 4],
            reward=[k],
            next_obs=rng.standard_normal((1, 3)),
            terminated=[0.0],
        )
    rec = r.gather_records(np.array([0]), np.arange(8)[None, :])
    assert np.array_equal(rec[:, :, r.with_ones["obs"]], with_ones(r.data["obs"][:1]))
    assert np.array_equal(rec[:, :, r.with_ones["next_obs"]], with_ones(r.data["next_obs"][:1]))
    nets = [StackedMLP(3, 5, 4, [7]) for _ in range(2)]
    for net in nets:
        net.opt = FlatRMSProp()
        net.opt.attach(net.flat.shape)
    targets = rng.standard_normal((1, 8)).astype(np.float32)
    x, actions = rec[:, :, r.columns["obs"]], rec[:, :, r.at["action"]].astype(np.int64)
    for net, x1 in zip(nets, (None, rec[:, :, r.with_ones["obs"]])):  # the same step, given the bias input or not
        fit_together([FitJob(net, np.array([0]), x, actions, targets, None, HUBER_MEAN, x1)])
    assert np.array_equal(nets[0].flat, nets[1].flat) and not np.array_equal(
        nets[0].flat, StackedMLP(3, 5, 4, [7]).flat
    )


def test_explorer_and_mixture_are_functions_of_the_step():
    cfgs = [agent_config("dqn-tamer"), agent_config("deep-tamer")]
    e = EpsilonGreedy(cfgs, np.array([5, 6], np.uint64), 4)
    rows = np.arange(2)
    np.testing.assert_allclose(e.epsilons(rows, np.array([0, 150])), [0.3, 0.15])
    np.testing.assert_allclose(e.epsilons(rows, np.array([10_000, 10_000])), [0.1, 0.1])
    greedy = np.array([2, 3])
    a1 = [e.choose(rows, np.array([t, t]), greedy) for t in range(200)]
    e2 = EpsilonGreedy(cfgs, np.array([5, 6], np.uint64), 4)
    a2 = [e2.choose(rows, np.array([t, t]), greedy) for t in range(200)]
    assert all(np.array_equal(x, y) for x, y in zip(a1, a2))
    explored = np.mean([x[0] != 2 for x in a1])
    assert 0.1 < explored < 0.4  # epsilon near 0.3 -> 0.1, three actions of four differ from the greedy one
    m = Mixture(cfgs)
    aq, ah = m.weights(rows, np.array([100, 100]))
    assert aq.ravel().tolist() == [1.0, 0.0]
    np.testing.assert_allclose(ah.ravel(), [0.9999**100, 1.0], rtol=1e-6)


def test_an_agent_takes_the_parts_it_is_given():
    cfg = [agent_config("dqn-tamer")]
    parts = build_parts(cfg, 2, 4, [0])
    parts.h = StackedMLP(2, 9, 4, [123], FlatRMSProp(1e-3))  # an H of another shape
    agent = TrialBatchAgent(cfg, 2, 4, [0], parts=parts)
    assert isinstance(agent.parts, AgentParts) and agent.h is parts.h
    for k in range(40):
        agent.record_step(
            0, np.array([k % 3, 1], np.float32), k % 4, -0.1, np.array([k % 3, 0], np.float32), False, float(k)
        )
        agent.give_feedback([(0, k + 0.5, 1)])
        agent.update()
    assert agent.h_updates[0] > 40 and agent.q_updates[0] > 0
    assert agent.policy_weights(0)["h.w1"].shape == (2, 9)


def test_batched_trials_must_share_structure():
    with pytest.raises(ValueError, match="share hidden"):
        TrialBatchAgent([agent_config("dqn"), agent_config("dqn", hidden=50)], 2, 4, [0, 1])


def test_the_teachers_reliability_lowers_alpha_h_only_for_the_teacher_q_contradicts():
    """Two trials (two teachers) with the reliability on, one paper row: before `alpha_h_trust_after`
    nothing counts; after it, the contradicted teacher's alpha_h falls to its reliability / ref, the confirmed
    one keeps the paper's schedule, and the paper row never changes."""
    trusting = agent_config("dqn-tamer", alpha_h_trust=0.1, alpha_h_trust_after=50, alpha_h_trust_ref=0.5)
    m = Mixture([trusting, trusting, agent_config("dqn-tamer")])
    rows, paper = np.arange(3), 0.9999 ** np.array([60, 60, 60])
    early = np.array([10, 10, 10])
    for _ in range(100):
        m.observe(rows, np.array([False, True, False]), early)
    np.testing.assert_allclose(m.alpha_h(rows, np.array([60, 60, 60])), paper)  # Q has not learned yet
    late = np.array([60, 60, 60])
    for _ in range(100):
        m.observe(rows, np.array([False, True, False]), late)
    ah = m.alpha_h(rows, late)
    assert ah[0] < 0.01 * paper[0] and ah[1] == pytest.approx(paper[1]) and ah[2] == pytest.approx(paper[2])
    state = m.state_dict()
    other = Mixture([trusting, trusting, agent_config("dqn-tamer")])
    other.load_state_dict(state)
    np.testing.assert_allclose(other.alpha_h(rows, late), ah)
    with pytest.raises(ValueError, match="alpha_h_trust"):
        agent_config("dqn-tamer", alpha_h_trust_ref=0.0)


@pytest.mark.parametrize("rows", [None, slice(1, 3), np.array([0, 2])])
def test_rmsprop_on_touched_rows_is_the_dense_step_bit_for_bit(rows):
    """A wide first layer's gradient is zero outside the rows of its inputs that were set: stepping only those
    (and decaying every running average) gives the same bits as the dense step, weights and averages."""
    rng = np.random.default_rng(3)
    count, width, tail = 6, 4, 5
    flat = rng.standard_normal((3, count * width + tail)).astype(np.float32)
    n = 3 if rows is None else 2
    grad = np.zeros((n, count * width + tail), np.float32)
    keys = np.array([1, 4, 6, 11]) if n == 3 else np.array([0, 5, 7])
    grad[:, : count * width].reshape(n, count, width)[keys // count, keys % count] = rng.standard_normal(
        (len(keys), width)
    )
    grad[:, count * width :] = rng.standard_normal((n, tail))
    dense, blocked = FlatRMSProp(1e-2), FlatRMSProp(1e-2)
    weights, start_avg = {}, rng.random(flat.shape).astype(np.float32)
    for name, opt, blocks in (("dense", dense, None), ("blocked", blocked, (count, width, keys))):
        opt.attach(flat.shape)
        opt.square_avg[...] = start_avg
        weights[name] = w = flat.copy()
        for _ in range(3):
            opt.step_rows(w, rows, grad, blocks)
    assert np.array_equal(weights["dense"], weights["blocked"]) and not np.array_equal(weights["dense"], flat)
    assert np.array_equal(dense.square_avg, blocked.square_avg)
