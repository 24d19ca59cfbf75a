"""`python -m services.console --replay LOG`: a recorded session in the console's page, with a timeline to scrub.

The server reads the log once and hands the page one JSON timeline (`/timeline.json`):

- the environment's picture (the same `static_scene` and `SceneTracker` as the live console) and, per step, where
  the agent was, the action, the reward;
- Q and H per action at every step: a fresh learner fed the recorded inputs in the recorded order (as `replay
  retrain` does, which reproduces the live weights bit for bit), read after each step is learned: the values the
  actor's next action was chosen with (in lockstep);
- each feedback (from its Credit): value, teacher, status and the steps it was credited to with their weights;
- the learning curve (EpisodeSummary).

The page (`static/replay.html`) draws the scene at the chosen step, marks the feedback credited to steps around
it, and a timeline of Q and H over the steps with every feedback and lines to its credited steps; drag, click,
arrow keys or play to scrub. Nothing is published: no Zenoh session is opened.
"""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

MAX_STEPS = 200_000  # a longer log is cut to its first steps for the page (said on the page)


def _learner_run(path) -> tuple[dict, dict]:
    """Q, H, alpha_h per (actor, seq) from a learner fed the recorded inputs, and the learner's config record."""
    from services.common.runtime import apply_torch_threads
    from services.common.config import learner_config_from_record
    from services.learner.core import LearnerCore
    from services.replay.retrain import _entries, _read, _replay

    log = _read(path)
    _, entries, config = _entries(path, log, None)
    apply_torch_threads()
    core = LearnerCore(learner_config_from_record(config["learner"]))
    values: dict[tuple[str, int], tuple] = {}
    agent = core.loop.agent

    def after(step) -> None:
        if len(values) < MAX_STEPS:
            q, h, _, alpha_h = agent.preferences(0, step.next_obs)
            values[(step.incarnation, step.seq)] = (
                [round(float(x), 4) for x in q],
                [round(float(x), 4) for x in h],
                round(alpha_h, 5),
            )

    _replay(core, log, entries, after)
    return values, config["learner"]


def timeline(path) -> dict:
    """Everything the replay page shows, as one JSON-ready dict."""
    from common.envs.scene import SceneTracker, static_scene
    from common.logs.mcap_log import LogRecoveryWarning, read_log
    from common.protocol import Credit, EpisodeSummary, Step

    values, learner = _learner_run(path)
    env, layout = learner.get("env", "maze"), int(learner.get("layout") or 0)
    tracker = SceneTracker(env, layout)
    steps: list[dict] = []
    credits: list[dict] = []
    curve: list[dict] = []
    run: str | None = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", LogRecoveryWarning)
        reader = read_log(path)
        for rec in reader:
            m = rec.message
            if isinstance(m, Step) and len(steps) < MAX_STEPS:
                run = m.run
                q, h, alpha_h = values.get((m.incarnation, m.seq), (None, None, None))
                steps.append(
                    {
                        "actor": m.incarnation,
                        "seq": m.seq,
                        "episode": m.episode,
                        "t": m.t_action,
                        "t_in_episode": m.t_in_episode,
                        "action": m.action,
                        "reward": round(m.reward, 4),
                        "scene": tracker.after(m.t_in_episode, m.action, m.next_obs),
                        "q": q,
                        "h": h,
                        "alpha_h": alpha_h,
                    }
                )
            elif isinstance(m, Credit):
                credits.append(
                    {
                        "teacher": m.teacher_id,
                        "seq": m.seq,
                        "value": m.value,
                        "status": m.status,
                        "t": m.t_reaction,
                        "actor": m.actor,
                        "lost_mass": round(m.lost_mass, 4),
                        "steps": [{"seq": s.seq, "weight": round(s.weight, 4)} for s in m.steps],
                    }
                )
            elif isinstance(m, EpisodeSummary):
                curve.append({"episode": m.episode, "return": m.return_, "steps": m.steps})
    return {
        "run": run,
        "env": env,
        "layout": layout,
        "algo": learner.get("algo"),
        "log": str(path),
        "scene": static_scene(env, layout),
        "steps": steps,
        "credits": credits,
        "curve": curve,
        "cut": len(steps) >= MAX_STEPS,
        "read": reader.status.summary(),
        "warnings": [str(w.message) for w in caught],
    }


def replay_main(config) -> int:
    """Serve the replay page for `config.replay` on config.host:config.port until Ctrl-C."""
    import asyncio

    from aiohttp import web

    from common.logs.mcap_log import NotMcapError

    path = Path(config.replay)
    if not path.exists():
        print(f"error: {path}: no such file or directory", file=sys.stderr)
        return 2
    try:
        data = json.dumps(timeline(path)).encode()
    except NotMcapError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except ValueError as e:  # e.g. no learner in the log: nothing to replay
        print(f"error: cannot replay {path}: {e}", file=sys.stderr)
        return 2
    static = Path(__file__).resolve().parent / "static"

    async def index(request):
        return web.FileResponse(static / "replay.html")

    async def tl(request):
        return web.Response(body=data, content_type="application/json")

    doors: list = []  # the door (services/console/door.py) once the port is known: a replay shows a run too

    @web.middleware
    async def door(request, handler):
        return await doors[0].middleware(request, handler)

    async def serve() -> None:
        import collections

        from services.console.door import Door, Keys, read_or_make_token, spent_file_for
        from services.console.sockets import SocketGuard

        app = web.Application(middlewares=[door])
        app.router.add_get("/", index)
        app.router.add_get("/timeline.json", tl)
        app.router.add_post("/enter", tl)  # (answered by the door)
        app.router.add_static("/static/", static)
        runner = web.AppRunner(app, access_log=None)
        await runner.setup()
        assert runner.server is not None  # (after setup)
        counters: collections.Counter = collections.Counter()  # (a replay keeps no stats)
        guard = SocketGuard(
            counters,
            config.header_timeout,
            config.unauthenticated_idle,
            config.max_connections_per_address,
            config.max_connections,
        )  # as the live console
        server = await asyncio.get_running_loop().create_server(guard.factory(runner.server), config.host, config.port)
        port = server.sockets[0].getsockname()[1]  # (port 0: the system's choice)
        keys = Keys(read_or_make_token(config.token_file), spent_file_for(config.token_file))
        doors.append(Door(keys, config.host, port, "http", counters, guard=guard))
        print(f"replay: {doors[0].address()} ({path})", file=sys.stderr, flush=True)
        sweeper = asyncio.create_task(guard.sweeper())
        try:
            await asyncio.Event().wait()
        finally:
            sweeper.cancel()
            server.close()
            await runner.cleanup()

    try:
        asyncio.run(serve())
    except KeyboardInterrupt:
        pass
    return 0
