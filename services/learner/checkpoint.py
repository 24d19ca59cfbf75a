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
import threading
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


def render(tensors: dict[str, Any], meta: dict[str, Any]) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """(named arrays, header): copies that own their data, so that writing them may go on while the learner runs."""
    arrays, skeleton = flatten(tensors)
    header = {"format": FORMAT, "skeleton": json.dumps(skeleton), "meta": json.dumps(meta)}
    return {f"agent.{k}": v for k, v in arrays.items()}, header


def write(path: str | Path, arrays: dict[str, np.ndarray], header: dict[str, str]) -> int:
    """One rendered checkpoint written atomically; returns its size in bytes."""
    import safetensors.numpy

    data = safetensors.numpy.save(arrays, metadata=header)
    atomic_write(path, data)
    return len(data)


def save(path: str | Path, tensors: dict[str, Any], meta: dict[str, Any]) -> int:
    """Write the checkpoint atomically; returns its size in bytes."""
    return write(path, *render(tensors, meta))


def capture(core: Any, gate: Any, rt: Any) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """The learner's whole state (its core, its input gate, its service counters), rendered: taken between two
    inputs, it is consistent; the rendering copies every array and writes the JSON now, while nothing moves."""
    tensors, meta = core.snapshot()
    meta = {
        "core": meta,
        "gate": gate.state(),
        "service": {"counters": dict(rt.counters), "incarnation": rt.incarnation, "t_saved": time.time()},
        "config": core.config_record(),
    }
    return render(tensors, meta)


class CheckpointWriter:
    """Writes the learner's checkpoints on a thread of its own, one at a time and in order. The learner's loop only
    captures (a consistent copy); serialising and writing the file go on while it learns, so a checkpoint no
    longer stalls the steps behind it for the whole write (30-36 ms on average at 250 steps/s, at most 115 ms;
    docs/notes/2026-11-28-full-speed.md). A failed write (a full disk) is raised in the loop at the next checkpoint
    or at the end, as it was when the loop wrote the file itself."""

    def __init__(self, rt: Any):
        self.rt = rt
        self.thread: threading.Thread | None = None
        self.failure: BaseException | None = None
        # Both keys made here, on the loop's thread: the loop reads counters and samples while the writer adds to them.
        rt.counters.setdefault("checkpoints", 0)
        rt.samples["checkpoint_write_s"]  # (a defaultdict: looking the key up makes it)

    def submit(self, path: str | Path, core: Any, gate: Any) -> None:
        """Capture the learner now, then write it behind the loop's back (after the previous write is done)."""
        self.wait()
        t0 = time.perf_counter()
        rendered = capture(core, gate, self.rt)
        self.rt.samples["checkpoint_cost_s"].append(time.perf_counter() - t0)  # what the loop waited
        self.thread = threading.Thread(target=self._write, args=(path, *rendered), name="checkpoint", daemon=True)
        self.thread.start()

    def wait(self) -> None:
        """Until the write in progress is done; raises its failure."""
        if self.thread is not None:
            self.thread.join()
            self.thread = None
        if self.failure is not None:
            failure, self.failure = self.failure, None
            raise failure

    def _write(self, path: str | Path, arrays: dict[str, np.ndarray], header: dict[str, str]) -> None:
        t0 = time.perf_counter()
        try:
            write(path, arrays, header)
        except BaseException as exc:  # (raised in the loop: `wait`)
            self.failure = exc
            return
        self.rt.counters["checkpoints"] += 1
        self.rt.samples["checkpoint_write_s"].append(time.perf_counter() - t0)


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

    def __init__(self, config: Any, steps: int, rt: Any):
        self.path, self.period, self.steps_between = (
            config.checkpoint,
            config.checkpoint_period,
            config.checkpoint_steps,
        )
        self.t, self.steps = time.monotonic(), steps
        self.writer = CheckpointWriter(rt)

    def save(self, core: Any, gate: Any) -> None:
        """A checkpoint of the learner as it is now (written on the writer's thread)."""
        if self.path is None:  # (called only with a checkpoint path)
            raise ValueError("no checkpoint path configured")
        self.writer.submit(self.path, core, gate)
        self.written(core.steps_learned)

    def close(self) -> None:
        """Wait for the last checkpoint's write (raises its failure)."""
        self.writer.wait()

    def due(self, steps_learned: int) -> bool:
        return self.due_in(steps_learned) <= 0

    def due_in(self, steps_learned: int, never: float = 3600.0) -> float:
        """Seconds until the next checkpoint (`never` while too few new steps are learned)."""
        if not self.path or steps_learned - self.steps < self.steps_between:
            return never
        return self.t + self.period - time.monotonic()

    def written(self, steps_learned: int) -> None:
        self.t, self.steps = time.monotonic(), steps_learned
