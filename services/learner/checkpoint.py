"""The learner's checkpoint: one safetensors file, written atomically (temporary file + `os.replace`).

Tensors: the agent's whole learning state (`TrialBatchAgent.state_dict()`: Q and H networks, the target
network, both RMSProp states, the replay memory, D_global, the held step history, the step and update
counters that drive the epsilon / alpha_h schedules and the counter-based random streams), flattened to
named arrays (`agent.q`, `agent.replay.rec`, ...). Metadata (strings, JSON): the core's input bookkeeping
(actor incarnation and next seq, each teacher's next seq, held feedback as Feedback JSON, the step clock,
the episode in progress, counters, the ingest position), the service's input gate (announced incarnations,
dedup state, rejection counts) and its own counters, and the learner config it was taken with.

Nothing is unpickled: safetensors holds raw arrays and a JSON header; torch tensors are rebuilt with
`torch.from_numpy`.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from services.common.statefiles import atomic_write

FORMAT = "hitl.learner-checkpoint/1"
SEP = "."


def _is_torch_tensor(value: Any) -> bool:
    """Whether `value` is a torch tensor, without importing torch: the numpy agents' state has none, and importing
    torch costs a learner about 1.5 s of CPU at its first checkpoint (measured 28 November 2026)."""
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(value, torch.Tensor)


def flatten(tree: Any, prefix: str = "") -> tuple[dict[str, np.ndarray], Any]:
    """Nested dicts of torch tensors / numpy arrays / JSON scalars -> (named arrays, a JSON skeleton that says
    where each array goes and whether it was a torch tensor)."""
    arrays: dict[str, np.ndarray] = {}
    if isinstance(tree, dict):
        skeleton = {}
        for k, v in tree.items():
            if not isinstance(k, str) or SEP in k:
                raise ValueError(f"checkpoint keys must be strings without {SEP!r}: {k!r}")
            sub, sk = flatten(v, f"{prefix}{SEP}{k}" if prefix else k)
            arrays.update(sub)
            skeleton[k] = sk
        return arrays, {"dict": skeleton}
    if _is_torch_tensor(tree):
        arrays[prefix] = np.ascontiguousarray(tree.detach().cpu().numpy()).copy()
        return arrays, {"torch": prefix}
    if isinstance(tree, np.ndarray):
        arrays[prefix] = np.ascontiguousarray(tree).copy()
        return arrays, {"numpy": prefix}
    if isinstance(tree, (np.integer, np.floating, np.bool_)):
        arrays[prefix] = np.asarray(tree).copy()
        return arrays, {"scalar": prefix}
    if tree is None or isinstance(tree, (bool, int, float, str)):
        return arrays, {"json": tree}
    raise TypeError(f"cannot checkpoint {type(tree).__name__} at {prefix!r}")


def unflatten(arrays: dict[str, np.ndarray], skeleton: Any) -> Any:
    if "dict" in skeleton:
        return {k: unflatten(arrays, v) for k, v in skeleton["dict"].items()}
    if "torch" in skeleton:  # (a torch network's state: torch is loaded only then)
        import torch

        return torch.from_numpy(np.array(arrays[skeleton["torch"]], copy=True))
    if "numpy" in skeleton:
        return np.array(arrays[skeleton["numpy"]], copy=True)
    if "scalar" in skeleton:
        return np.array(arrays[skeleton["scalar"]], copy=True)[()]
    return skeleton["json"]


def save(path: str | Path, tensors: dict[str, Any], meta: dict[str, Any]) -> int:
    """Write the checkpoint atomically; returns its size in bytes."""
    import safetensors.numpy

    arrays, skeleton = flatten(tensors)
    header = {"format": FORMAT, "skeleton": json.dumps(skeleton), "meta": json.dumps(meta)}
    data = safetensors.numpy.save({f"agent.{k}": v for k, v in arrays.items()}, metadata=header)
    atomic_write(path, data)
    return len(data)


def save_learner(path: str | Path | None, core: Any, gate: Any, rt: Any) -> None:
    """The learner's whole state (its core, its input gate, its service counters) saved atomically at `path`."""
    if path is None:  # (called only with a checkpoint path)
        raise ValueError("no checkpoint path configured")
    t0 = time.perf_counter()
    tensors, meta = core.snapshot()
    meta = {
        "core": meta,
        "gate": gate.state(),
        "service": {"counters": dict(rt.counters), "incarnation": rt.incarnation, "t_saved": time.time()},
        "config": core.config_record(),
    }
    save(path, tensors, meta)
    rt.counters["checkpoints"] += 1
    rt.samples["checkpoint_cost_s"].append(time.perf_counter() - t0)


def load(path: str | Path) -> tuple[dict[str, Any], dict[str, Any]] | None:
    """(tensors, meta) from a checkpoint file, or None if there is none. A damaged file raises."""
    import safetensors
    import safetensors.numpy

    path = Path(path)
    if not path.exists():
        return None
    with safetensors.safe_open(str(path), framework="numpy") as f:
        header = f.metadata() or {}
    if header.get("format") != FORMAT:
        raise ValueError(f"{path}: not a learner checkpoint ({header.get('format')!r})")
    arrays = {k[len("agent.") :]: v for k, v in safetensors.numpy.load_file(str(path)).items()}
    return unflatten(arrays, json.loads(header["skeleton"])), json.loads(header["meta"])


class CheckpointSchedule:
    """When the learner writes its checkpoint: every `checkpoint_period` s at most, once `checkpoint_steps` new
    steps are learned. A paced run does not rewrite its whole state every few seconds for a step or two (362 ms a
    checkpoint in one measured run); a learner restarted from an older checkpoint catches up from the log."""

    def __init__(self, config: Any, steps: int):
        self.path, self.period, self.steps_between = (
            config.checkpoint,
            config.checkpoint_period,
            config.checkpoint_steps,
        )
        self.t, self.steps = time.monotonic(), steps

    def due(self, steps_learned: int) -> bool:
        return self.due_in(steps_learned) <= 0

    def due_in(self, steps_learned: int, never: float = 3600.0) -> float:
        """Seconds until the next checkpoint (`never` while too few new steps are learned)."""
        if not self.path or steps_learned - self.steps < self.steps_between:
            return never
        return self.t + self.period - time.monotonic()

    def written(self, steps_learned: int) -> None:
        self.t, self.steps = time.monotonic(), steps_learned
