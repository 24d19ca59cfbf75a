"""The environment drawn in Foxglove's own schema (`foxglove.SceneUpdate`, built with the `foxglove-sdk` package):
what a person sees when opening a log or the live bridge in Foxglove's 3D panel.

:class:`SceneBuilder` turns the messages of a run into scene messages, for three topics:

- ``layout``: the environment, once per episode (at its first step): maze walls, start and goal; taxi walls, the
  four stands and the episode's destination;
- ``agent``: the agent after each step, with an arrow for the action it took and the step's numbers;
- ``feedback``: each resolved feedback at the steps it was credited to (a tile per step, green for +1, red for
  -1, opaque in proportion to the credit weight, labelled with the weight), or a note of why it was not.

It is pure (no transport): the recorder writes its output into the log and the Foxglove bridge serves it live,
from the same Step and Credit messages. Positions come from the observation (maze MDP, taxi) or the step's
`info` (`row`, `col`: maze POMDP). Coordinates: one cell is 1 m, x to the east, y to the north, the frame
`env`.
"""

from __future__ import annotations

import collections
import functools
import heapq
from typing import Any

try:
    import foxglove.messages as fm
except ImportError:  # the `foxglove` extra is not installed: logs and the bridge carry no scene
    fm = None

PARTS = ("layout", "agent", "feedback")
FRAME = "env"
FEEDBACK_LIFETIME_S = 3.0
#: Tiles drawn for one feedback: its heaviest credited steps. At 250 steps/s a 0.2-4 s delay window credits 127 steps
#: of near-equal weight; drawing them all was 56 % of the recorder's CPU (py-spy, `services bench --phases rate`) and
#: no clearer. The message's metadata still lists every credited step.
MAX_TILES = 24
_MOVES = {0: (0.0, 1.0), 1: (1.0, 0.0), 2: (0.0, -1.0), 3: (-1.0, 0.0)}  # action -> (dx, dy): N E S W
_ACTIONS = {"maze": ("north", "east", "south", "west"), "taxi": ("south", "north", "east", "west", "pickup", "dropoff")}
_TAXI_MOVES = {0: (0.0, -1.0), 1: (0.0, 1.0), 2: (1.0, 0.0), 3: (-1.0, 0.0)}  # gymnasium taxi: S N E W
_STANDS = ("R", "G", "Y", "B")
_STAND_COLOURS = ((0.9, 0.2, 0.2), (0.2, 0.8, 0.3), (0.95, 0.85, 0.2), (0.2, 0.4, 0.95))


# The small parts are made once per distinct value (they are immutable): a feedback credited over a hundred steps
# draws three primitives a step, and building each part anew cost most of the recorder's time at 250 steps/s.
@functools.lru_cache(maxsize=4096)
def _colour(r: float, g: float, b: float, a: float = 1.0) -> Any:
    return fm.Color(r=r, g=g, b=b, a=a)


@functools.lru_cache(maxsize=256)
def _vector(x: float, y: float, z: float) -> Any:
    return fm.Vector3(x=x, y=y, z=z)


@functools.lru_cache(maxsize=4096)
def _pose(x: float, y: float, z: float = 0.0, yaw_dir: tuple[float, float] | None = None) -> Any:
    """A pose at (x, y, z); with `yaw_dir`, turned so that its x axis points that way (for arrows)."""
    if yaw_dir is None:
        q = fm.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
    else:
        import math

        yaw = math.atan2(yaw_dir[1], yaw_dir[0])
        q = fm.Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))
    return fm.Pose(position=fm.Vector3(x=x, y=y, z=z), orientation=q)


def _cube(x: float, y: float, z: float, sx: float, sy: float, sz: float, colour: Any) -> Any:
    return fm.CubePrimitive(pose=_pose(x, y, z), size=_vector(sx, sy, sz), color=colour)


def _text(x: float, y: float, z: float, text: str, size: float = 14.0, colour: Any = None) -> Any:
    return fm.TextPrimitive(
        pose=_pose(x, y, z),
        billboard=True,
        font_size=size,
        scale_invariant=True,
        color=colour or _colour(1, 1, 1),
        text=text,
    )


def _arrow(x: float, y: float, direction: tuple[float, float], colour: Any, z: float = 0.35) -> Any:
    return fm.ArrowPrimitive(
        pose=_pose(x - 0.3 * direction[0], y - 0.3 * direction[1], z, direction),
        shaft_length=0.35,
        shaft_diameter=0.08,
        head_length=0.25,
        head_diameter=0.2,
        color=colour,
    )


def _entity(t: float, eid: str, lifetime: float = 0.0, meta: dict[str, str] | None = None, **prims: Any) -> Any:
    return fm.SceneEntity(
        timestamp=fm.Timestamp.from_epoch_secs(t),
        frame_id=FRAME,
        id=eid,
        lifetime=fm.Duration.from_secs(lifetime) if lifetime else None,
        frame_locked=True,
        metadata=[fm.KeyValuePair(key=k, value=v) for k, v in (meta or {}).items()],
        **prims,
    )


class SceneBuilder:
    """Scene messages from a run's Step and Credit messages (see the module doc). Returns (part, bytes) pairs."""

    def __init__(self, env: str, layout: int = 0, memory: int = 4096):
        self.env = env
        self.kind = "taxi" if env.startswith("taxi") else "maze" if env.startswith("maze") else None
        if self.kind is None:
            raise ValueError(f"no scene for env {env!r}")
        self.layout_index = layout
        self._cells: collections.OrderedDict = collections.OrderedDict()  # (actor, seq) -> (before, after, action)
        self.memory = memory
        self._episode: tuple[str, int] | None = None
        self._last_after: dict[str, tuple[int, int]] = {}
        self._layouts: dict[int | None, tuple[list, list]] = {}  # the layout's primitives, per taxi destination
        if self.kind == "maze":
            from common.envs.maze import SIZE, make_layout

            self.size = (SIZE, SIZE)
            self.maze = make_layout(layout)
        else:
            from common.envs.taxi import TaxiEnv

            t = TaxiEnv()
            self.size = (5, 5)
            self.stands = [tuple(map(int, loc)) for loc in t.locs]
            self.desc = [
                bytes(row).decode() if not isinstance(row, str) else row for row in (b"".join(r) for r in t._env.desc)
            ]

    @classmethod
    def from_run_config(cls, config: dict) -> SceneBuilder | None:
        """From a run config (the launcher's `run.json`, a service's config, or the learner's Ingest config):
        the first `env` found (with its `layout`); None when there is none, no scene for it, or no foxglove-sdk."""
        if fm is None:
            return None
        stack = [config]
        while stack:
            node = stack.pop(0)
            if not isinstance(node, dict):
                continue
            if isinstance(node.get("env"), str):
                try:
                    return cls(node["env"], int(node.get("layout") or 0))
                except (ValueError, TypeError):
                    return None
            stack.extend(v for v in node.values() if isinstance(v, dict))
        return None

    # -- geometry ----------------------------------------------------------------------------------------
    def _xy(self, cell: tuple[int, int]) -> tuple[float, float]:
        r, c = cell
        return c + 0.5, self.size[0] - 1 - r + 0.5

    def _cells_of(self, step: Any) -> tuple[tuple[int, int], tuple[int, int]]:
        """(cell before, cell after) of a Step."""
        if self.kind == "taxi":
            return _taxi_cell(step.obs), _taxi_cell(step.next_obs)
        n = self.size[0] - 1
        if len(step.obs) == 2:  # MDP: (row, col) / (SIZE - 1)
            return (
                (round(step.obs[0] * n), round(step.obs[1] * n)),
                (round(step.next_obs[0] * n), round(step.next_obs[1] * n)),
            )
        after = (int(step.info.get("row", -1)), int(step.info.get("col", -1)))
        before = self.maze.start if step.t_in_episode == 0 else self._last_after.get(step.incarnation, after)
        return before, after

    # -- inputs ------------------------------------------------------------------------------------------
    def on_step(self, step: Any) -> list[tuple[str, bytes]]:
        out = []
        before, after = self._cells_of(step)
        self._last_after[step.incarnation] = after
        self._cells[(step.incarnation, step.seq)] = (before, after, int(step.action))
        while len(self._cells) > self.memory:
            self._cells.popitem(last=False)
        episode = (step.incarnation, step.episode)
        if episode != self._episode:
            self._episode = episode
            out.append(("layout", self.layout_update(step).encode()))
        out.append(("agent", self.agent_update(step, before, after).encode()))
        return out

    def on_credit(self, credit: Any) -> list[tuple[str, bytes]]:
        return [("feedback", self.feedback_update(credit).encode())]

    def feed(self, run: str, message: Any) -> list[tuple[str, bytes]]:
        """(key, bytes) of the scene messages that a decoded message of `run` gives (none for most types)."""
        from common.protocol import KEYS, Credit, Step

        if isinstance(message, Step):
            parts = self.on_step(message)
        elif isinstance(message, Credit):
            parts = self.on_credit(message)
        else:
            return []
        return [(KEYS["scene"].key(run, part), data) for part, data in parts]

    # -- the three pictures --------------------------------------------------------------------------------
    def layout_update(self, step: Any) -> Any:
        h, w = self.size
        if self.kind == "maze":
            key, title = None, f"{self.env} layout {self.layout_index}, episode {step.episode}"
        else:
            key, title = _taxi_destination(step.obs), f"taxi, episode {step.episode}"
        if key not in self._layouts:  # (built once per destination: building the primitives is what costs)
            self._layouts[key] = self._layout_primitives(key)
        cubes, texts = self._layouts[key]
        texts = texts + [_text(w / 2, h + 0.4, 0.5, title, 14)]
        return fm.SceneUpdate(
            entities=[_entity(step.t_action, "layout", meta={"episode": str(step.episode)}, cubes=cubes, texts=texts)]
        )

    def _layout_primitives(self, dest: int | None) -> tuple[list, list]:
        """The layout's cubes and labels: the maze's walls, start and goal; taxi's walls and stands (`dest`: the
        episode's destination stand)."""
        h, w = self.size
        cubes = [_cube(w / 2, h / 2, -0.05, w, h, 0.1, _colour(0.85, 0.85, 0.82))]
        texts = []
        if self.kind == "maze":
            m = self.maze
            for r in range(h):
                for c in range(w):
                    if m.walls[r][c]:
                        x, y = self._xy((r, c))
                        cubes.append(_cube(x, y, 0.25, 1.0, 1.0, 0.5, _colour(0.25, 0.27, 0.3)))
            for cell, colour, label in (
                (m.goal, _colour(0.1, 0.75, 0.3), "goal"),
                (m.start, _colour(0.3, 0.5, 0.95), "start"),
            ):
                x, y = self._xy(cell)
                cubes.append(_cube(x, y, 0.01, 0.9, 0.9, 0.02, colour))
                texts.append(_text(x, y, 0.6, label, 12))
        else:
            cubes += self._taxi_walls()
            for i, ((r, c), rgb) in enumerate(zip(self.stands, _STAND_COLOURS)):
                x, y = self._xy((r, c))
                cubes.append(_cube(x, y, 0.01, 0.9, 0.9, 0.02 if i != dest else 0.12, _colour(*rgb, 0.9)))
                texts.append(_text(x, y, 0.6, _STANDS[i] + (" (destination)" if i == dest else ""), 12))
        return cubes, texts

    def agent_update(self, step: Any, before: tuple[int, int], after: tuple[int, int]) -> Any:
        x, y = self._xy(after)
        bx, by = self._xy(before)
        names = _ACTIONS[self.kind]
        action = names[step.action] if 0 <= step.action < len(names) else str(step.action)
        prims: dict[str, list] = {
            "spheres": [
                fm.SpherePrimitive(
                    pose=_pose(x, y, 0.35),
                    size=_vector(0.6, 0.6, 0.6),
                    color=_colour(0.95, 0.55, 0.1) if self.kind == "maze" else _colour(0.95, 0.8, 0.1),
                )
            ]
        }
        move = (_MOVES if self.kind == "maze" else _TAXI_MOVES).get(step.action)
        if move is not None:
            prims["arrows"] = [_arrow(bx, by, move, _colour(0.1, 0.1, 0.1, 0.8))]
        prims["texts"] = [_text(x, y, 0.9, f"step {step.seq} {action} r={step.reward:g}", 11)]
        if self.kind == "taxi" and _taxi_passenger(step.next_obs) < 4:
            px, py = self._xy(self.stands[_taxi_passenger(step.next_obs)])
            prims["spheres"].append(
                fm.SpherePrimitive(pose=_pose(px, py, 0.3), size=_vector(0.3, 0.3, 0.3), color=_colour(0.6, 0.2, 0.8))
            )
        return fm.SceneUpdate(entities=[_entity(step.t_action, "agent", **prims)])

    def feedback_update(self, credit: Any) -> Any:
        good = credit.value > 0
        rgb = (0.1, 0.8, 0.25) if good else (0.9, 0.15, 0.15)
        cubes, texts, arrows = [], [], []
        # (a step from before this builder started has no cell)
        held = [(s, cell) for s in credit.steps if (cell := self._cells.get((credit.actor, s.seq))) is not None]
        drawn = held
        if len(held) > MAX_TILES:  # the heaviest, the latest among equals, in the credit's order
            kept = {s.seq for s, _ in heapq.nlargest(MAX_TILES, held, key=lambda sc: (sc[0].weight, sc[0].seq))}
            drawn = [(s, cell) for s, cell in held if s.seq in kept]
        for s, (before, _, action) in drawn:
            x, y = self._xy(before)
            cubes.append(_cube(x, y, 0.03, 0.95, 0.95, 0.06, _colour(*rgb, 0.2 + 0.8 * s.weight)))
            texts.append(_text(x, y, 0.5, f"{credit.value:+d} w={s.weight:.2f} (step {s.seq})", 11))
            move = (_MOVES if self.kind == "maze" else _TAXI_MOVES).get(action)
            if move is not None:
                arrows.append(_arrow(x, y, move, _colour(*rgb, 0.9), z=0.1))
        if len(drawn) < len(held):
            h, w = self.size
            rest = len(held) - len(drawn)
            texts.append(_text(w / 2, -0.4, 0.5, f"and {rest} more credited steps (lighter; listed in metadata)", 11))
        if not cubes:
            h, w = self.size
            texts.append(
                _text(
                    w / 2,
                    -0.4,
                    0.5,
                    f"feedback {credit.value:+d} from {credit.teacher_id}: {credit.status}",
                    12,
                    _colour(*rgb),
                )
            )
        meta = {
            "teacher": credit.teacher_id,
            "seq": str(credit.seq),
            "value": str(credit.value),
            "status": credit.status,
            "lost_mass": f"{credit.lost_mass:.3f}",
            "steps": " ".join(f"{s.seq}:{s.weight:.3f}" for s in credit.steps),
        }
        eid = f"feedback/{credit.teacher_id}/{credit.seq}"
        return fm.SceneUpdate(
            entities=[
                _entity(credit.t_reaction, eid, FEEDBACK_LIFETIME_S, meta, cubes=cubes, texts=texts, arrows=arrows)
            ]
        )

    def _taxi_walls(self) -> list:
        walls = []
        for r in range(5):
            row = self.desc[1 + r]
            for c in range(4):
                if row[2 * c + 2] == "|":
                    x, y = self._xy((r, c))
                    walls.append(_cube(x + 0.5, y, 0.25, 0.08, 1.0, 0.5, _colour(0.25, 0.27, 0.3)))
        return walls


def derived_records(run: str, message: Any, scene: SceneBuilder | None, dropped: Any = None) -> list[tuple[str, bytes]]:
    """(key, bytes) a log or a live viewer adds for one decoded message of `run`: the Credits an Ingest carries,
    each as if it had come alone on its own key, and the scene drawn from the message and from those Credits.
    A carried message that cannot stand alone (e.g. over its own size limit) is left out and counted in
    `dropped` (a Counter, `derived_dropped_<reason>`): the Ingest that carried it is logged whole anyway."""
    from common.protocol import ProtocolError, carried

    inner = []
    out = []
    for key, m in carried(message):
        try:  # (checked as part of the message that carried it: only its own size is left to check)
            out.append((key, m.encode_checked()))
        except ProtocolError as e:
            if dropped is not None:
                dropped[f"derived_dropped_{e.reason}"] += 1
            continue
        inner.append((key, m))
    if scene is not None:
        for m in [message] + [m for _, m in inner]:
            out += scene.feed(run, m)
    return out


def _onehot(values: list, start: int, n: int) -> int:
    part = list(values[start : start + n])
    return int(max(range(n), key=lambda i: part[i])) if part else 0


def _taxi_cell(obs: list) -> tuple[int, int]:
    return _onehot(obs, 0, 5), _onehot(obs, 5, 5)


def _taxi_passenger(obs: list) -> int:
    return _onehot(obs, 10, 5)


def _taxi_destination(obs: list) -> int:
    return _onehot(obs, 15, 4)


def scene_available() -> bool:
    """Whether foxglove-sdk (the `foxglove` extra) is installed, so that scenes can be drawn."""
    return fm is not None
