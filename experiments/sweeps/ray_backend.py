"""A sweep's jobs as Ray tasks: one task per batched group of trials, results streamed back as they finish.

Each task is a Ray streaming generator: it runs its batch (`execute.run_job`) in a thread and yields the
batch's messages (progress, each finished trial's record, the job's timing) as they happen; the driver
waits on all generators at once and hands every message to the same handler as the local pool, which
writes each record to the sweep's cache. Ray is an optional extra (`pip install .[ray]`).
"""

from __future__ import annotations

import os
import queue
import socket
import threading
from collections.abc import Callable, Iterator

_DONE = object()


def job_messages(job_id: int, items: list) -> Iterator:
    """Run one job in a thread of this (Ray worker) process; yield its messages as they come."""
    import torch

    from experiments.sweeps.execute import run_job

    torch.set_num_threads(1)
    q: queue.Queue = queue.Queue()

    def work():
        try:
            q.put(("job", run_job(job_id, items, q.put)))
        except BaseException as exc:  # sent to the driver, which stops with the message
            q.put(("error", f"job {job_id} on {os.uname().nodename}: {type(exc).__name__}: {exc}"))
        q.put(_DONE)

    threading.Thread(target=work, daemon=True).start()
    while (msg := q.get()) is not _DONE:
        yield msg


def connect(address: str):
    """ray.init for `--ray auto|local|HOST:PORT` ('local' starts a private instance for this sweep)."""
    try:
        import ray
    except ImportError:
        raise RuntimeError("--ray needs Ray: pip install '.[ray]'") from None
    # The workers import this project: give them the driver's copy (first on their path).
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env = {"env_vars": {"PYTHONPATH": os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p)}}
    kw = dict(runtime_env=env, log_to_driver=False, configure_logging=False)
    if address not in ("auto", "local"):
        _check_reachable(address)
    try:
        if address == "local":
            ray.init(num_cpus=os.cpu_count(), include_dashboard=False, **kw)
        else:
            ray.init(address=address, **kw)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise RuntimeError(f"cannot connect to Ray at {address!r}: {str(exc).splitlines()[0]}") from None
    return ray


def cluster_cpus(address: str) -> int:
    """Connect (once) and return the cluster's CPUs: the sweep makes one batch per CPU."""
    import ray as _ray

    ray = _ray if _ray_ready() else connect(address)
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def _ray_ready() -> bool:
    try:
        import ray
    except ImportError:
        return False
    return ray.is_initialized()


def _check_reachable(address: str, timeout: float = 5.0) -> None:
    """Fail in one line when nothing listens at HOST:PORT (ray.init would wait minutes for it)."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise RuntimeError(f"--ray expects auto, local or HOST:PORT, got {address!r}")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as exc:
        raise RuntimeError(f"cannot connect to Ray at {address}: {exc.strerror or exc}") from None


def run_ray(jobs: list[list], address: str, on_message: Callable[[tuple], None]) -> list[dict]:
    """Run every job as a Ray task (one CPU each); messages go to `on_message` as they arrive."""
    import ray as _ray

    ray = _ray if _ray_ready() else connect(address)
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(job_messages)
        gens = {task.options(num_returns="streaming").remote(j, items): j for j, items in enumerate(jobs)}
        infos: list[dict] = []
        pending = list(gens)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1, timeout=None)
            for gen in ready:
                try:
                    msg = ray.get(next(gen))
                except StopIteration:
                    continue
                pending.append(gen)
                if msg[0] == "error":
                    raise RuntimeError(msg[1])
                if msg[0] == "job":
                    infos.append(msg[1])
                on_message(msg)
        return infos
    finally:
        ray.shutdown()
