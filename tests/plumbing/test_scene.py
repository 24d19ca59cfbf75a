"""The scene drawn from steps and credits: walls where the maze has walls, the agent where the environment put
it, feedback tiles on the credited steps' cells with their weights."""

from __future__ import annotations

import numpy as np
import pytest

from common.envs.maze import MazeEnv, make_layout
from common.envs.taxi import TaxiEnv
from common.protocol import Credit, CreditedStep, SceneUpdate, Step, decode
from common.logs.scene import SceneBuilder


def steps_of(env, actions, seed=0):
    obs, _ = env.reset(seed=seed)
    out = []
    for k, a in enumerate(actions):
        nxt, r, term, trunc, info = env.step(a)
        out.append(
            Step(
                run="r",
                incarnation="a1",
                seq=k,
                t_action=1700000000.0 + k,
                episode=0,
                t_in_episode=k,
                obs=np.asarray(obs).tolist(),
                action=int(a),
                reward=float(r),
                next_obs=np.asarray(nxt).tolist(),
                terminated=term,
                truncated=trunc,
                weights_version=0,
                info={k2: float(v) for k2, v in info.items()},
            )
        )
        obs = nxt
    return out


def xy(size, cell):
    return cell[1] + 0.5, size - 1 - cell[0] + 0.5


@pytest.mark.parametrize("env_name", ["maze", "maze-pomdp"])
def test_maze_layout_and_agent_positions(env_name):
    layout = make_layout(4)
    env = MazeEnv(4, "mdp" if env_name == "maze" else "pomdp")
    builder = SceneBuilder.from_run_config({"launcher": {"env": env_name, "layout": 4}})
    rng = np.random.default_rng(0)
    positions = []
    for step in steps_of(env, rng.integers(0, 4, 30)):
        out = builder.feed("r", step)
        positions.append(step.info["row"]), positions.append(step.info["col"])
        agent = decode("hitl/r/scene/agent", dict((k.split("/")[-1], v) for k, v in out)["agent"])
        p = agent.entities[0].spheres[0].pose.position
        assert (p.x, p.y) == xy(8, (int(step.info["row"]), int(step.info["col"])))
        if step.seq == 0:
            lay = decode("hitl/r/scene/layout", out[0][1])
            walls = sum(map(sum, layout.walls))
            assert len(lay.entities[0].cubes) == 1 + walls + 2  # floor, walls, goal, start
        else:
            assert len(out) == 1  # the layout once per episode


def test_feedback_tiles_sit_on_the_credited_steps_with_their_weights():
    env = MazeEnv(0, "mdp")
    builder = SceneBuilder("maze", 0)
    steps = steps_of(env, [1, 1, 2, 2])
    for s in steps:
        builder.feed("r", s)
    credit = Credit(
        run="r",
        teacher_id="oracle",
        seq=5,
        value=-1,
        status="credited",
        t_reaction=1700000003.5,
        t_credited=1700000003.6,
        actor="a1",
        steps=[CreditedStep(1, 0.25), CreditedStep(2, 0.75)],
        lost_mass=0.0,
    )
    [(key, data)] = builder.feed("r", credit)
    assert key == "hitl/r/scene/feedback"
    e = SceneUpdate.decode(data).entities[0]
    assert e.id == "feedback/oracle/5" and e.lifetime.seconds == 3
    for cube, s, w in zip(e.cubes, steps[1:3], (0.25, 0.75)):
        before = (round(s.obs[0] * 7), round(s.obs[1] * 7))
        assert (cube.pose.position.x, cube.pose.position.y) == xy(8, before)
        assert cube.color.r > cube.color.g and cube.color.a == pytest.approx(0.2 + 0.8 * w)
    assert [t.text for t in e.texts] == ["-1 w=0.25 (step 1)", "-1 w=0.75 (step 2)"]


def test_taxi_layout_marks_the_destination_and_the_taxi_moves():
    builder = SceneBuilder("taxi")
    [s] = steps_of(TaxiEnv(), [1], seed=3)
    out = dict(builder.on_step(s))
    lay = SceneUpdate.decode(out["layout"]).entities[0]
    texts = [t.text for t in lay.texts]
    assert sum("(destination)" in t for t in texts) == 1 and len(lay.cubes) > 5  # floor, walls, 4 stands
    p = SceneUpdate.decode(out["agent"]).entities[0].spheres[0].pose.position
    row, col = int(np.argmax(s.next_obs[:5])), int(np.argmax(s.next_obs[5:10]))
    assert (p.x, p.y) == xy(5, (row, col))


def test_no_scene_for_an_unknown_environment():
    assert SceneBuilder.from_run_config({"env": "CartPole-v1"}) is None
    assert SceneBuilder.from_run_config({"nothing": 1}) is None


def test_a_wide_credit_draws_its_heaviest_steps_and_says_how_many_more():
    """At 250 steps/s a delay window credits about 127 steps: the picture keeps the heaviest MAX_TILES, in order,
    says how many it left out, and the metadata still lists every step."""
    from common.logs.scene import MAX_TILES

    maze = MazeEnv(make_layout(0))
    builder = SceneBuilder("maze", layout=0)
    steps = steps_of(maze, [k % 4 for k in range(60)])
    for s in steps:
        builder.on_step(s)
    weights = [0.01] * 60
    for k in (3, 20, 41):
        weights[k] = 0.2
    credit = Credit(
        run="r",
        teacher_id="oracle",
        seq=7,
        value=1,
        status="credited",
        t_reaction=1700000061.0,
        t_credited=1700000061.1,
        actor="a1",
        steps=[CreditedStep(k, w) for k, w in enumerate(weights)],
        lost_mass=0.0,
    )
    [(_, data)] = builder.feed("r", credit)
    e = SceneUpdate.decode(data).entities[0]
    drawn = [int(t.text.split("step ")[1].rstrip(")")) for t in e.texts if "(step " in t.text]
    assert len(e.cubes) == len(drawn) == MAX_TILES and drawn == sorted(drawn)
    latest_light = sorted(set(range(60)) - {3, 20, 41})[-(MAX_TILES - 3) :]
    assert set(drawn) == {3, 20, 41, *latest_light}
    assert f"and {60 - MAX_TILES} more credited steps" in e.texts[-1].text
    assert len(dict((m.key, m.value) for m in e.metadata)["steps"].split()) == 60
