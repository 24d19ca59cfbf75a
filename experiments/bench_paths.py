"""The two network paths side by side: the paper's MLP as the fast numpy code (`networks.StackedMLP`) and
as a torch module trained with autograd and torch.optim (`torch_net.TorchValueNetworks`, what any other
network uses), on the same trials in one invocation (`python -m experiments bench`)."""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from experiments.runner import TrialSpec, run_trials


def bench_paths(specs: list[TrialSpec]) -> dict:
    """Run `specs` batched once per path; steps/s of each and whether the returns agree."""
    out = {"trials": len(specs)}
    returns = {}
    for path in ("mlp", "torch-mlp"):
        group = [dataclasses.replace(s, agent=dataclasses.replace(s.agent, network=path)) for s in specs]
        t0 = time.perf_counter()
        results = []
        for env in dict.fromkeys(s.env for s in group):  # one lockstep batch per environment kind
            results += run_trials([s for s in group if s.env == env])
        wall = time.perf_counter() - t0
        steps = int(sum(r.total_steps for r in results))
        out[path] = {"s": wall, "env_steps": steps, "steps_per_s": steps / wall}
        returns[path] = [r.returns for r in results]
    same = sum(np.allclose(a, b, atol=1e-6) for a, b in zip(returns["mlp"], returns["torch-mlp"]))
    out["same_returns"] = int(same)
    out["numpy_over_torch"] = out["mlp"]["steps_per_s"] / out["torch-mlp"]["steps_per_s"]
    return out


def format_paths(r: dict) -> str:
    return "\n".join(
        [
            f"network paths on the same {r['trials']} trials (the paper's MLP; one lockstep batch per env):",
            f"  numpy MLP (fast path):        {r['mlp']['s']:8.1f} s  ({r['mlp']['steps_per_s']:.0f} steps/s)",
            f"  torch MLP (autograd + optim): {r['torch-mlp']['s']:8.1f} s  ({r['torch-mlp']['steps_per_s']:.0f} "
            f"steps/s)",
            f"  numpy / torch: x{r['numpy_over_torch']:.1f}; trials with the same returns on both paths: "
            f"{r['same_returns']} of {r['trials']}",
        ]
    )
