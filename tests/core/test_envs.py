import numpy as np
import pytest

from common.envs import LAYOUT_COUNT, MazeEnv, TaxiEnv, make_env, make_layout, progress_rule
from common.envs.maze import MAX_STEPS, NEIGHBOURS, manhattan
from common.envs.taxi import FIXED_TASKS


def test_every_layout_is_solvable_with_start_at_distance_five():
    for index in range(LAYOUT_COUNT):
        layout = make_layout(index)
        assert manhattan(layout.start, layout.goal) == 5, index
        assert not layout.walls[layout.start[0]][layout.start[1]]
        assert not layout.walls[layout.goal[0]][layout.goal[1]]
        path = layout.shortest_path()
        assert path is not None and path >= 5, index


def test_ten_distinct_layouts_and_deterministic():
    layouts = [make_layout(i) for i in range(LAYOUT_COUNT)]
    assert len({(lay.walls, lay.start, lay.goal) for lay in layouts}) == LAYOUT_COUNT
    assert make_layout(3) == make_layout(3)
    with pytest.raises(ValueError, match="layout"):
        make_layout(LAYOUT_COUNT)


def test_ascii_marks_start_goal_and_walls():
    layout = make_layout(0)
    text = layout.ascii()
    rows = text.splitlines()
    assert len(rows) == 8 and all(len(r) == 8 for r in rows)
    assert rows[layout.start[0]][layout.start[1]] == "S"
    assert rows[layout.goal[0]][layout.goal[1]] == "G"
    assert sum(r.count("#") for r in rows) == sum(map(sum, layout.walls))


def test_maze_rewards_goal_and_walls():
    env = MazeEnv(0)
    env.reset()
    layout = env.layout
    # Walk the shortest path found by BFS: -0.01 per step, +1 on the goal step, terminated there.
    from collections import deque

    moves = ((-1, 0), (0, 1), (1, 0), (0, -1))
    prev = {layout.start: None}
    q = deque([layout.start])
    while q:
        c = q.popleft()
        for a, (dr, dc) in enumerate(moves):
            n = (c[0] + dr, c[1] + dc)
            if not layout.is_wall(*n) and n not in prev:
                prev[n] = (c, a)
                q.append(n)
    actions, c = [], layout.goal
    while prev[c] is not None:
        c, a = prev[c]
        actions.append(a)
    actions.reverse()
    total = 0.0
    for k, a in enumerate(actions):
        _, r, term, trunc, info = env.step(a)
        total += r
        assert term == (k == len(actions) - 1)
    assert total == pytest.approx(1.0 - 0.01 * (len(actions) - 1))


def test_bumping_a_wall_stays_put_and_teacher_says_minus_one():
    env = MazeEnv(0)
    env.reset()
    env.pos = (0, 3)  # top row: north is outside the grid
    _, r, term, trunc, info = env.step(0)
    assert env.pos == (0, 3) and r == -0.01 and not term
    assert progress_rule(info) == -1


def test_step_limit_truncates():
    env = MazeEnv(0, max_steps=7)
    env.reset()
    env.pos = (0, 3)
    for _ in range(6):
        assert not env.step(0)[3]
    assert env.step(0)[3]
    assert MAX_STEPS == 1000


def test_mdp_observation_is_scaled_coordinates():
    env = MazeEnv(2, "mdp")
    obs, _ = env.reset()
    r, c = env.layout.start
    np.testing.assert_allclose(obs, [r / 7, c / 7])


def test_pomdp_observation_is_the_eight_neighbours():
    env = MazeEnv(0, "pomdp")
    env.reset()
    for cell in [(0, 0), (7, 7), (3, 4), env.layout.start]:
        if env.layout.is_wall(*cell):
            continue
        env.pos = cell
        obs = env._obs()
        assert obs.shape == (8,)
        expected = [1.0 if env.layout.is_wall(cell[0] + dr, cell[1] + dc) else 0.0 for dr, dc in NEIGHBOURS]
        np.testing.assert_array_equal(obs, expected)
    env.pos = (0, 0) if not env.layout.is_wall(0, 0) else (0, 1)
    obs = env._obs()
    assert obs[0] == obs[1] == obs[2] == 1.0  # the row above the grid is wall


def _taxi_at(env, row, col, passenger, dest):
    env._env.s = env._env.encode(row, col, passenger, dest)
    env.state = int(env._env.s)


def test_taxi_observation_and_teacher_signals():
    env = TaxiEnv()
    obs, _ = env.reset(seed=3)
    assert obs.shape == (19,) and obs.sum() == 4
    _, _, passenger, dest = env._decode(env.state)
    # At the passenger's stand, a pick-up is a sub-goal: the teacher says +1.
    _taxi_at(env, *env.locs[passenger], passenger, dest)
    _, r, term, _, info = env.step(4)
    assert info["subgoal_reached"] == 1.0 and progress_rule(info) == 1 and r == -1 and not term
    assert env._decode(env.state)[2] == 4  # in the taxi
    # At the destination with the passenger aboard, a drop-off pays +20 and ends the episode.
    _taxi_at(env, *env.locs[dest], 4, dest)
    _, r, term, _, info = env.step(5)
    assert r == 20 and term and progress_rule(info) == 1
    # Moving away from the passenger is -1.
    _taxi_at(env, 2, 2, 0, 1)  # passenger at R (0, 0)
    _, _, _, _, info = env.step(2)  # south
    assert info["target_distance_after"] > info["target_distance_before"] and progress_rule(info) == -1


def test_make_env_rejects_unknown_name():
    with pytest.raises(ValueError, match="unknown env 'nope'"):
        make_env("nope")


@pytest.mark.parametrize("name,layout", [("taxi-s", 0), ("taxi-fixed-s", 7)])
def test_taxi_state_onehot_observation(name, layout):
    """The reproduction's Taxi observation: the 19 factored values unchanged, then a one-hot of Gymnasium's
    500 states at 19 + state, through resets and steps (pick-up included)."""
    env, _ = make_env(name, layout)
    plain = TaxiEnv(fixed_task=env.fixed_task)
    assert env.observation_space.shape == (519,)
    for seed in range(5):
        obs, _ = env.reset(seed=seed)
        ref, _ = plain.reset(seed=seed)
        for action in [4, 0, 1, 2, 3, 5, 4]:
            assert obs.shape == (519,) and obs.dtype == np.float32
            np.testing.assert_array_equal(obs[:19], ref)
            assert obs[19:].sum() == 1.0 and obs[19 + env.state] == 1.0
            row, col, passenger, dest = env._decode(env.state)
            assert obs[row] == obs[5 + col] == obs[10 + passenger] == obs[15 + dest] == 1.0
            obs, *_ = env.step(action)
            ref, *_ = plain.step(action)
    if env.fixed_task is not None:
        state = int(env.reset(seed=11)[0][19:].argmax())
        assert env._decode(state)[2:] == FIXED_TASKS[layout]
    _taxi_at(env, *env.locs[0], 0, 2)
    obs, _, _, _, info = env.step(4)  # pick-up at R: the passenger is now in the taxi (4), and the one-hot moves
    assert info["subgoal_reached"] == 1.0 and obs[10 + 4] == 1.0
    assert obs[19:].argmax() == env._env.encode(*env.locs[0], 4, 2)
