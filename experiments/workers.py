"""Running the reproduction's batches on worker processes, with progress messages to the parent."""
from __future__ import annotations

import multiprocessing as mp
import os
import queue
import signal
import threading
import time
from typing import Callable

from experiments.runner import TrialResult, run_trials
from experiments.trialcache import Task, result_record, write_json_atomic


def _run_job(job_id: int, tasks: list[Task], emit: Callable[[tuple], None]) -> dict:
    """Run one batch; write each trial's cache files when it finishes; report progress via emit:
    ("progress", fraction of trials) as episodes end, ("trial", slots, fraction already reported) when
    a trial is done."""
    specs = [t.spec for t in tasks]
    reported = [0.0] * len(tasks)
    unsent = [0.0]
    last = [time.perf_counter()]

    def on_episode(i: int, record: dict) -> None:
        step = len(tasks[i].slots) / max(specs[i].episodes, 1)
        reported[i] += step
        unsent[0] += step
        now = time.perf_counter()
        if now - last[0] > 0.25:
            emit(("progress", unsent[0]))
            unsent[0] = 0.0
            last[0] = now

    def on_trial_done(i: int, result: TrialResult) -> None:
        rec = result_record(tasks[i].key, result)
        for s in tasks[i].slots:
            write_json_atomic(s.path, rec)
        emit(("progress", unsent[0]))
        unsent[0] = 0.0
        emit(("trial", len(tasks[i].slots), reported[i]))

    t0, c0 = time.perf_counter(), time.process_time()
    profile: dict = {}
    results = run_trials(specs, on_episode=on_episode, on_trial_done=on_trial_done, profile=profile)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {"job": job_id, "pid": os.getpid(), "env": specs[0].env, "trials": len(specs), "wall_s": wall, "cpu_s": cpu,
            "trial_steps": int(sum(r.total_steps for r in results)),
            "max_trial_steps": int(max(r.total_steps for r in results)),
            "by_running_trials": profile,
            "steps": {tasks[i].key: r.total_steps for i, r in enumerate(results)}}


def _worker(jobs_q, msg_q, parent: int) -> None:
    import torch
    torch.set_num_threads(1)

    def emit(msg):
        if os.getppid() != parent:  # the parent is gone: stop (finished trials are already cached)
            raise SystemExit(1)
        msg_q.put(msg)

    while True:
        item = jobs_q.get()
        if item is None:
            return
        job_id, tasks = item
        try:
            info = _run_job(job_id, tasks, emit)
            msg_q.put(("job", info))
        except BaseException as exc:  # report, then die: the parent stops the run
            msg_q.put(("error", f"job {job_id}: {type(exc).__name__}: {exc}"))
            raise


def run_jobs(jobs: list[list[Task]], workers: int, on_message: Callable[[tuple], None]) -> list[dict]:
    """Run jobs on `workers` processes (in this process when workers <= 1). Returns the job infos."""
    infos = []
    if workers <= 1:
        for j, tasks in enumerate(jobs):
            info = _run_job(j, tasks, on_message)
            infos.append(info)
            on_message(("job", info))
        return infos
    ctx = mp.get_context("spawn")
    jobs_q, msg_q = ctx.Queue(), ctx.Queue()
    procs = [ctx.Process(target=_worker, args=(jobs_q, msg_q, os.getpid()), daemon=True)
             for _ in range(min(workers, len(jobs)))]
    old_term = signal.signal(signal.SIGTERM, _raise_exit) if threading.current_thread() is threading.main_thread() else None
    for p in procs:
        p.start()
    for j, tasks in enumerate(jobs):
        jobs_q.put((j, tasks))
    for _ in procs:
        jobs_q.put(None)
    try:
        while len(infos) < len(jobs):
            try:
                msg = msg_q.get(timeout=1.0)
            except queue.Empty:
                dead = [p for p in procs if not p.is_alive() and p.exitcode not in (0, None)]
                if dead:
                    raise RuntimeError(f"a worker died (exit code {dead[0].exitcode})")
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
