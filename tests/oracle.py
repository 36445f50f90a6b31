"""A plain, one-environment, scalar-Python reference of the foraging environment.

Written straight from the rules in docs/environment.md (NOT from envs/foraging.py), so that the
batched torch environment can be checked against it step for step. Everything here is Python
floats, ints and loops; readability beats speed.

Implementation choices of the project that the spec leaves open and that this oracle mirrors:
- respawn cells come from a counter-based hash stream keyed by (respawn_key, steps before the
  step, agent index); ``respawn_cell`` re-implements the tiny hash with Python ints;
- a box dropped in a step is absent for the whole rest of that step (no later agent can pick
  it, no sensing sees it) and lies at its respawn cell from the next step on;
- an ended environment is frozen: it neither moves nor earns; ``steps`` counts the steps taken;
  its observation is the sensing of the frozen arena (a box dropped in the ending step appears);
- a step's reward is each event's count times the task's value for it, added in the order
  pick_target, pick_other, deliver_target, deliver_other;
- another nest edge carries the paper's cells over with ``m = floor(size)``: bottom ``(m - x, y)``,
  left ``(y, x)``, right ``(y, m - x)``.

The module also holds small helpers that convert between this oracle's per-environment state
and the batched ``envs.ForagingState``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

# The spec's kinematic matrix: (vx, vy, r) = A @ wheels.
A = ((-0.28867513, -0.57735027, 0.8660254),
     (0.5, -1.0, 0.5),
     (0.5, 0.0, 0.5))

MASK31 = 0x7FFFFFFF


def hash31(x: int) -> int:
    """The project's 31-bit integer mixer, on Python ints."""
    x = (((x >> 16) ^ x) * 0x45D9F3B) & MASK31
    x = (((x >> 16) ^ x) * 0x45D9F3B) & MASK31
    return (x >> 16) ^ x


def respawn_cell(key: int, steps: int, agent: int, size: float, drop_zone: str = "top") -> tuple[int, int]:
    """Integer cell (x in {6..size-2}, y in {2..size-2} with the nest on top) for a box dropped by
    ``agent`` at the step where the environment's step counter (before the step) is ``steps``."""
    base = hash31(hash31(key & MASK31) ^ steps) ^ (agent * 2)
    hx, hy = hash31(base), hash31(base ^ 1)
    high = int(size) - 1
    x, y = 6 + hx % (high - 6), 2 + hy % (high - 2)
    m = math.floor(size)
    return {"top": (x, y), "bottom": (m - x, y), "left": (y, x), "right": (y, m - x)}[drop_zone]


def nest_depth(config, x: float, y: float, drop_zone: str) -> float:
    """A robot's distance to the nest's edge; it is in the nest below 1."""
    return {"top": x, "bottom": config.size - x, "left": y, "right": config.size - y}[drop_zone]


@dataclass
class OracleState:
    """One environment. Lists are per agent (ax, ay, heading, carrying) or per box."""

    ax: list[float]
    ay: list[float]
    heading: list[float]
    carrying: list[int]          # box index or -1
    bx: list[float]
    by: list[float]
    color: list[int]
    present: list[bool]          # lying in the arena (not carried, not gone)
    target: int
    season: tuple[int, ...]
    steps: int = 0
    retrieved: int = 0
    done: bool = False
    respawn_key: int = 0
    hidden: set = field(default_factory=set)  # boxes dropped in the last step: not yet sensed
    drop_zone: str = "top"
    rewards: tuple[float, float, float, float] = (1.0, -1.0, 2.0, 0.0)  # pick target/other, deliver target/other
    failed_robots: int = 0       # the highest-index robots do nothing
    motor_gain: float = 1.0


class Oracle:
    """The spec, one environment at a time."""

    def __init__(self, config, state: OracleState):
        self.c = config
        self.s = state
        self.last_obs = self.observe()

    # ---------------------------------------------------------------- sensing
    def candidates(self, i: int) -> list[tuple[int, float, float]]:
        """(type, distance, direction in degrees) of everything agent i senses, in the
        spec's order (walls top/bottom/left/right, other agents, boxes), before sorting."""
        c, s = self.c, self.s
        ax, ay = s.ax[i], s.ay[i]
        out = []
        # Walls: strictly < sensor_range. Bottom and right carry the odd "- 1" (the spec keeps it,
        # so a distance can be negative near those edges).
        walls = ((ax, 0.0), (c.size - ax - 1, 180.0), (ay, 90.0), (c.size - ay - 1, 270.0))
        for dist, direction in walls:
            if dist < c.sensor_range:
                out.append((1, dist, direction))
        if c.see_other_agents:
            for j in range(c.n_agents):
                if j == i:
                    continue
                dist = math.hypot(ax - s.ax[j], ay - s.ay[j])
                if dist <= c.sensor_range:  # inclusive, unlike walls
                    out.append((2, dist, direction_deg(ax, ay, s.ax[j], s.ay[j])))
        for k in range(c.n_boxes):
            if not s.present[k] or k in s.hidden:
                continue
            dist = math.hypot(ax - s.bx[k], ay - s.by[k])
            if dist <= c.sensor_range:  # inclusive, unlike walls
                out.append((s.color[k], dist, direction_deg(ax, ay, s.bx[k], s.by[k])))
        return out

    def neighbours(self, i: int) -> list[tuple[int, float, float]]:
        """The first n_neighbors candidates by distance (stable sort), padded with (0, 0, 0)."""
        cands = sorted(self.candidates(i), key=lambda t: t[1])  # Python's sort is stable
        kept = cands[: self.c.n_neighbors]
        return kept + [(0, 0.0, 0.0)] * (self.c.n_neighbors - len(kept))

    def observe_agent(self, i: int) -> list[float]:
        c, s = self.c, self.s
        n_col = len(c.colors)
        nb = self.neighbours(i)
        obs: list[float] = []
        for typ, _, _ in nb:  # 1. type one-hot per neighbour (an empty slot is type 0 "nothing")
            one = [0.0] * (n_col + 3)
            one[typ] = 1.0
            obs += one
        obs += [d / c.sensor_range for _, d, _ in nb]  # 2. distances
        sins, coss = [], []
        for typ, _, direction in nb:  # 3. sin, then cos of the directions (0 for an empty slot)
            if typ == 0:
                sins.append(0.0)
                coss.append(0.0)
            else:
                sins.append(math.sin(math.radians(direction)))
                coss.append(math.cos(math.radians(direction)))
        obs += sins + coss
        obs += [math.sin(math.radians(s.heading[i])), math.cos(math.radians(s.heading[i]))]  # 4.
        carried = [0.0] * (n_col + 1)  # 5. carried one-hot: 0 nothing, colour - 2 otherwise
        if s.carrying[i] < 0:
            carried[0] = 1.0
        else:
            carried[s.color[s.carrying[i]] - 2] = 1.0
        obs += carried
        tgt = [0.0] * n_col  # 6. target one-hot at target - 3
        tgt[s.target - 3] = 1.0
        obs += tgt
        return obs

    def observe(self) -> list[list[float]]:
        return [self.observe_agent(i) for i in range(self.c.n_agents)]

    # ---------------------------------------------------------------- step
    def step(self, wheels):
        """wheels: per agent, 3 wheel speeds. Returns (obs, reward, done, events) where events
        has per-agent lists picked, dropped (box index or -1), drop_correct (bool) and
        respawn_cell ((x, y) or (-1, -1))."""
        c, s = self.c, self.s
        A_n = c.n_agents
        events = {"picked": [-1] * A_n, "dropped": [-1] * A_n, "drop_correct": [False] * A_n,
                  "respawn_cell": [(-1, -1)] * A_n}
        s.hidden = set()  # boxes dropped in the previous step become visible now
        if s.done:
            # Frozen: no motion, no reward, no counting. The agents still sense the (unchanged)
            # arena, so a box dropped in the ending step shows up at its respawn cell, as the
            # spec's "visible from the next step on" says.
            self.last_obs = self.observe()
            return self.last_obs, 0.0, True, events
        steps_before = s.steps
        dt = c.time_step
        working = A_n - s.failed_robots  # robots working..A_n - 1 have failed: they do nothing
        # 1. kinematics (arena frame: the heading does not rotate the motion) of the worn wheels
        for i in range(working):
            w = [speed * s.motor_gain for speed in wheels[i]]
            vx = A[0][0] * w[0] + A[0][1] * w[1] + A[0][2] * w[2]
            vy = A[1][0] * w[0] + A[1][1] * w[1] + A[1][2] * w[2]
            r = A[2][0] * w[0] + A[2][1] * w[1] + A[2][2] * w[2]
            s.ax[i] = min(max(s.ax[i] + vx * dt, 0.0), c.size)
            s.ay[i] = min(max(s.ay[i] + vy * dt, 0.0), c.size)
            s.heading[i] = (s.heading[i] + math.degrees(r / 12.5 * dt)) % 360.0
        # 2.-3. agents in index order: pick, then drop
        count = {"pick_target": 0, "pick_other": 0, "deliver_target": 0, "deliver_other": 0}
        for i in range(working):
            if s.carrying[i] < 0:
                best, best_d = -1, math.inf
                for k in range(c.n_boxes):  # nearest box in the arena, lowest index on a tie
                    if not s.present[k] or k in s.hidden:
                        continue
                    d = math.hypot(s.ax[i] - s.bx[k], s.ay[i] - s.by[k])
                    if d < best_d:
                        best, best_d = k, d
                if best >= 0 and best_d < c.sensitivity:  # strict
                    s.carrying[i] = best
                    s.present[best] = False  # leaves the arena at once
                    events["picked"][i] = best
                    count["pick_target" if s.color[best] == s.target else "pick_other"] += 1
            if s.carrying[i] >= 0 and nest_depth(c, s.ax[i], s.ay[i], s.drop_zone) < 1.0:
                k = s.carrying[i]
                s.carrying[i] = -1
                correct = s.color[k] == s.target
                events["dropped"][i] = k
                events["drop_correct"][i] = correct
                count["deliver_target" if correct else "deliver_other"] += 1
                if correct:
                    s.retrieved += 1
                if c.repositioning:
                    cx, cy = respawn_cell(s.respawn_key, steps_before, i, c.size, s.drop_zone)
                    s.bx[k], s.by[k] = float(cx), float(cy)
                    s.present[k] = True
                    s.hidden.add(k)  # not sensed in this step
                    events["respawn_cell"][i] = (cx, cy)
        reward = 0.0
        for n, value in zip(count.values(), s.rewards):
            reward += n * value
        s.steps += 1
        s.done = s.retrieved >= c.max_retrieves or s.steps >= c.duration
        # 4. sensing
        self.last_obs = self.observe()
        return self.last_obs, reward, s.done, events

    def set_task(self, task) -> None:
        """Take over every field of ``task`` (an ``envs.Task``)."""
        self.s.target, self.s.season = int(task.target), tuple(task.season)
        self.s.drop_zone, self.s.rewards = task.drop_zone, task.rewards.values()
        self.s.failed_robots, self.s.motor_gain = task.failed_robots, task.motor_gain
        self.last_obs = self.observe()


def direction_deg(ax: float, ay: float, ex: float, ey: float) -> float:
    """Direction of (ex, ey) seen from (ax, ay): 0 towards the top (x = 0), 90 towards the left."""
    return math.degrees(math.atan2(ay - ey, ax - ex)) % 360.0


# -------------------------------------------------------------------- conversions
def oracle_states_from(state) -> list[OracleState]:
    """Per-environment oracle states from a batched ``ForagingState`` (tensors, batch first)."""
    out = []
    B = state.agent_pos.shape[0]
    n_colors = state.season.shape[1]
    for b in range(B):
        season = tuple(3 + j for j in range(n_colors) if bool(state.season[b, j]))
        out.append(OracleState(
            ax=[float(v) for v in state.agent_pos[b, :, 0]],
            ay=[float(v) for v in state.agent_pos[b, :, 1]],
            heading=[float(v) for v in state.heading[b]],
            carrying=[int(v) for v in state.carrying[b]],
            bx=[float(v) for v in state.box_pos[b, :, 0]],
            by=[float(v) for v in state.box_pos[b, :, 1]],
            color=[int(v) for v in state.box_color[b]],
            present=[bool(v) for v in state.box_present[b]],
            target=int(state.target[b]), season=season,
            steps=int(state.steps[b]), retrieved=int(state.retrieved[b]), done=bool(state.done[b]),
            respawn_key=int(state.respawn_key[b]),
            drop_zone=("top", "bottom", "left", "right")[int(state.drop_zone[b])],
            rewards=tuple(float(v) for v in state.rewards[b]), failed_robots=int(state.failed_robots[b]),
            motor_gain=float(state.motor_gain[b])))
    return out


def batched_state_from(states: list[OracleState], n_colors: int, dtype=None):
    """A batched ``ForagingState`` (float64 unless ``dtype``) from oracle states."""
    import torch

    from envs import ForagingState

    dtype = dtype or torch.float64
    season = torch.zeros(len(states), n_colors, dtype=torch.bool)
    for b, s in enumerate(states):
        for color in s.season:
            season[b, color - 3] = True
    return ForagingState(
        agent_pos=torch.tensor([[[x, y] for x, y in zip(s.ax, s.ay)] for s in states], dtype=dtype),
        heading=torch.tensor([s.heading for s in states], dtype=dtype),
        carrying=torch.tensor([s.carrying for s in states], dtype=torch.long),
        box_pos=torch.tensor([[[x, y] for x, y in zip(s.bx, s.by)] for s in states], dtype=dtype),
        box_color=torch.tensor([s.color for s in states], dtype=torch.long),
        box_present=torch.tensor([s.present for s in states], dtype=torch.bool),
        target=torch.tensor([s.target for s in states], dtype=torch.long),
        season=season,
        drop_zone=torch.tensor([("top", "bottom", "left", "right").index(s.drop_zone) for s in states]),
        rewards=torch.tensor([s.rewards for s in states], dtype=dtype),
        failed_robots=torch.tensor([s.failed_robots for s in states], dtype=torch.long),
        motor_gain=torch.tensor([s.motor_gain for s in states], dtype=dtype),
        steps=torch.tensor([s.steps for s in states], dtype=torch.long),
        retrieved=torch.tensor([s.retrieved for s in states], dtype=torch.long),
        done=torch.tensor([s.done for s in states], dtype=torch.bool),
        respawn_key=torch.tensor([s.respawn_key for s in states], dtype=torch.long))
