"""Q and H as any torch `nn.Module`, one per trial, trained with autograd and `torch.optim.RMSprop`.

`--agent.network` picks the module: `mlp` (the paper's one-hidden-layer tanh MLP; on the default `auto`
path it runs as the fast numpy code of `networks.py` instead), `torch-mlp` (the same MLP on this torch
path: same initial weights, same updates, a test checks it), `cnn` (a small CNN for image observations,
the default for them), or `module:factory`. A factory's contract:

    factory(obs_shape: tuple[int, ...], n_actions: int, hidden: int) -> torch.nn.Module

called once per trial with torch's global generator seeded from the trial seed (so its default
initialisation is reproducible); the module maps a float32 batch [N, prod(obs_shape)] (flat
observations, as replay stores them; reshape inside if you need the image) to [N, n_actions].

Each trial has its own module, target copy and `torch.optim.RMSprop` on `--agent.device` (cpu, cuda);
a gradient step on some trials sums their losses (each trial's gradient is its own) and steps their
optimisers only, so a trial learns the same alone or among others.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from common.agents.config import NETWORKS, resolve_network  # noqa: F401 (resolve_network: re-exported)
from common.agents.mlp import init_mlp
from common.agents.networks import ValueNetworks


class PaperMLP(nn.Module):
    """in -> hidden (tanh) -> out, laid out as `networks.StackedMLP` (x @ w1 + b1), same initialisation."""

    def __init__(self, in_dim: int, hidden: int, out_dim: int, seed: int | None = None):
        super().__init__()
        p = {k: torch.from_numpy(v) for k, v in init_mlp(in_dim, hidden, out_dim, 0 if seed is None else seed).items()}
        self.w1, self.b1 = nn.Parameter(p["w1"]), nn.Parameter(p["b1"])
        self.w2, self.b2 = nn.Parameter(p["w2"]), nn.Parameter(p["b2"])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.tanh(x @ self.w1 + self.b1) @ self.w2 + self.b2


class GridCNN(nn.Module):
    """Two 3x3 convolutions (16, 32 channels, ReLU) over a (height, width, channels) image, then a dense
    layer of `hidden` ReLU units: small enough for MiniGrid's 7x7x3 view on a CPU."""

    def __init__(self, obs_shape: tuple[int, ...], n_actions: int, hidden: int):
        super().__init__()
        if len(obs_shape) != 3:
            raise ValueError(f"cnn needs image observations (height, width, channels), got shape {obs_shape}")
        self.shape = tuple(int(s) for s in obs_shape)
        h, w, c = self.shape
        pad = 1 if min(h, w) < 5 else 0
        self.conv = nn.Sequential(
            nn.Conv2d(c, 16, 3, padding=pad), nn.ReLU(), nn.Conv2d(16, 32, 3, padding=pad), nn.ReLU(), nn.Flatten()
        )
        with torch.no_grad():
            n_flat = self.conv(torch.zeros(1, c, h, w)).shape[1]
        self.head = nn.Sequential(nn.Linear(n_flat, hidden), nn.ReLU(), nn.Linear(hidden, n_actions))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        image = x.reshape(-1, *self.shape).permute(0, 3, 1, 2)
        return self.head(self.conv(image))


def network_factory(name: str) -> Callable[[tuple[int, ...], int, int], nn.Module]:
    """(obs_shape, n_actions, hidden) -> module, for a network name or `module:factory`."""
    if name in ("mlp", "torch-mlp"):
        return lambda shape, n, hidden: PaperMLP(int(np.prod(shape)), hidden, n)
    if name == "cnn":
        return GridCNN
    if ":" not in name:
        raise ValueError(f"unknown network {name!r}; choose one of {', '.join(NETWORKS)} or give module:factory")
    from common.envs.rules import load_object

    return load_object(name, "network factory")


def build_modules(
    name: str, obs_shape: tuple[int, ...], n_actions: int, hidden: int, seeds: list[int]
) -> list[nn.Module]:
    """One module per trial, each initialised from its own seed; a bad factory is a one-line error."""
    factory = network_factory(name)
    modules = []
    for seed in seeds:
        if name in ("mlp", "torch-mlp"):
            modules.append(PaperMLP(int(np.prod(obs_shape)), hidden, n_actions, seed))
            continue
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(seed) % (2**63))
            try:
                module = factory(tuple(obs_shape), int(n_actions), int(hidden))
            except Exception as exc:
                raise ValueError(f"network factory {name!r} failed: {type(exc).__name__}: {exc}") from None
        if not isinstance(module, nn.Module):
            raise ValueError(f"network factory {name!r} returned {type(module).__name__}, not a torch.nn.Module")
        modules.append(module.float())
    probe = modules[0](torch.zeros(2, int(np.prod(obs_shape))))
    if tuple(probe.shape) != (2, n_actions):
        raise ValueError(
            f"network {name!r} maps [N, {int(np.prod(obs_shape))}] to {tuple(probe.shape)}, not [N, {n_actions}]"
        )
    return modules


class TorchValueNetworks:
    """`networks.ValueNetworks` over B trials' torch modules, each with its own `torch.optim.RMSprop`
    (none for a target network).

    A list, not one stacked module: each trial's module is called as it is (any nn.Module works, buffers
    and all), and at the paper's sizes a plain call costs far less than a vmapped functional one."""

    def __init__(
        self,
        modules: list[nn.Module],
        n_actions: int,
        lr: float | None = None,
        alpha: float = 0.99,
        eps: float = 1e-8,
        device: str = "cpu",
    ):
        self.device = torch.device(device)
        self.n_actions = int(n_actions)
        self.modules = [m.to(self.device) for m in modules]
        self.opts = (
            [torch.optim.RMSprop(m.parameters(), lr=lr, alpha=alpha, eps=eps) for m in self.modules]
            if lr is not None
            else None
        )
        if self.opts is None:
            for m in self.modules:
                m.requires_grad_(False)

    @property
    def trials(self) -> int:
        return len(self.modules)

    def forward(self, rows: np.ndarray | None, x) -> torch.Tensor:
        """x [n, N, obs] -> values [n, N, A] (a tensor, with autograd) for trials `rows` (all when None)."""
        x = torch.as_tensor(np.asarray(x, np.float32), device=self.device)
        order = range(self.trials) if rows is None else rows
        out = [self.modules[int(r)](x[k]) for k, r in enumerate(order)]
        return out[0].unsqueeze(0) if len(out) == 1 else torch.stack(out)

    def values(self, rows: np.ndarray | None, x: np.ndarray, x1: np.ndarray | None = None) -> np.ndarray:
        """(`ValueNetworks.values`; x1, the input with its bias column, is not needed here.)"""
        with torch.no_grad():
            return self.forward(rows, x).cpu().numpy()

    def fit(self, job) -> None:
        """One RMSprop step of trials `job.rows` on the job's loss (summed over its trials: each trial's
        gradient is its own); the other trials are not touched."""
        if self.opts is None:
            raise RuntimeError("this network is not trained (a target network is synced, never fitted)")
        opts = self.opts
        pred = self.forward(job.rows, job.x)
        actions = torch.as_tensor(np.asarray(job.actions, np.int64), device=self.device).unsqueeze(-1)
        pred = pred.gather(-1, actions).squeeze(-1)
        target = torch.as_tensor(np.asarray(job.targets, np.float32), device=self.device)
        if job.loss.kind == "huber":  # its gradient is the error clipped to [-1, 1]
            per_row = F.smooth_l1_loss(pred, target, reduction="none", beta=1.0)
        else:
            weights = torch.as_tensor(np.asarray(job.weights, np.float32), device=self.device)
            per_row = weights * (pred - target) ** 2
        loss = per_row.mean(dim=1) if job.loss.reduce == "mean" else per_row.sum(dim=1)
        for r in job.rows:
            opts[int(r)].zero_grad(set_to_none=True)
        loss.sum().backward()
        for r in job.rows:
            opts[int(r)].step()

    def sync_from(self, other: ValueNetworks, rows: np.ndarray) -> None:
        if not isinstance(other, TorchValueNetworks):
            raise TypeError(f"a torch network syncs from another, not from {type(other).__name__}")
        for r in rows:
            self.modules[int(r)].load_state_dict(other.modules[int(r)].state_dict())

    def select(self, rows: np.ndarray) -> None:
        """Keep trials `rows` (modules and optimisers), in that order."""
        keep = [int(r) for r in rows]
        self.modules = [self.modules[r] for r in keep]
        if self.opts is not None:
            self.opts = [self.opts[r] for r in keep]

    def policy_state(self, row: int) -> dict[str, np.ndarray]:
        return {k: v.detach().cpu().numpy().copy() for k, v in self.modules[row].state_dict().items()}

    def load_policy_state(self, row: int, state: dict) -> None:
        own = self.modules[row].state_dict()
        tensors = {}
        for k, v in own.items():
            if k not in state:
                raise ValueError(f"weights: missing {k}")
            a = np.asarray(state[k])
            if tuple(a.shape) != tuple(v.shape):
                raise ValueError(f"weights {k}: expected shape {tuple(v.shape)}, got {tuple(a.shape)}")
            tensors[k] = torch.as_tensor(a)
        self.modules[row].load_state_dict(tensors)

    def state_dict(self) -> dict:
        """Weights and RMSprop state as nested dicts of tensors with dot-free string keys (what the learner's
        checkpoint stores): {"t<k>": {"w": {name: tensor}, "sq": {i: square_avg}, "step": {i: step}}}."""
        out = {}
        for k, m in enumerate(self.modules):
            trial = {"w": {n.replace(".", "/"): v.detach().cpu().clone() for n, v in m.state_dict().items()}}
            if self.opts is not None:
                states = [self.opts[k].state.get(p, {}) for p in m.parameters()]
                trial["sq"] = {str(i): st["square_avg"].detach().cpu().clone() for i, st in enumerate(states) if st}
                trial["step"] = {
                    str(i): torch.as_tensor(st["step"]).detach().cpu().clone() for i, st in enumerate(states) if st
                }
            out[f"t{k}"] = trial
        return out

    def load_state_dict(self, state: dict) -> None:
        for k, m in enumerate(self.modules):
            trial = state[f"t{k}"]
            m.load_state_dict({n.replace("/", "."): torch.as_tensor(v) for n, v in trial["w"].items()})
            if self.opts is None:
                continue
            for i, p in enumerate(m.parameters()):
                if str(i) in trial.get("sq", {}):
                    self.opts[k].state[p] = {
                        "step": torch.as_tensor(trial["step"][str(i)]).clone(),
                        "square_avg": torch.as_tensor(trial["sq"][str(i)]).to(self.device),
                    }


def param_count(module: nn.Module) -> int:
    return sum(math.prod(p.shape) for p in module.parameters())
