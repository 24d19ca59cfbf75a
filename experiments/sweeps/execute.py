"""Running a sweep's trials: the cache, batched jobs, a local process pool (default) or Ray, one progress bar.

Cache: one JSON file per distinct trial, `cache/<key[:2]>/<key>.json`, where the key hashes everything
that determines the result (`experiments.trialcache.trial_key`: environment, layout, seed, episodes, agent,
observer and teacher rule unless the agent ignores feedback). Cells whose trials are
identical (DQN under two observers) share them, an interrupted sweep resumes with only the missing
trials, and a repeated one only re-plots.

The workers (processes here, or Ray tasks) only compute: each finished trial's record is sent back to
this process, which writes it to the cache at once. So a Ray cluster needs no shared file system.

Batching: missing trials are grouped into lockstep batches by environment, split over the workers
(`experiments.trialcache.make_jobs`); results do not depend on the batching.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import platform
import queue
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from collections.abc import Callable, Hashable, Iterable

from experiments.trialcache import Task, make_jobs, read_cached, result_record, trial_key, write_json_atomic
from experiments.runner import TrialSpec, run_trials
from experiments.sweeps.grid import Sweep

Emit = Callable[[tuple], None]


def sweep_key(spec: TrialSpec) -> str:
    """The reproduction's key (environment, layout, seed, episodes, agent; observer and teacher rule
    unless the agent ignores feedback), so sweeps and the reproduction can share trials."""
    return trial_key(spec)


def cache_path(cache_dir: str, key: str) -> str:
    return os.path.join(cache_dir, key[:2], f"{key}.json")


Slot = Hashable  # what a result fills: (cell, trial) in a sweep, (condition, arm, trial) in the reproduction
PathOf = Callable[[Slot, str], str]  # (slot, key) -> its cache file


@dataclass
class Plan:
    records: dict[Slot, dict]  # slot -> cached record
    todo: list[Task]  # distinct trials to compute
    slots: dict[str, list[Slot]] = field(default_factory=dict)  # key of a trial to compute -> slots it fills
    reused: int = 0  # slots filled from another slot's file with the same key (copied to their own)

    @property
    def missing(self) -> int:
        return sum(len(self.slots[t.key]) for t in self.todo)


def sweep_slots(sweep: Sweep) -> list[tuple[Slot, TrialSpec]]:
    return [((cell.index, k), sweep.spec(cell, k)) for cell in sweep.cells() for k in range(sweep.trials)]


def by_key(cache_dir: str) -> PathOf:
    """A sweep's cache: one file per distinct trial, whatever slots it fills."""
    return lambda slot, key: cache_path(cache_dir, key)


def plan(slot_specs: Iterable[tuple[Slot, TrialSpec]], path_of: PathOf) -> Plan:
    """Which slots' results are cached, and the distinct trials still to run. A slot whose own file is
    missing but whose trial is cached under another slot (same key) gets a copy of that file."""
    records: dict[Slot, dict] = {}
    pending: dict[str, list[tuple[Slot, TrialSpec]]] = {}
    known: dict[str, dict] = {}
    read: dict[str, dict | None] = {}
    for slot, spec in slot_specs:
        key = sweep_key(spec)
        path = path_of(slot, key)
        if path not in read:
            read[path] = read_cached(path, key)
        if read[path] is not None:
            records[slot] = known[key] = read[path]
        else:
            pending.setdefault(key, []).append((slot, spec))
    todo, slots, reused = [], {}, 0
    for key, items in pending.items():
        if key in known:
            for slot, _ in items:
                write_json_atomic(path_of(slot, key), known[key])
                records[slot] = known[key]
                reused += 1
        else:
            todo.append(Task(key, items[0][1]))
            slots[key] = [slot for slot, _ in items]
    return Plan(records, todo, slots, reused)


# ---------------------------------------------------------------------------------- one job
def run_job(job_id: int, items: list[tuple[str, TrialSpec, int]], emit: Emit) -> dict:
    """Run one batch of (key, spec, weight) trials in lockstep. Sends ("progress", trials) as episodes
    end (weighted: a trial filling w cells counts w), ("trial", key, record, trials already reported) as
    each trial finishes. Returns the job's timing."""
    specs = [s for _, s, _ in items]
    reported = [0.0] * len(items)
    unsent = [0.0]
    last = [time.perf_counter()]

    def on_episode(i: int, _record: dict) -> None:
        step = items[i][2] / max(specs[i].episodes, 1)
        reported[i] += step
        unsent[0] += step
        if time.perf_counter() - last[0] > 0.25:
            emit(("progress", unsent[0]))
            unsent[0] = 0.0
            last[0] = time.perf_counter()

    def on_trial_done(i: int, result) -> None:
        emit(("progress", unsent[0]))
        unsent[0] = 0.0
        emit(("trial", items[i][0], result_record(items[i][0], result), reported[i]))

    t0, c0, started_at = time.perf_counter(), time.process_time(), time.time()
    profile: dict = {}
    results = run_trials(specs, on_episode=on_episode, on_trial_done=on_trial_done, profile=profile)
    return {
        "job": job_id,
        "pid": os.getpid(),
        "host": platform.node(),
        "env": specs[0].env,
        "trials": len(specs),
        "wall_s": time.perf_counter() - t0,
        "cpu_s": time.process_time() - c0,
        "started_at": started_at,
        "ended_at": time.time(),  # epoch seconds: how the workers' ends spread
        "trial_steps": int(sum(r.total_steps for r in results)),
        "max_trial_steps": int(max(r.total_steps for r in results)),
        "by_running_trials": profile,
    }


# ------------------------------------------------------------------------------ local pool
def _worker(jobs_q, msg_q, parent: int) -> None:
    import torch

    torch.set_num_threads(1)

    def emit(msg):
        if os.getppid() != parent:  # the sweep is gone: stop (what it received is cached)
            raise SystemExit(1)
        msg_q.put(msg)

    while (item := jobs_q.get()) is not None:
        try:
            msg_q.put(("job", run_job(item[0], item[1], emit)))
        except Exception as exc:  # reported to the sweep, which stops with the message
            msg_q.put(("error", f"job {item[0]}: {type(exc).__name__}: {exc}"))
            raise


def run_local(jobs: list[list], workers: int, on_message: Emit) -> list[dict]:
    """Run jobs on `workers` spawned processes (in this process when workers <= 1)."""
    if workers <= 1:
        infos = []
        for j, items in enumerate(jobs):
            infos.append(run_job(j, items, on_message))
            on_message(("job", infos[-1]))
        return infos
    ctx = mp.get_context("spawn")
    jobs_q, msg_q = ctx.Queue(), ctx.Queue()
    procs = [
        ctx.Process(target=_worker, args=(jobs_q, msg_q, os.getpid()), daemon=True)
        for _ in range(min(workers, len(jobs)))
    ]
    main_thread = threading.current_thread() is threading.main_thread()
    old_term = signal.signal(signal.SIGTERM, _raise_exit) if main_thread else None
    for p in procs:
        p.start()
    for j, items in enumerate(jobs):
        jobs_q.put((j, items))
    for _ in procs:
        jobs_q.put(None)
    infos: list[dict] = []
    try:
        while len(infos) < len(jobs):
            try:
                msg = msg_q.get(timeout=1.0)
            except queue.Empty:
                dead = [p for p in procs if not p.is_alive() and p.exitcode not in (0, None)]
                if dead:
                    raise RuntimeError(f"a worker died (exit code {dead[0].exitcode})") from None
                continue
            if msg[0] == "error":
                raise RuntimeError(msg[1])
            if msg[0] == "job":
                infos.append(msg[1])
            on_message(msg)
    finally:
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(timeout=5)
        if old_term is not None:
            signal.signal(signal.SIGTERM, old_term)
    return infos


def _raise_exit(signum, frame):
    raise SystemExit(128 + signum)


# ----------------------------------------------------------------------------------- driver
@dataclass
class RunStats:
    cell_trials: int
    computed: int  # distinct trials simulated
    filled: int  # (cell, trial) results filled by them
    cached: int  # (cell, trial) results read from the cache
    run_s: float
    jobs: list[dict]
    backend: str
    reused: int = 0  # of the cached: copied from another slot's file with the same trial


def execute(
    sweep: Sweep,
    cache_dir: str,
    workers: int = 2,
    ray_address: str | None = None,
    progress: bool = True,
    on_trial: Callable[[int, int], None] | None = None,
) -> tuple[Plan, RunStats]:
    """Compute every missing trial of the sweep; see `run_slots`."""
    return run_slots(sweep_slots(sweep), by_key(cache_dir), workers, ray_address, progress, on_trial)


def run_slots(
    slot_specs: list[tuple[Slot, TrialSpec]],
    path_of: PathOf,
    workers: int = 2,
    ray_address: str | None = None,
    progress: bool = True,
    on_trial: Callable[[int, int], None] | None = None,
) -> tuple[Plan, RunStats]:
    """Compute every missing trial (writing it to its slots' cache files as it arrives); return the
    full plan. `on_trial(done, total)` is called as trials arrive (an exception from it stops the run;
    what arrived stays cached)."""
    p = plan(slot_specs, path_of)
    total = len(slot_specs)
    done0 = len(p.records)
    items = {t.key: (t.key, t.spec, len(p.slots[t.key])) for t in p.todo}
    if ray_address and p.todo:
        from experiments.sweeps.ray_backend import cluster_cpus

        workers = cluster_cpus(ray_address)  # one batch per CPU of the cluster
    jobs = [[items[t.key] for t in job] for job in make_jobs(p.todo, workers)]
    bar = _bar(total, done0) if progress and jobs else None
    done, partial = [done0], [0.0]

    def on_message(msg: tuple) -> None:
        if msg[0] == "progress":
            partial[0] += msg[1]
        elif msg[0] == "trial":
            _, key, rec, reported = msg
            for path in dict.fromkeys(path_of(slot, key) for slot in p.slots[key]):
                write_json_atomic(path, rec)
            for slot in p.slots[key]:
                p.records[slot] = rec
            done[0] += len(p.slots[key])
            partial[0] -= reported
            if on_trial is not None:
                on_trial(done[0], total)
        if bar is not None and msg[0] in ("progress", "trial"):
            bar.n = min(float(total), done[0] + max(partial[0], 0.0))
            bar.refresh()

    t0 = time.perf_counter()
    try:
        if not jobs:
            infos = []
        elif ray_address:
            from experiments.sweeps.ray_backend import run_ray

            infos = run_ray(jobs, ray_address, on_message)
        else:
            infos = run_local(jobs, workers, on_message)
    finally:
        if bar is not None:
            bar.close()
    run_s = time.perf_counter() - t0
    missing = total - len(p.records)
    if missing:
        raise RuntimeError(f"{missing} trials missing after the run")
    stats = RunStats(
        total,
        len(p.todo),
        p.missing,
        done0,
        run_s,
        infos,
        "ray" if ray_address and jobs else "local" if jobs else "cache",
        p.reused,
    )
    return p, stats


def _bar(total: int, initial: int):
    from tqdm import tqdm

    return tqdm(
        total=float(total),
        initial=float(initial),
        desc="sweep",
        unit="trial",
        file=sys.stderr,
        bar_format="{desc}: {n:.0f}/{total:.0f} trials |{bar}| {elapsed} elapsed, {remaining} left",
    )
