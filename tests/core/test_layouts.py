"""Maze layouts: the honest / misleading classifier on hand-made mazes, the generated pool, the
shortest-path teacher."""

import numpy as np

from common.envs import make_env
from common.envs.maze import (
    HONEST,
    LAYOUT_COUNT,
    LAYOUT_KIND_COUNT,
    MISLEADING,
    SIZE,
    MazeLayout,
    layout_kind,
    layout_pool,
    make_layout,
)


def maze(rows: list[str]) -> MazeLayout:
    """'#' wall, 'S' start, 'G' goal, '.' space; rows shorter than SIZE are padded with walls."""
    rows = [r.ljust(SIZE, "#") for r in rows] + ["#" * SIZE] * (SIZE - len(rows))

    def find(ch: str) -> tuple[int, int]:
        return next((r, c) for r, row in enumerate(rows) for c, x in enumerate(row) if x == ch)

    walls = tuple(tuple(x == "#" for x in row) for row in rows)
    return MazeLayout(0, walls, find("S"), find("G"))


def test_an_open_maze_is_honest():
    m = maze(["S.....", "......", "......", "..G..."])
    assert m.misleading_dead_ends() == [] and m.kind == HONEST
    assert m.shortest_path() == 5


def test_a_dead_end_along_an_approved_path_makes_a_maze_misleading():
    # From S every approved move goes east towards G, into the pocket at (0, 3), whose only approved
    # move (east) is a wall: the rule leads the agent into a dead end; the way round is south.
    m = maze(["S..#G", "....."])
    assert m.misleading_dead_ends() == [(0, 2)]
    assert m.kind == MISLEADING
    assert m.shortest_path() == 6  # longer than the Manhattan distance 4


def test_a_dead_end_off_every_approved_path_does_not_count():
    # The pocket at (2, 0) has no approved move, but no approved move from S ever enters it.
    m = maze(["S...G", "#####", "."])
    assert m.misleading_dead_ends() == [] and m.kind == HONEST


def test_the_pool_has_sixty_distinct_layouts_of_each_kind_in_alternating_order():
    pool, drawn = layout_pool(LAYOUT_COUNT)
    assert len(pool) == LAYOUT_COUNT == 2 * LAYOUT_KIND_COUNT == 1140
    assert len({(L.walls, L.start, L.goal) for L in pool}) == LAYOUT_COUNT
    for L in pool:
        assert L.kind == layout_kind(L.index) == (HONEST if L.index % 2 == 0 else MISLEADING)
        assert L.shortest_path() is not None
        if L.kind == HONEST:
            assert L.shortest_path() == 5  # honest: the Manhattan distance is a path
    assert drawn[HONEST] >= 60 and drawn[MISLEADING] >= 60
    assert make_layout(3) == pool[3]


def test_layouts_0_to_59_are_those_of_every_run_before_the_fresh_ones():
    """Layouts 60-179 continue the same stream: the first 60 are the pool of every earlier run and pilot
    (this fingerprint is theirs, computed with the 60-layout generator of commit 5a1a7bf)."""
    import hashlib

    pool, _ = layout_pool()
    old = repr([(L.walls, L.start, L.goal) for L in pool[:60]]).encode()
    assert hashlib.sha256(old).hexdigest()[:16] == "2fcf6c4b9a026826"
    # and 60-119 those of the run of 25 November 2026 (the 120-layout generator of commit 91a0881)
    then = repr([(L.walls, L.start, L.goal) for L in pool[60:120]]).encode()
    assert hashlib.sha256(then).hexdigest()[:16] == "0bcb9f796d5b25cf"
    # and 0-179 those of every run to the end of 25 November (the 180-layout generator, commit 93b5cd7): the stream
    # extended to 1,140 on 28 November changed none of them, nor the draws REPORT.md counts for them
    first = repr([(L.walls, L.start, L.goal) for L in pool[:180]]).encode()
    assert hashlib.sha256(first).hexdigest()[:16] == "7d7413387e108035"
    assert layout_pool()[1] == {HONEST: 97, MISLEADING: 90}


def test_the_shortest_path_teacher_never_misleads_where_the_manhattan_teacher_does():
    m = next(L for L in layout_pool()[0] if L.kind == MISLEADING)
    env_m, manhattan_rule = make_env("maze", m.index)
    env_s, sp_rule = make_env("maze", m.index, "shortest-path")
    dist = m.distances_to_goal()
    for r in range(SIZE):
        for c in range(SIZE):
            if dist[r, c] <= 0:
                continue
            approved = []
            for a in range(4):
                env_s.reset()
                env_s.pos = (r, c)
                _, _, _, _, info = env_s.step(a)
                approved.append(sp_rule(info) > 0)
            assert any(approved), "a teacher who knows the maze approves some move from every cell"
    # and the Manhattan teacher approves nothing at the dead end
    dead = m.misleading_dead_ends()[0]
    votes = []
    for a in range(4):
        env_m.reset()
        env_m.pos = dead
        votes.append(manhattan_rule(env_m.step(a)[4]))
    assert max(votes) == -1
    assert np.all(m.distances_to_goal()[m.goal] == 0)
