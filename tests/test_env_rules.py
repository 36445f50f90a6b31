"""One small hand-built scenario per rule of the environment (docs/environment.md).

Each test builds an explicit state (mostly one environment), steps the batched environment with
known wheel speeds and reads the observation back through ``decode`` (the spec's layout).
"""
from __future__ import annotations

import contextlib
import math
import random
from collections import Counter

import pytest
import torch
from torch._dynamo.utils import counters
from torch.utils._python_dispatch import TorchDispatchMode

from envs import TASKS, ConfigError, ForagingConfig, ForagingEnv, Rewards, Task, outputs_to_wheels
from envs.execution import COMPILE_OPTIONS
from envs.foraging import _remainder, hash31, respawn_cells

try:
    from oracle import A, OracleState, batched_state_from, respawn_cell
    from oracle import hash31 as py_hash31
    from test_env_oracle import DRIFTS
except ImportError:  # tests/ imported as a package
    from tests.oracle import A, OracleState, batched_state_from, respawn_cell
    from tests.oracle import hash31 as py_hash31
    from tests.test_env_oracle import DRIFTS

F64 = torch.float64
# inverse of the spec's kinematic matrix: wheels for a wanted (vx, vy, r)
A_INV = ((-0.8660254100688773, 0.5000000043301269, 1.0),
         (0.0, -1.0, 1.0),
         (0.8660254100688773, -0.500000004330127, 1.0))


def wheels_for(vx, vy, r=0.0):
    return [A_INV[j][0] * vx + A_INV[j][1] * vy + A_INV[j][2] * r for j in range(3)]

RED, BLUE, GREEN, YELLOW = 3, 4, 5, 6
WALL, AGENT = 1, 2


# ---------------------------------------------------------------------------- helpers
N_FILLED = 12


def make_state(agents, boxes, task=TASKS["red"], steps=0, retrieved=0, done=False, key=12345,
               fill=True) -> OracleState:
    """agents: (x, y[, heading[, carrying]]); boxes: (x, y, colour[, present]).

    ``fill``: pad with filler boxes (higher indices, stacked on the integer cell farthest from
    every agent, never sensed nor reached in these short scenarios) up to ``N_FILLED`` boxes, so
    that each scenario tests its own rule and not the separate few-boxes case (see
    ``test_padding_with_fewer_boxes_than_slots``).
    """
    agents = [tuple(a) + (180.0, -1)[len(a) - 2:] for a in agents]
    boxes = [tuple(b) + (True,)[len(b) - 3:] for b in boxes]
    if fill and len(boxes) < N_FILLED:
        cells = [(x, y) for x in range(21) for y in range(21)]
        far = max(cells, key=lambda cell: min(math.hypot(cell[0] - a[0], cell[1] - a[1]) for a in agents))
        assert min(math.hypot(far[0] - a[0], far[1] - a[1]) for a in agents) > 5.0
        boxes += [(far[0], far[1], task.season[-1], True)] * (N_FILLED - len(boxes))
    present = [bool(b[3]) for b in boxes]
    for a in agents:
        if a[3] >= 0:
            present[a[3]] = False
    return OracleState(ax=[float(a[0]) for a in agents], ay=[float(a[1]) for a in agents],
                       heading=[float(a[2]) for a in agents], carrying=[int(a[3]) for a in agents],
                       bx=[float(b[0]) for b in boxes], by=[float(b[1]) for b in boxes],
                       color=[int(b[2]) for b in boxes], present=present,
                       target=task.target, season=tuple(task.season), steps=steps, retrieved=retrieved,
                       done=done, respawn_key=key, drop_zone=task.drop_zone, rewards=task.rewards.values(),
                       failed_robots=task.failed_robots, motor_gain=task.motor_gain)


def make_env(agents, boxes, task=TASKS["red"], dtype=F64, steps=0, retrieved=0, done=False, key=12345, **options):
    """A one-environment batch holding exactly this state; returns (env, observations)."""
    state = make_state(agents, boxes, task, steps, retrieved, done, key, fill=options.pop("fill", True))
    config = ForagingConfig(n_agents=len(agents), n_boxes=len(state.bx), **options)
    env = ForagingEnv(config, batch_size=1, device="cpu", dtype=dtype)
    obs = env.reset(state=batched_state_from([state], config.n_colors, dtype=dtype))
    return env, obs


def step(env, wheels=None):
    """Step a batch with per-agent wheel speeds (default: all zero, nobody moves)."""
    c = env.config
    w = torch.zeros(env.batch_size, c.n_agents, 3, dtype=env.dtype)
    if wheels is not None:
        w[:] = torch.as_tensor(wheels, dtype=env.dtype)
    return env.step(w)


def decode(row, config):
    """Split one agent's observation by the spec's layout."""
    row = [float(v) for v in row]
    c, n = config.n_colors, config.n_neighbors
    t = c + 3
    types = []
    for j in range(n):
        one = row[j * t:(j + 1) * t]
        assert sorted(one) == [0.0] * (t - 1) + [1.0], f"slot {j} type is not one-hot: {one}"
        types.append(one.index(1.0))
    o = t * n
    dist = [d * config.sensor_range for d in row[o:o + n]]
    sin, cos = row[o + n:o + 2 * n], row[o + 2 * n:o + 3 * n]
    o += 3 * n
    heading = row[o:o + 2]
    carried = row[o + 2:o + 2 + c + 1]
    target = row[o + 3 + c:o + 3 + 2 * c]
    assert len(row) == o + 3 + 2 * c == config.obs_dim
    return {"slots": list(zip(types, dist, sin, cos)), "types": types, "dist": dist, "sin": sin, "cos": cos,
            "heading": heading, "carried": carried, "target": target}


def approx(a, b, tol=1e-9):
    return all(abs(x - y) <= tol for x, y in zip(a, b)) and len(a) == len(b)


# ---------------------------------------------------------------------------- sensing
def test_walls_strictly_inside_range_boxes_inclusive():
    # agent 0: top wall at exactly 4 (not sensed), box at exactly 4 (sensed)
    # agent 1: top wall at 3.999 (sensed); bottom wall at exactly 4 for agent 2 (size - x - 1 = 4)
    env, obs = make_env([(4.0, 10.0), (3.999, 3.0), (15.0, 10.0), (15.01, 10.0)],
                        [(8.0, 10.0, RED), (19.0, 12.0, BLUE)])
    c = env.config
    d0 = decode(obs[0, 0], c)
    assert d0["types"] == [RED, 0, 0], f"wall at exactly sensor_range must be excluded, box at it included: {d0['slots']}"
    assert d0["dist"][0] == pytest.approx(4.0)
    d1 = decode(obs[0, 1], c)
    assert d1["types"][:2] == [WALL, WALL] and d1["dist"][:2] == pytest.approx([3.0, 3.999])
    d2 = decode(obs[0, 2], c)
    assert d2["types"] == [0, 0, 0], f"bottom wall at distance size - x - 1 = 4 must not be sensed: {d2['slots']}"
    d3 = decode(obs[0, 3], c)
    assert d3["types"][0] == WALL and d3["dist"][0] == pytest.approx(3.99)


def test_bottom_and_right_walls_have_the_minus_one():
    env, obs = make_env([(19.5, 19.8), (20.0, 0.0), (18.5, 10.0)], [(8.0, 8.0, RED)])
    c = env.config
    d = decode(obs[0, 0], c)
    # right: 20 - 19.8 - 1 = -0.8, bottom: 20 - 19.5 - 1 = -0.5; both negative, sorted first
    assert d["types"] == [WALL, WALL, 0]
    assert d["dist"][:2] == pytest.approx([-0.8, -0.5]), "bottom/right wall distance must be size - coord - 1"
    assert approx(d["sin"][:2], [-1.0, 0.0], 1e-12) and approx(d["cos"][:2], [0.0, -1.0], 1e-12), \
        "right wall reads direction 270, bottom 180"
    d = decode(obs[0, 1], c)  # on the bottom-left corner: bottom -1, left 0
    assert d["types"] == [WALL, WALL, 0] and d["dist"][:2] == pytest.approx([-1.0, 0.0])
    assert approx(d["sin"][:2], [0.0, 1.0], 1e-12) and approx(d["cos"][:2], [-1.0, 0.0], 1e-12)
    d = decode(obs[0, 2], c)  # 20 - 18.5 - 1 = 0.5
    assert d["types"][0] == WALL and d["dist"][0] == pytest.approx(0.5)


@pytest.mark.parametrize("offset, sin, cos", [((-2, 0), 0.0, 1.0),    # towards the top: 0 degrees
                                              ((0, -2), 1.0, 0.0),    # towards the left: 90
                                              ((2, 0), 0.0, -1.0),    # towards the bottom: 180
                                              ((0, 2), -1.0, 0.0),    # towards the right: 270
                                              ((-2, -2), math.sqrt(.5), math.sqrt(.5))])  # 45
def test_direction_convention(offset, sin, cos):
    env, obs = make_env([(10.0, 10.0)], [(10 + offset[0], 10 + offset[1], GREEN)], task=TASKS["green"])
    d = decode(obs[0, 0], env.config)
    assert d["types"] == [GREEN, 0, 0]
    assert d["sin"][0] == pytest.approx(sin, abs=1e-12) and d["cos"][0] == pytest.approx(cos, abs=1e-12), \
        f"entity at offset {offset}: expected sin {sin} cos {cos}, got {d['sin'][0]} {d['cos'][0]}"
    assert d["sin"][1:] == [0.0, 0.0] and d["cos"][1:] == [0.0, 0.0], "empty slots read sin = cos = 0"


def test_own_heading_sin_cos():
    env, obs = make_env([(10.0, 10.0, 30.0), (10.0, 5.0, 270.0)], [(15.0, 15.0, RED)])
    c = env.config
    assert decode(obs[0, 0], c)["heading"] == pytest.approx([0.5, math.cos(math.radians(30))])
    assert decode(obs[0, 1], c)["heading"] == pytest.approx([-1.0, 0.0], abs=1e-12)


def test_stable_tie_order_wall_before_box_and_lower_box_index_first():
    # agent at (3, 10): top wall at 3; box 2 at (6, 10) also at 3 -> wall first.
    env, obs = make_env([(3.0, 10.0)], [(9.0, 9.0, RED), (9.0, 9.0, BLUE), (6.0, 10.0, GREEN)])
    d = decode(obs[0, 0], env.config)
    assert d["types"][:2] == [WALL, GREEN], f"at equal distance the wall comes before the box: {d['slots']}"
    # boxes at equal distance: index order, regardless of direction or colour
    env, obs = make_env([(10.0, 10.0)], [(10.0, 13.0, BLUE), (10.0, 7.0, RED), (13.0, 10.0, GREEN),
                                         (7.0, 10.0, YELLOW)])
    d = decode(obs[0, 0], env.config)
    assert d["types"] == [BLUE, RED, GREEN], f"equal distances keep box index order: {d['slots']}"
    # stacked boxes: the lower index first
    env, obs = make_env([(10.0, 10.0)], [(15.0, 15.0, RED), (12.0, 12.0, YELLOW), (12.0, 12.0, BLUE)])
    d = decode(obs[0, 0], env.config)
    assert d["types"] == [YELLOW, BLUE, 0]
    # walls among themselves: top, bottom, left, right (corner at equal distances)
    env, obs = make_env([(2.0, 2.0), (17.0, 17.0)], [(10.0, 10.0, RED)])
    assert decode(obs[0, 0], env.config)["sin"][:2] == pytest.approx([0.0, 1.0]), "top before left"
    assert decode(obs[0, 1], env.config)["sin"][:2] == pytest.approx([0.0, -1.0]), "bottom before right"


def test_other_agents_sensed_inclusive_after_walls_before_boxes():
    # agent 1 exactly 4 away (sensed, <=); agent 2 at 3 and box at 3 (agent first); carried box unseen
    agents = [(10.0, 10.0), (10.0, 14.0, 180.0, 1), (13.0, 10.0), (10.0, 5.9)]
    boxes = [(7.0, 10.0, RED), (10.0, 11.0, BLUE)]
    env, obs = make_env(agents, boxes, see_other_agents=True)
    d = decode(obs[0, 0], env.config)
    assert d["types"] == [AGENT, RED, AGENT], f"agents: inclusive range, before boxes on ties: {d['slots']}"
    assert d["dist"] == pytest.approx([3.0, 3.0, 4.0])
    env, obs = make_env(agents, boxes, see_other_agents=False)
    assert decode(obs[0, 0], env.config)["types"] == [RED, 0, 0], "see_other_agents=False hides agents"


def test_see_other_agents_with_a_batch_of_several_environments():
    config = ForagingConfig(see_other_agents=True)
    env = ForagingEnv(config, batch_size=3, device="cpu", dtype=F64)
    try:
        obs = env.reset(tasks=TASKS["red"], generator=0)
        obs, *_ = step(env)
    except RuntimeError as e:
        raise AssertionError(f"BUG: see_other_agents=True crashes for batch_size > 1: {e}") from e
    assert obs.shape == (3, 5, 41)


def test_truncation_to_n_neighbors_and_padding():
    boxes = [(12.0, 10.0, RED), (10.0, 11.0, BLUE), (13.0, 12.0, GREEN), (10.0, 8.0, YELLOW), (11.0, 11.0, GREEN)]
    env, obs = make_env([(10.0, 10.0), (10.0, 16.0)], boxes)
    c = env.config
    d = decode(obs[0, 0], c)
    # distances: 2, 1, 3.6, 2, 1.414 -> the three nearest are box 1, box 4, box 0 (box 3 ties, later index)
    assert d["types"] == [BLUE, GREEN, RED] and d["dist"] == pytest.approx([1.0, math.sqrt(2), 2.0])
    d = decode(obs[0, 1], c)  # (10, 16): right wall at 3, box 1 at 5 (out), nothing else
    assert d["types"] == [WALL, 0, 0] and d["dist"] == [3.0, 0.0, 0.0]
    assert d["slots"][1:] == [(0, 0.0, 0.0, 0.0)] * 2, "a missing slot is (0, 0, 0): type 'nothing' one-hot"
    env, obs = make_env([(10.0, 10.0)], boxes, n_neighbors=2)
    assert decode(obs[0, 0], env.config)["types"] == [BLUE, GREEN]


@pytest.mark.parametrize("n_boxes", [1, 2])
def test_padding_with_fewer_boxes_than_slots(n_boxes):
    # n_neighbors = 3 but only n_boxes boxes exist: one box in range, the rest far away
    boxes = [(8.0, 10.0, RED), (18.0, 18.0, BLUE)][:n_boxes]
    env, obs = make_env([(5.0, 10.0)], boxes, fill=False)
    d = decode(obs[0, 0], env.config)
    assert d["types"] == [RED, 0, 0], (f"BUG: with {n_boxes} box(es) and 3 slots, one box at distance 3 "
                                       f"reads {d['slots']}; expected [box, (0,0,0), (0,0,0)]")


@pytest.mark.parametrize("n_neighbors", [4, 5, 6, 8])
def test_padding_with_many_neighbour_slots(n_neighbors):
    # one wall and one box in range; every other slot must be (0, 0, 0)
    env, obs = make_env([(2.0, 10.0)], [(5.0, 10.0, RED), (15.0, 15.0, BLUE)], n_neighbors=n_neighbors)
    d = decode(obs[0, 0], env.config)
    expected = [WALL, RED] + [0] * (n_neighbors - 2)
    assert d["types"] == expected, (f"BUG: n_neighbors={n_neighbors}: slots {d['slots']}; expected types "
                                    f"{expected} (empty slots padded with nothing)")
    assert d["dist"] == pytest.approx([2.0, 3.0] + [0.0] * (n_neighbors - 2))


def test_carried_one_hot_and_target_one_hot():
    env, obs = make_env([(10.0, 10.0, 180.0, 0), (10.0, 4.0), (15.0, 4.0, 180.0, 1)],
                        [(15.0, 15.0, GREEN), (8.0, 8.0, YELLOW)], task=TASKS["green"])
    c = env.config
    d = decode(obs[0, 0], c)
    assert d["carried"] == [0, 0, 0, 1, 0], "carrying colour 5: index 5 - 2 = 3"
    assert d["target"] == [0, 0, 1, 0], "target 5: index 5 - 3 = 2"
    assert decode(obs[0, 1], c)["carried"] == [1, 0, 0, 0, 0], "nothing: index 0"
    assert decode(obs[0, 2], c)["carried"] == [0, 0, 0, 0, 1]
    assert GREEN not in decode(obs[0, 0], c)["types"] + decode(obs[0, 1], c)["types"], "a carried box is not sensed"
    state = make_state([(10.0, 10.0, 0.0, 0)], [(8.0, 8.0, 10)], task=TASKS["cyan"])
    config = ForagingConfig(colors=tuple(range(3, 11)), n_agents=1, n_boxes=len(state.bx))
    env = ForagingEnv(config, 1, dtype=F64)
    obs = env.reset(state=batched_state_from([state], 8))
    d = decode(obs[0, 0], config)
    assert d["carried"] == [0] * 8 + [1] and d["target"] == [0] * 6 + [1, 0]


# ---------------------------------------------------------------------------- picks
def test_pick_radius_is_strict():
    env, obs = make_env([(10.5, 10.0), (5.0, 15.49), (12.0, 5.51)],
                        [(10.0, 10.0, RED), (5.0, 15.0, RED), (12.0, 6.0, RED)])
    obs, reward, done, info = step(env)
    assert info["picked"][0].tolist() == [-1, 1, 2], "distance exactly 0.5 must not pick; 0.49 must"
    assert reward.item() == 2.0
    assert env.state.carrying[0].tolist() == [-1, 1, 2]
    assert env.state.box_present[0, :3].tolist() == [True, False, False]


def test_pick_any_color_wrong_color_costs_one():
    env, obs = make_env([(10.2, 10.0), (12.0, 14.3)], [(10.0, 10.0, BLUE), (12.0, 14.0, RED)])
    obs, reward, done, info = step(env)
    assert info["picked"][0].tolist() == [0, 1]
    assert reward.item() == 0.0  # -1 for blue, +1 for red
    env, obs = make_env([(10.2, 10.0)], [(10.0, 10.0, BLUE)])
    obs, reward, done, info = step(env)
    assert reward.item() == -1.0
    assert decode(obs[0, 0], env.config)["carried"] == [0, 0, 1, 0, 0], "carries the blue box (index 4 - 2)"


def test_nearest_box_picked_lowest_index_on_tie_and_carrier_does_not_pick():
    env, obs = make_env([(10.0, 10.25), (14.0, 14.0, 180.0, 3)],
                        [(10.0, 11.0, BLUE), (10.0, 10.0, YELLOW), (10.0, 10.0, RED), (14.0, 14.0, RED)])
    obs, reward, done, info = step(env)
    assert info["picked"][0].tolist() == [1, -1], "nearest box, the lower index of a stack; a carrier picks nothing"
    assert env.state.box_present[0, :4].tolist() == [True, False, True, False]


def test_two_agents_on_one_box_lower_index_wins_and_stack_goes_to_the_next():
    # agent 1 is nearer, but agent 0 acts first
    env, obs = make_env([(10.4, 10.0), (10.0, 10.1)], [(10.0, 10.0, RED), (15.0, 15.0, BLUE)])
    obs, reward, done, info = step(env)
    assert info["picked"][0].tolist() == [0, -1] and reward.item() == 1.0
    # a box stacked on the same cell goes to the later agent
    env, obs = make_env([(10.4, 10.0), (10.0, 10.1), (9.8, 10.0)],
                        [(10.0, 10.0, RED), (15.0, 15.0, BLUE), (10.0, 10.0, BLUE), (10.0, 10.0, RED)])
    obs, reward, done, info = step(env)
    assert info["picked"][0].tolist() == [0, 2, 3], "stacked boxes go to agents in index order"
    assert reward.item() == 1.0 - 1.0 + 1.0
    # agent 1's nearest box is taken by agent 0: it then takes its next nearest if within reach
    env, obs = make_env([(10.4, 10.0), (10.0, 10.45)], [(10.0, 10.0, RED), (10.0, 11.0, BLUE)])
    obs, reward, done, info = step(env)
    assert info["picked"][0].tolist() == [0, -1], "the next nearest (0.55 away) is out of reach"
    env, obs = make_env([(10.4, 10.0), (10.0, 10.45)], [(10.0, 10.0, RED), (10.0, 10.0, BLUE)])
    assert step(env)[3]["picked"][0].tolist() == [0, 1]


def test_picked_box_disappears_from_sensing_at_once():
    env, obs = make_env([(10.2, 10.0), (10.0, 12.0)], [(10.0, 10.0, RED), (16.0, 16.0, BLUE)])
    c = env.config
    assert decode(obs[0, 1], c)["types"][0] == RED
    obs, reward, done, info = step(env)
    assert info["picked"][0].tolist() == [0, -1]
    for i in range(2):
        assert RED not in decode(obs[0, i], c)["types"], f"agent {i} still senses the picked box"


def test_pick_then_drop_in_the_same_step():
    # a box lying in the drop zone: the agent picks it (+1) and drops it (+2) in one step
    env, obs = make_env([(0.3, 5.1)], [(0.0, 5.0, RED), (10.0, 10.0, BLUE)], key=77)
    obs, reward, done, info = step(env)
    assert info["picked"][0].tolist() == [0] and info["dropped"][0].tolist() == [0]
    assert reward.item() == 3.0


# ---------------------------------------------------------------------------- drops
def test_drop_zone_is_x_below_one():
    agents = [(0.95, 5.0, 180.0, 0), (1.0, 8.0, 180.0, 1), (0.5, 12.0, 180.0, 2)]
    boxes = [(10.0, 10.0, RED), (12.0, 12.0, RED), (14.0, 14.0, BLUE)]
    env, obs = make_env(agents, boxes, key=4242, steps=7)
    obs, reward, done, info = step(env)
    assert info["dropped"][0].tolist() == [0, -1, 2], "x = 1.0 exactly is not in the drop zone"
    assert info["drop_correct"][0].tolist()[0] is True and info["drop_correct"][0].tolist()[2] is False
    assert reward.item() == 2.0, "a correct retrieval earns +2, a wrong one 0"
    s = env.state
    assert s.retrieved.tolist() == [1] and s.carrying[0].tolist() == [-1, 1, -1]
    cells = [respawn_cell(4242, 7, i, 20) for i in range(3)]
    assert info["respawn_cell"][0, 0].tolist() == list(cells[0]) and info["respawn_cell"][0, 2].tolist() == list(cells[2])
    assert info["respawn_cell"][0, 1].tolist() == [-1, -1]
    assert s.box_pos[0, 0].tolist() == list(cells[0]) and s.box_pos[0, 2].tolist() == list(cells[2])
    assert s.box_present[0, :3].tolist() == [True, False, True]
    assert s.box_color[0, :3].tolist() == [RED, RED, BLUE], "a respawned box keeps its colour"


# a robot carrying a red box just inside each nest edge (depth 0.95) and one just outside (1.0);
# for the top edge these are the scene above
EDGE_DROPS = {
    "top": [(0.95, 5.0), (1.0, 8.0)],
    "bottom": [(19.05, 5.0), (19.0, 8.0)],
    "left": [(5.0, 0.95), (8.0, 1.0)],
    "right": [(5.0, 19.05), (8.0, 19.0)],
}


@pytest.mark.parametrize("edge", list(EDGE_DROPS))
def test_drop_zone_at_each_edge_is_one_unit_deep_strictly(edge):
    inside, outside = EDGE_DROPS[edge]
    task = Task(RED, (RED, BLUE), name=f"red-{edge}", drop_zone=edge)
    env, obs = make_env([(*inside, 180.0, 0), (*outside, 180.0, 1)], [(10.0, 10.0, RED), (12.0, 12.0, RED)],
                        task=task, key=4242, steps=7)
    obs, reward, done, info = step(env)
    assert info["dropped"][0].tolist() == [0, -1], f"{edge}: depth 0.95 drops, depth 1.0 exactly does not"
    assert reward.item() == 2.0 and env.state.retrieved.tolist() == [1]
    cell = respawn_cell(4242, 7, 0, 20, edge)
    assert info["respawn_cell"][0, 0].tolist() == list(cell) and env.state.box_pos[0, 0].tolist() == list(cell)
    # the respawn band follows the edge: 6 to 18 cells away from the nest edge, 2 to 18 across
    depth = {"top": cell[0], "bottom": 20 - cell[0], "left": cell[1], "right": 20 - cell[1]}[edge]
    across = cell[1] if edge in ("top", "bottom") else cell[0]
    assert 6 <= depth <= 18 and 2 <= across <= 18, cell


def test_respawn_cells_of_every_edge_are_the_top_edges_carried_over():
    """Over many drops, every edge's respawn cell is the top edge's cell mirrored or transposed
    (``ZONE_FRAMES``), for the same key, step and robot."""
    cells = respawn_cells(torch.arange(200) * 7919, torch.arange(200), 5, 20)
    env = ForagingEnv(ForagingConfig(), batch_size=200)
    x, y = cells[..., 0], cells[..., 1]
    for index, edge in enumerate(EDGE_DROPS):
        placed = env._to_nest_frame(cells, torch.full((200,), index, dtype=torch.int32))
        expected = {"top": (x, y), "bottom": (20 - x, y), "left": (y, x), "right": (y, 20 - x)}[edge]
        assert torch.equal(placed, torch.stack(expected, dim=-1)), edge


def test_each_reward_value_is_the_tasks():
    """One step with one event of each kind: the reward is each count times the task's value."""
    rewards = Rewards(pick_target=0.25, pick_other=-8.0, deliver_target=64.0, deliver_other=-512.0)
    task = Task(RED, (RED, BLUE), name="odd-rewards", rewards=rewards)
    # robots 0 and 1 on a red and a blue box; 2 and 3 in the nest with a red and a blue box
    agents = [(10.2, 10.0), (12.2, 12.0), (0.5, 3.0, 180.0, 2), (0.5, 6.0, 180.0, 3), (0.6, 9.0, 180.0, 4)]
    boxes = [(10.0, 10.0, RED), (12.0, 12.0, BLUE), (14.0, 2.0, RED), (14.0, 4.0, BLUE), (14.0, 6.0, BLUE)]
    env, obs = make_env(agents, boxes, task=task)
    obs, reward, done, info = step(env)
    assert info["picked"][0].tolist()[:2] == [0, 1] and info["dropped"][0].tolist()[2:] == [2, 3, 4]
    assert reward.item() == 0.25 - 8.0 + 64.0 - 2 * 512.0
    assert env.state.retrieved.tolist() == [1], "only a target box delivered is a retrieval"
    paper, _ = make_env(agents, boxes)
    assert step(paper)[1].item() == 1 - 1 + 2 + 0, "the paper's values are the default"


def test_a_failed_robot_neither_moves_nor_picks_nor_drops_and_is_still_sensed():
    task = Task(RED, (RED, BLUE), name="red-failed", failed_robots=2)
    # robot 2 (working) and robots 3, 4 (failed): 4 sits on a box, 3 carries one in the nest
    agents = [(5.0, 3.0), (5.0, 6.0), (10.2, 10.0), (0.5, 12.0, 90.0, 1), (12.1, 12.0, 45.0)]
    boxes = [(10.0, 10.0, RED), (16.0, 16.0, RED), (12.0, 12.0, RED)]
    env, obs = make_env(agents, boxes, task=task, see_other_agents=True)
    before = env.state
    obs, reward, done, info = step(env, [wheels_for(1.0, 1.0, 2.0)] * 5)
    after = env.state
    assert info["picked"][0].tolist() == [-1, -1, 0, -1, -1], "the failed robot 4 must not pick"
    assert info["dropped"][0].tolist() == [-1] * 5, "the failed robot 3 must not drop"
    assert torch.equal(after.agent_pos[0, 3:], before.agent_pos[0, 3:]) and torch.equal(after.heading[0, 3:],
                                                                                            before.heading[0, 3:])
    assert not torch.equal(after.agent_pos[0, :3], before.agent_pos[0, :3]), "the working robots move"
    assert after.carrying[0].tolist() == [-1, -1, 0, 1, -1] and reward.item() == 1.0
    # robot 2, moved to about (10.3, 10.1), senses the failed robot 4 at (12.1, 12) as a robot
    seen = decode(obs[0, 2], env.config)
    assert AGENT in seen["types"], seen["slots"]


@pytest.mark.parametrize("gain", [1.0, 0.5, 0.3])
def test_motor_gain_scales_every_wheel_speed(gain):
    task = Task(RED, (RED, BLUE), name="worn", motor_gain=gain)
    wheels = [1.5, -0.5, 2.0]
    env, _ = make_env([(10.0, 10.0, 30.0)], [(3.0, 3.0, RED)], task=task)
    step(env, [wheels])
    worn = [w * gain for w in wheels]
    vx = sum(A[0][j] * worn[j] for j in range(3))
    vy = sum(A[1][j] * worn[j] for j in range(3))
    r = sum(A[2][j] * worn[j] for j in range(3))
    s = env.state
    assert s.agent_pos[0, 0].tolist() == pytest.approx([10.0 + vx * 0.1, 10.0 + vy * 0.1], abs=1e-12)
    assert s.heading[0, 0].item() == pytest.approx(30.0 + math.degrees(r / 12.5 * 0.1), abs=1e-12)


def test_reset_for_each_nest_edge_is_the_papers_draw_mirrored_or_transposed():
    """The same generator draws the same episode for every edge, carried into its frame: the
    start row and the box band face the nest, the headings face away from it."""
    env = ForagingEnv(ForagingConfig(), batch_size=8, dtype=F64)
    top = env.sample_state(TASKS["red"], generator=3)
    size = 20.0
    for edge in ("bottom", "left", "right"):
        s = env.sample_state(Task(RED, (RED, BLUE), name=f"red-{edge}", drop_zone=edge), generator=3)
        x, y, bx, by = top.agent_pos[..., 0], top.agent_pos[..., 1], top.box_pos[..., 0], top.box_pos[..., 1]
        frames = {"bottom": ((size - x, y), (size - bx, by), 180 - top.heading),
                  "left": ((y, x), (by, bx), 90 - top.heading),
                  "right": ((y, size - x), (by, size - bx), top.heading - 90)}
        agents, boxes, heading = frames[edge]
        assert torch.equal(s.agent_pos, torch.stack(agents, -1)) and torch.equal(s.box_pos, torch.stack(boxes, -1))
        assert torch.allclose(s.heading, torch.remainder(heading, 360.0), atol=1e-12), edge
        assert torch.equal(s.box_color, top.box_color) and s.drop_zone.tolist() == [("top", "bottom", "left", "right").index(edge)] * 8
    # the paper's task is drawn as before: a task of every edge in one batch leaves the top one's
    mixed = env.sample_state([Task(RED, (RED, BLUE), name=e, drop_zone=e) for e in EDGE_DROPS] * 2, generator=3)
    assert torch.equal(mixed.agent_pos[0], top.agent_pos[0]) and torch.equal(mixed.heading[0], top.heading[0])


def test_dropped_box_hidden_this_step_visible_at_its_respawn_cell_next_step():
    key, steps = 9001, 3
    cx, cy = respawn_cell(key, steps, 0, 20)
    # agent 1 waits 0.6 from the respawn cell (out of pick reach), facing it from the top
    env, obs = make_env([(0.5, 5.0, 180.0, 0), (cx - 0.6, cy)], [(10.0, 3.0, GREEN), (19.0, 19.0, RED)],
                        task=TASKS["green"], key=key, steps=steps)
    c = env.config
    obs, reward, done, info = step(env)
    assert info["dropped"][0].tolist() == [0, -1] and reward.item() == 2.0
    assert tuple(info["respawn_cell"][0, 0].tolist()) == (cx, cy)
    assert GREEN not in decode(obs[0, 1], c)["types"], "the dropped box must not be sensed in its drop step"
    assert GREEN not in decode(obs[0, 0], c)["types"]
    obs, reward, done, info = step(env)
    d = decode(obs[0, 1], c)
    assert GREEN in d["types"], f"the respawned box must be sensed from the next step on: {d['slots']}"
    j = d["types"].index(GREEN)
    assert d["dist"][j] == pytest.approx(0.6) and d["cos"][j] == pytest.approx(-1.0), "seen below the agent"
    assert info["picked"][0].tolist() == [-1, -1]


def test_respawned_box_cannot_be_picked_in_its_drop_step():
    # documented choice: a box dropped in a step is absent for the rest of that step
    key, steps = 555, 0
    cx, cy = respawn_cell(key, steps, 0, 20)
    env, obs = make_env([(0.5, 5.0, 180.0, 0), (cx + 0.2, cy)], [(10.0, 3.0, RED), (19.0, 19.0, BLUE)],
                        key=key, steps=steps)
    obs, reward, done, info = step(env)
    assert info["dropped"][0].tolist() == [0, -1]
    assert info["picked"][0].tolist() == [-1, -1], "a box dropped this step is absent for later agents' picks"
    obs, reward, done, info = step(env)
    assert info["picked"][0].tolist() == [-1, 0] and reward.item() == 1.0, "next step it can be picked"


def test_repositioning_off_removes_the_box():
    env, obs = make_env([(0.5, 5.0, 180.0, 0), (9.0, 9.0)], [(10.0, 10.0, RED), (12.0, 12.0, BLUE)],
                        repositioning=False)
    obs, reward, done, info = step(env)
    assert info["dropped"][0].tolist() == [0, -1] and reward.item() == 2.0
    cell = info["respawn_cell"][0, 0].tolist()
    s = env.state
    assert s.box_present[0, :2].tolist() == [False, True] and s.carrying[0].tolist() == [-1, -1]
    for _ in range(3):
        obs, *_ = step(env)
        assert env.state.box_present[0, :2].tolist() == [False, True]
        assert RED not in decode(obs[0, 1], env.config)["types"]
    assert cell == [-1, -1], (f"BUG (info only): with repositioning off the dropped box is gone, yet "
                              f"info['respawn_cell'] reports cell {cell} instead of -1")


# ---------------------------------------------------------------------------- episode end
def test_max_retrieves_ends_the_episode_the_whole_step_counts_then_frozen():
    agents = [(0.5, 5.0, 180.0, 0), (10.1, 10.0), (10.0, 14.2)]
    boxes = [(10.0, 3.0, RED), (10.0, 10.0, RED), (10.0, 14.0, BLUE)]
    env, obs = make_env(agents, boxes, max_retrieves=2, retrieved=1, steps=4)
    obs, reward, done, info = step(env)
    assert done.tolist() == [True], "retrieved reached max_retrieves"
    assert reward.item() == 2.0 + 1.0 - 1.0, "every agent's reward of the ending step counts"
    before = env.state
    wheels = [[2.0, -2.0, 1.0]] * 3
    for _ in range(3):
        obs, reward, done, info = step(env, wheels)
        assert reward.item() == 0.0 and done.tolist() == [True], "an ended environment earns nothing"
        assert info["picked"][0].tolist() == [-1] * 3 and info["dropped"][0].tolist() == [-1] * 3
        after = env.state
        assert torch.equal(after.agent_pos, before.agent_pos) and torch.equal(after.heading, before.heading), \
            "an ended environment does not move"
        assert after.steps.tolist() == [5] and after.retrieved.tolist() == [2]


def test_duration_ends_the_episode():
    env, obs = make_env([(10.0, 10.0)], [(15.0, 15.0, RED)], duration=5, steps=2)
    for t in range(3, 6):
        obs, reward, done, info = step(env, [[1.0, 0.0, 0.0]])
        assert env.state.steps.tolist() == [t]
        assert done.tolist() == [t >= 5], f"after {t} steps of 5"
    pos = env.state.agent_pos.clone()
    obs, reward, done, info = step(env, [[1.0, 0.0, 0.0]])
    assert done.tolist() == [True] and torch.equal(env.state.agent_pos, pos) and env.state.steps.tolist() == [5]


def test_mixed_batch_only_the_ended_environment_freezes():
    config = ForagingConfig(n_agents=1, n_boxes=N_FILLED, max_retrieves=1)
    states = [make_state([(0.5, 5.0, 180.0, 0)], [(10.0, 10.0, RED)]),
              make_state([(5.0, 5.0, 180.0, -1)], [(10.0, 10.0, RED)])]
    env = ForagingEnv(config, 2, dtype=F64)
    env.reset(state=batched_state_from(states, 4))
    obs, reward, done, info = step(env, [[[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]]])
    assert done.tolist() == [True, False] and reward.tolist() == [2.0, 0.0]
    x_before = env.state.agent_pos[:, 0, 0].clone()
    obs, reward, done, info = step(env, [[[1.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]]])
    x_after = env.state.agent_pos[:, 0, 0]
    assert x_after[0] == x_before[0] and x_after[1] != x_before[1]
    assert env.state.steps.tolist() == [1, 2]


# ---------------------------------------------------------------------------- kinematics
def test_kinematics_one_step_exact():
    w = [(1.3, -0.7, 0.4), (2.0, -2.0, 1.1), (0.0, 0.0, 0.0)]
    agents = [(10.0, 10.0, 90.0), (7.0, 12.0, 359.9), (5.0, 5.0, 123.0)]
    env, obs = make_env(agents, [(18.0, 2.0, RED)])
    step(env, w)
    s = env.state
    for i, (x, y, h) in enumerate(agents):
        vx, vy, r = (sum(A[row][j] * w[i][j] for j in range(3)) for row in range(3))
        assert s.agent_pos[0, i, 0].item() == pytest.approx(x + vx * 0.1, abs=1e-12)
        assert s.agent_pos[0, i, 1].item() == pytest.approx(y + vy * 0.1, abs=1e-12)
        assert s.heading[0, i].item() == pytest.approx((h + math.degrees(r / 12.5 * 0.1)) % 360, abs=1e-9)
    assert 0.0 <= s.heading[0, 1].item() < 1.0, "heading wraps modulo 360"


def test_kinematics_matrix_columns():
    # each wheel alone, speed 1: the displacement is that column of A times dt
    env, obs = make_env([(10.0, 10.0), (10.0, 10.0), (10.0, 10.0)], [(18.0, 2.0, RED)])
    step(env, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    s = env.state
    for j in range(3):
        dx = s.agent_pos[0, j, 0].item() - 10.0
        dy = s.agent_pos[0, j, 1].item() - 10.0
        dh = s.heading[0, j].item() - 180.0
        assert (dx, dy) == pytest.approx((A[0][j] * 0.1, A[1][j] * 0.1), abs=1e-12), f"wheel {j}"
        assert dh == pytest.approx(math.degrees(A[2][j] / 12.5 * 0.1), abs=1e-9)


def test_motion_is_in_the_arena_frame():
    headings = [0.0, 77.0, 180.0, 300.0]
    env, obs = make_env([(10.0, 10.0, h) for h in headings], [(18.0, 2.0, RED)])
    step(env, [[1.5, 0.2, -0.9]] * 4)
    p = env.state.agent_pos[0]
    assert torch.equal(p, p[:1].expand_as(p)), "motion must not depend on the heading"


def test_positions_clipped_to_the_arena():
    agents = [(0.05, 10.0), (10.0, 0.01), (19.99, 19.99), (19.95, 5.0)]
    env, obs = make_env(agents, [(15.0, 15.0, RED)])
    wheels = [wheels_for(-1.0, 0.0), wheels_for(0.0, -1.0), wheels_for(1.0, 1.0), wheels_for(1.0, -1.0)]
    step(env, wheels)
    p = env.state.agent_pos[0].tolist()
    assert p[0][0] == 0.0 and p[0][1] == pytest.approx(10.0), "x clipped at 0"
    assert p[1][1] == 0.0 and p[1][0] == pytest.approx(10.0), "y clipped at 0"
    assert p[2] == [20.0, 20.0], "x and y clipped at size"
    assert p[3][0] == 20.0 and p[3][1] == pytest.approx(4.9), "only the coordinate that leaves is clipped"


# ---------------------------------------------------------------------------- reset sampling
def test_reset_sampling_rules():
    config = ForagingConfig()
    B = 200
    env = ForagingEnv(config, B, dtype=F64)
    tasks = [TASKS["red"], TASKS["green"]] * (B // 2)
    env.reset(tasks=tasks, generator=3)
    s = env.state
    pos = s.box_pos
    assert torch.equal(pos, pos.round()), "boxes on integer cells"
    assert pos[..., 0].min() == 6 and pos[..., 0].max() == 18, "box x in {6..18}"
    assert pos[..., 1].min() == 2 and pos[..., 1].max() == 18, "box y in {2..18}"
    d = torch.cdist(pos, pos) + torch.eye(config.n_boxes, dtype=F64) * 100
    assert d.min() >= 2.0, "boxes pairwise at least 2 apart"
    for b in range(B):
        target = tasks[b].target
        colors = s.box_color[b].tolist()
        assert colors.count(target) == 10, "exactly int(n_boxes * rate_target) target boxes"
        assert set(colors) <= set(tasks[b].season)
        assert s.target[b].item() == target
    assert s.box_color.eq(s.target[:, None]).float().mean(0).min() > 0.3, "colours are permuted"
    assert s.box_color.eq(s.target[:, None]).float().mean(0).max() < 0.7, "colours are permuted"
    x, y = s.agent_pos[..., 0], s.agent_pos[..., 1]
    assert (x >= 1).all() and (x <= 3).all() and x.min() < 1.1 and x.max() > 2.9
    slots = torch.arange(1, 6, dtype=F64) * 20 / 6
    assert ((y - slots).abs() <= 1).all() and (y - slots).abs().max() > 0.9
    assert ((s.heading - 180).abs() <= 10).all() and (s.heading - 180).abs().max() > 9
    assert (s.carrying == -1).all() and s.box_present.all()
    assert (s.steps == 0).all() and (s.retrieved == 0).all() and not s.done.any()
    assert s.season[0].tolist() == [True, True, False, False] and s.season[1].tolist() == [False, False, True, True]


def test_reset_other_colors_drawn_from_the_season_only():
    config = ForagingConfig(rate_target=0.33)
    task = Task(RED, (RED, BLUE, YELLOW))
    env = ForagingEnv(config, 50, dtype=F64)
    env.reset(tasks=task, generator=11)
    colors = env.state.box_color
    assert (colors == RED).sum(1).tolist() == [6] * 50, "int(20 * 0.33) = 6 target boxes"
    assert set(colors.unique().tolist()) == {RED, BLUE, YELLOW}
    n_blue, n_yellow = (colors == BLUE).sum().item(), (colors == YELLOW).sum().item()
    assert abs(n_blue - n_yellow) < 0.15 * (n_blue + n_yellow), "uniform over the other season colours"
    env = ForagingEnv(ForagingConfig(rate_target=1.0), 4, dtype=F64)
    env.reset(tasks=TASKS["green"], generator=1)
    assert (env.state.box_color == GREEN).all()


def test_reset_determinism_and_generators():
    config = ForagingConfig()
    wheels = torch.rand(30, 4, 5, 3, generator=torch.Generator().manual_seed(0), dtype=F64) * 4 - 2

    def run(generator):
        env = ForagingEnv(config, 4, dtype=F64)
        out = [env.reset(tasks=TASKS["red"], generator=generator)]
        for t in range(30):
            o, r, d, _ = env.step(wheels[t])
            out += [o, r]
        return out, env.state

    a, sa = run(5)
    b, sb = run(5)
    assert all(torch.equal(x, y) for x, y in zip(a, b)), "same seed, same trajectory"
    c, sc = run(6)
    assert not torch.equal(a[0], c[0]), "different seeds differ"
    g1, g2 = torch.Generator().manual_seed(42), torch.Generator().manual_seed(42)
    d, sd = run(g1)
    e, se = run(g2)
    assert all(torch.equal(x, y) for x, y in zip(d, e)) and torch.equal(sd.respawn_key, se.respawn_key)
    f, sf = run(g1)  # the generator advanced
    assert not torch.equal(d[0], f[0])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_cpu_device_and_dtypes(dtype):
    env = ForagingEnv(ForagingConfig(), 3, device="cpu", dtype=dtype)
    obs = env.reset(tasks=TASKS["green"], generator=0)
    assert obs.dtype == dtype and obs.device.type == "cpu" and obs.shape == (3, 5, 41)
    obs, reward, done, info = env.step(torch.zeros(3, 5, 3, dtype=dtype))
    assert obs.dtype == dtype and env.state.agent_pos.dtype == dtype
    assert reward.shape == (3,) and done.dtype == torch.bool
    ref = ForagingEnv(ForagingConfig(), 3, device="cpu", dtype=F64)
    ref_obs = ref.reset(tasks=TASKS["green"], generator=0)
    w = torch.rand(10, 3, 5, 3, generator=torch.Generator().manual_seed(1), dtype=F64) * 4 - 2
    env.reset(tasks=TASKS["green"], generator=0)
    for t in range(10):
        obs, *_ = env.step(w[t].to(dtype))
        ref_obs, *_ = ref.step(w[t])
    assert (obs.double() - ref_obs).abs().max() < 1e-4


# ---------------------------------------------------------------------------- tasks
def test_per_environment_tasks():
    config = ForagingConfig(n_agents=2, n_boxes=N_FILLED)
    agents = [(10.2, 10.0), (12.0, 12.3)]
    boxes = [(10.0, 10.0, RED), (12.0, 12.0, GREEN)]
    states = [make_state(agents, boxes, task=TASKS["red"]), make_state(agents, boxes, task=TASKS["green"])]
    env = ForagingEnv(config, 2, dtype=F64)
    obs = env.reset(state=batched_state_from(states, 4))
    assert decode(obs[0, 0], config)["target"] == [1, 0, 0, 0]
    assert decode(obs[1, 0], config)["target"] == [0, 0, 1, 0]
    obs, reward, done, info = step(env)
    assert reward.tolist() == [0.0, 0.0]  # +1 -1 in both, from opposite boxes
    assert info["picked"].tolist() == [[0, 1], [0, 1]]
    # drop both: red env earns +2 for the red box only, green env for the green box only
    s = env.state
    s.agent_pos[:, :, 0] = 0.5
    env.reset(state=s)
    obs, reward, done, info = step(env)
    assert reward.tolist() == [2.0, 2.0]
    assert info["drop_correct"].tolist() == [[True, False], [False, True]]
    assert env.state.retrieved.tolist() == [1, 1]


def test_sampling_with_one_task_per_environment():
    env = ForagingEnv(ForagingConfig(colors=tuple(range(3, 11))), 4, dtype=F64)
    tasks = [TASKS[n] for n in ("red", "green", "purple", "cyan")]
    obs = env.reset(tasks=tasks, generator=2)
    for b, t in enumerate(tasks):
        assert set(env.state.box_color[b].tolist()) <= set(t.season)
        assert decode(obs[b, 0], env.config)["target"].index(1.0) == t.target - 3


def test_set_tasks_changes_the_task_mid_episode():
    # agent 0 creeps towards the green box at 0.1 per step: out of reach after step 1, in reach after step 2
    env, obs = make_env([(12.0, 11.35), (5.0, 5.0)], [(10.0, 10.0, RED), (12.0, 12.0, GREEN)])
    creep = [wheels_for(0.0, 1.0), [0.0, 0.0, 0.0]]
    obs, reward, done, info = step(env, creep)
    assert info["picked"][0].tolist() == [-1, -1]
    assert decode(obs[0, 0], env.config)["target"] == [1, 0, 0, 0]
    env.set_tasks(TASKS["green"])
    s = env.state
    assert s.target.tolist() == [GREEN] and s.season[0].tolist() == [False, False, True, True]
    assert s.box_color[0, :2].tolist() == [RED, GREEN], "boxes keep their colours"
    obs, reward, done, info = step(env, creep)
    assert decode(obs[0, 0], env.config)["target"] == [0, 0, 1, 0]
    assert info["picked"][0].tolist() == [1, -1] and reward.item() == 1.0, "green is now the target"
    assert env.state.steps.tolist() == [2]


@pytest.mark.parametrize("in_place", [False, True])
def test_set_tasks_moves_the_nest_and_changes_rewards_and_failures_mid_episode(in_place):
    """A carrier at the bottom edge does not deliver under the paper's task and does after a
    drift to a bottom nest, at the new task's value; the failed robot stops at once."""
    env, obs = make_env([(19.5, 5.0, 180.0, 0), (10.0, 3.0)], [(10.0, 10.0, RED)])
    if in_place:
        env.graph_step(capture=False)
    state = env.state
    env.reset(state=state)  # the arena may share this state's tensors
    assert step(env)[3]["dropped"][0].tolist() == [-1, -1]
    env.set_tasks(Task(RED, (RED, BLUE), name="red-south", drop_zone="bottom", failed_robots=1,
                       rewards=Rewards(deliver_target=7.0)))
    before = env.state.agent_pos[0, 1].clone()
    obs, reward, done, info = step(env, [[0.0, 0.0, 0.0], wheels_for(1.0, 1.0)])
    assert info["dropped"][0].tolist() == [0, -1] and reward.item() == 7.0
    assert torch.equal(env.state.agent_pos[0, 1], before), "the failed robot 1 stays put"
    assert state.drop_zone.tolist() == [0] and state.rewards[0].tolist() == [1.0, -1.0, 2.0, 0.0], \
        "set_tasks must not change the state given to reset"


# ---------------------------------------------------------------------------- helpers of the module
def test_outputs_to_wheels():
    config = ForagingConfig()
    out = torch.tensor([0.0, 0.5, 1.0, 0.25], dtype=F64)
    assert outputs_to_wheels(out, config).tolist() == [-2.0, 0.0, 2.0, -1.0]


def test_float_remainder_equals_integer_remainder():
    """The respawn cells take ``h % n`` through float64 division (it vectorises): exact for every
    31-bit ``h``, including multiples of ``n`` and their neighbours, where rounding would show."""
    rng = random.Random(1)
    for n in (*range(1, 40), 1000, 2 ** 21 + 1):
        top = (2 ** 31 - 1) // n * n
        hs = [0, 1, n - 1, n, n + 1, top - 1, top, 2 ** 31 - 1] + [rng.randrange(2 ** 31) for _ in range(300)]
        hs += [rng.randrange(2 ** 31 // n) * n + d for _ in range(100) for d in (-1, 0) if n > 1]
        h = torch.tensor([x for x in hs if 0 <= x < 2 ** 31], dtype=torch.int32)
        assert _remainder(h, n).tolist() == [x % n for x in h.tolist()], n


def test_respawn_stream_matches_a_plain_python_hash():
    rng = random.Random(0)
    keys = [rng.randrange(0, 2 ** 31 - 1) for _ in range(64)] + [0, 2 ** 31 - 2]
    xs = [rng.randrange(0, 2 ** 31) for _ in range(200)]
    for dtype in (torch.int32, torch.long):  # int32 products wrap; the mask keeps their low bits
        assert hash31(torch.tensor(xs, dtype=dtype)).tolist() == [py_hash31(x) for x in xs]
    seen = set()
    for size in (20, 16):
        for steps in (0, 1, 7, 499):
            cells = respawn_cells(torch.tensor(keys), torch.full((len(keys),), steps), 5, size)
            assert cells.shape == (5, len(keys), 2) and cells.dtype == torch.int32
            for i in range(5):
                for b, key in enumerate(keys):
                    cell = respawn_cell(key, steps, i, size)
                    assert tuple(cells[i, b].tolist()) == cell
                    if size == 20:
                        seen.add(cell)
    xs_, ys_ = {c[0] for c in seen}, {c[1] for c in seen}
    assert xs_ == set(range(6, 19)) and ys_ == set(range(2, 19)), "respawn cells: x in {6..18}, y in {2..18}"


def test_compiled_step_matches_eager():
    """``compile()`` gives the same rewards, events and discrete state as eager, with pick
    conflicts and respawns exercised, on a batch that mixes the paper's red with a task of every
    kind of drift (``DRIFTS``: each nest edge, other reward values, failed robots, a motor gain),
    each environment with its own; floats agree to rounding (inductor's vectorised sin and cos
    differ from eager's in the last bit)."""
    config = ForagingConfig(n_boxes=12, max_retrieves=3, duration=60)
    eager, compiled = (ForagingEnv(config, batch_size=24, dtype=F64) for _ in range(2))
    graphs_before = counters["stats"]["unique_graphs"]
    compiled.compile()
    generator = torch.Generator().manual_seed(5)
    tasks = [DRIFTS[b % len(DRIFTS)] for b in range(24)]
    start = _colliding_start(eager, generator, tasks)
    obs_e, obs_c = eager.reset(state=start), compiled.reset(state=start)
    torch.testing.assert_close(obs_c, obs_e, rtol=0, atol=1e-12)
    events = Counter()
    for _ in range(60):
        wheels = (torch.rand(24, config.n_agents, 3, generator=generator, dtype=F64) * 4 - 2)
        out_e, out_c = eager.step(wheels), compiled.step(wheels)
        torch.testing.assert_close(out_c[0], out_e[0], rtol=0, atol=1e-12)
        assert torch.equal(out_c[1], out_e[1]) and torch.equal(out_c[2], out_e[2])
        for name, want in out_e[3].items():
            assert torch.equal(out_c[3][name], want), name
        events["picks"] += int((out_e[3]["picked"] >= 0).sum())
        events["conflicts"] += int(((out_e[3]["picked"] >= 0).sum(dim=1) >= 2).sum())
        events["drops"] += int((out_e[3]["dropped"] >= 0).sum())
        for b, dropped in enumerate((out_e[3]["dropped"] >= 0).sum(dim=1).tolist()):
            events[f"drops at the {tasks[b].drop_zone}"] += dropped
    assert events["conflicts"] >= 5 and events["drops"] >= 5, events
    assert all(events[f"drops at the {edge}"] for edge in EDGE_DROPS), events
    # steps with and without conflicts reuse the two graphs: a dtype that differed between the
    # two pick paths would recompile them (and run 100x slower)
    assert counters["stats"]["unique_graphs"] - graphs_before == 2
    for name in ("carrying", "box_pos", "box_present", "steps", "retrieved", "done"):
        assert torch.equal(getattr(compiled.state, name), getattr(eager.state, name)), name
    for name in ("agent_pos", "heading"):
        torch.testing.assert_close(getattr(compiled.state, name), getattr(eager.state, name), rtol=0, atol=1e-9)


NEST_SIDE = {"top": ((1.0, 10.0), (1.2, 10.1)), "bottom": ((19.0, 10.0), (18.8, 10.1)),
             "left": ((10.0, 1.0), (10.1, 1.2)), "right": ((10.0, 19.0), (10.1, 18.8))}
"""Per nest edge of the paper's arena: a box cell beside the nest, and a point within pick-up reach
of it (the top edge's carried into each edge's frame)."""


def _colliding_start(env: ForagingEnv, generator: torch.Generator, tasks=TASKS["red"]):
    """Every agent starts on a stacked cell next to its environment's nest (``tasks``: one for all
    or one per environment): picks collide, drops follow."""
    start = env.sample_state(tasks, generator)
    for b, task in enumerate([tasks] * env.batch_size if isinstance(tasks, Task) else tasks):
        box, agent = NEST_SIDE[task.drop_zone]
        start.box_pos[b, :4] = torch.tensor(box, dtype=env.dtype)
        start.agent_pos[b, :, 0], start.agent_pos[b, :, 1] = agent
    return start


@pytest.fixture
def dynamo_graphs_run_eagerly(monkeypatch):
    """``torch.compile`` captures dynamo's graphs as usual but runs them with the eager backend,
    skipping inductor's code generation and C++ build (minutes per graph on CI's two cores): for
    tests of which batch sizes dynamo compiles, a question its backend plays no part in."""
    compile_with_inductor = torch.compile

    def compile_without_inductor(function, *, dynamic, options):
        assert options is COMPILE_OPTIONS, "the step's own options reach torch.compile"
        return compile_with_inductor(function, dynamic=dynamic, backend="eager")
    monkeypatch.setattr(torch, "compile", compile_without_inductor)


def test_every_batch_size_compiles_whatever_the_process_compiled_before(dynamo_graphs_run_eagerly):
    """A batch size met after dynamo's own limit is compiled like the first one. Dynamo would
    run it eagerly, which rounds differently, so that a run's numbers would depend on the batch
    sizes its process had met before (a resume, the trial before it in a sweep's worker); going
    past the toolkit's own limit is an error, never a silent switch to eager."""
    # a configuration and batch sizes of this test alone, so no other test's graphs are reused
    config = ForagingConfig(n_boxes=7, max_retrieves=2, duration=10)
    generator = torch.Generator().manual_seed(3)
    new_graphs = []
    # a process that has used up dynamo's limit: the next new batch size would run eagerly
    with torch._dynamo.config.patch(recompile_limit=1):
        for batch_size in (5, 7):
            env = ForagingEnv(config, batch_size=batch_size, dtype=F64)
            env.compile()
            before = counters["stats"]["unique_graphs"]
            env.reset(state=env.sample_state(TASKS["red"], generator))
            env.step(torch.zeros(batch_size, config.n_agents, 3, dtype=F64))
            new_graphs.append(counters["stats"]["unique_graphs"] - before)
    assert new_graphs == [2, 2], "each batch size compiles both graphs of the step"
    assert torch._dynamo.config.fail_on_recompile_limit_hit


def test_every_batch_size_compiles_in_a_thread_that_did_not_compile_it(dynamo_graphs_run_eagerly):
    """Dynamo's settings are each thread's own: an environment compiled in one thread and stepped
    in another (an evaluation thread of a later generation) still compiles its batch size, however
    many the process compiled before, and never drops to eager. The stepping thread here starts
    from dynamo's limit lowered to 1, as if the process had used it up."""
    from concurrent.futures import ThreadPoolExecutor

    config = ForagingConfig(n_boxes=6, max_retrieves=2, duration=10)
    envs = [ForagingEnv(config, batch_size=batch_size, dtype=F64) for batch_size in (3, 4)]
    for env in envs:
        env.compile()

    def first_steps() -> list[int]:
        torch._dynamo.config.recompile_limit = 1
        torch._dynamo.config.fail_on_recompile_limit_hit = False
        new_graphs = []
        for env in envs:
            before = counters["stats"]["unique_graphs"]
            env.reset(state=env.sample_state(TASKS["red"], torch.Generator().manual_seed(3)))
            env.step(torch.zeros(env.batch_size, config.n_agents, 3, dtype=F64))
            new_graphs.append(counters["stats"]["unique_graphs"] - before)
        return new_graphs

    with ThreadPoolExecutor(1) as pool:
        assert pool.submit(first_steps).result() == [2, 2], "each batch size compiles both graphs of the step"


@pytest.mark.parametrize("compiled", [False, True], ids=["eager", "compiled"])
def test_in_place_step_for_cuda_graphs_equals_the_plain_step(compiled):
    """``graph_step``'s step (fixed buffers, no wait for the device: what a CUDA graph replays,
    run here without one) gives the plain step's numbers bit for bit, through pick conflicts,
    drops, respawns, episode ends and autoresets, and never changes a state handed to reset."""
    config = ForagingConfig(n_boxes=12, max_retrieves=3, duration=40)
    plain, in_place = (ForagingEnv(config, batch_size=24, dtype=F64) for _ in range(2))
    if compiled:
        plain.compile()
        in_place.compile()
    in_place.graph_step(capture=False)
    generator = torch.Generator().manual_seed(5)
    start = _colliding_start(plain, generator)
    handed = start.clone()
    assert torch.equal(in_place.reset(state=handed), plain.reset(state=start))
    events = Counter()
    for step in range(90):
        wheels = torch.rand(24, config.n_agents, 3, generator=generator, dtype=F64) * 4 - 2
        want, got = plain.step(wheels), in_place.step(wheels)
        for w, g in zip(want[:3], got[:3]):
            assert torch.equal(g, w), step
        assert want[3].keys() == got[3].keys()
        for name, value in want[3].items():
            assert torch.equal(got[3][name], value), (step, name)
        events["conflicts"] += int(((want[3]["picked"] >= 0).sum(dim=1) >= 2).sum())
        events["drops"] += int((want[3]["dropped"] >= 0).sum())
        events["ended"] += int(want[2].sum())
        if step % 10 == 9:  # autoreset: fresh episodes written into the buffers in place
            seed = 100 + step
            assert torch.equal(in_place.reset_done(TASKS["green"], generator=seed),
                               plain.reset_done(TASKS["green"], generator=seed))
    assert events["conflicts"] >= 5 and events["drops"] >= 5 and events["ended"] >= 24, events
    for name in ("agent_pos", "heading", "carrying", "box_pos", "box_present", "steps", "retrieved", "done"):
        assert torch.equal(getattr(in_place.state, name), getattr(plain.state, name)), name
    for name in ("agent_pos", "steps", "carrying", "box_present"):
        assert torch.equal(getattr(handed, name), getattr(start, name)), name


def test_step_outputs_survive_the_next_in_place_step():
    env = ForagingEnv(ForagingConfig(), batch_size=4)
    env.graph_step(capture=False)
    env.reset(TASKS["red"], generator=1)
    first = env.step(torch.ones(4, env.config.n_agents, 3))
    kept = [first[0].clone(), first[1].clone()]
    env.step(-torch.ones(4, env.config.n_agents, 3))
    assert torch.equal(first[0], kept[0]) and torch.equal(first[1], kept[1])


def test_a_cuda_graph_needs_a_cuda_device():
    env = ForagingEnv(ForagingConfig(), batch_size=2)
    with pytest.raises(ConfigError, match="cuda device"):
        env.graph_step(capture=True)


class _HostReads(TorchDispatchMode):
    """Counts reads of a tensor's value back to the host (``bool(t)``, ``int(t)``, ``t.item()``):
    on a GPU each waits for the device, and none may happen inside a CUDA graph's capture."""

    def __init__(self):
        super().__init__()
        self.count = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.count += func is torch.ops.aten._local_scalar_dense.default
        return func(*args, **(kwargs or {}))


def test_the_in_place_step_never_waits_for_the_device():
    """What capture needs, checked on the CPU: the plain step reads values back to the host (to
    skip the rare conflict resolution and respawns), the in-place step never does."""
    config = ForagingConfig(n_boxes=12)
    generator = torch.Generator().manual_seed(3)
    reads = {}
    for mode in ("plain", "in place"):
        env = ForagingEnv(config, batch_size=8)
        if mode == "in place":
            env.graph_step(capture=False)
        env.reset(state=_colliding_start(env, torch.Generator().manual_seed(3)))
        with _HostReads() as counter:
            for _ in range(5):
                env.step(torch.rand(8, config.n_agents, 3, generator=generator) * 4 - 2)
        reads[mode] = counter.count
    assert reads["plain"] >= 5 and reads["in place"] == 0, reads


class _FakeCapture:
    """Stands in for CUDA's capture and replay on the CPU, with their semantics as far as the
    environment relies on them: capture records the step without running it (the arena's
    buffers are as before), and a replay runs the step again on the same input buffers and writes
    its outputs into the tensors the capture returned."""

    def __init__(self, env: ForagingEnv):
        self.env, self.replays = env, 0

    def graph(self, graph, capture_error_mode="global"):
        fake = self

        class Capture:
            def __enter__(self):
                self.before = fake.env._arena.clone()

            def __exit__(self, *exc):
                fake.env._arena.copy_(self.before)

        return Capture()

    def replay(self):
        self.replays += 1
        fresh = self.env._step_in_place(self.env._graph_wheels)
        observations, reward, done, info = self.env._graph_outputs
        for into, value in [(observations, fresh[0]), (reward, fresh[1]), (done, fresh[2]),
                            *((info[k], fresh[3][k]) for k in info)]:
            into.copy_(value)


@pytest.mark.parametrize("compiled", [False, True], ids=["eager", "compiled"])
def test_captured_step_replays_the_plain_step(monkeypatch, compiled):
    """The capture's plumbing, on the CPU with a stand-in for CUDA: the warm-up steps before the
    capture are undone, each replay reads the wheels of its step, a reset writes where the
    replays read, and the numbers are the plain step's, eager and compiled."""
    config = ForagingConfig(n_boxes=12, max_retrieves=3, duration=40)
    plain, graphed = (ForagingEnv(config, batch_size=24, dtype=F64) for _ in range(2))
    if compiled:
        plain.compile()
        graphed.compile()
    fake = _FakeCapture(graphed)
    stream = type("Stream", (), {"wait_stream": lambda self, other: None})
    monkeypatch.setattr(torch.cuda, "Stream", lambda device=None: stream())
    monkeypatch.setattr(torch.cuda, "current_stream", lambda device=None: stream())
    monkeypatch.setattr(torch.cuda, "stream", lambda s: contextlib.nullcontext())
    monkeypatch.setattr(torch.cuda, "graph", fake.graph)
    monkeypatch.setattr(torch.cuda, "CUDAGraph", lambda: type("Graph", (), {"replay": lambda self: fake.replay()})())
    graphed.graph_step(capture=False)
    graphed._capture = True  # as graph_step() sets it on a cuda device
    generator = torch.Generator().manual_seed(5)
    start = _colliding_start(plain, generator)
    graphed.reset(state=start.clone())
    plain.reset(state=start)
    for step in range(60):
        wheels = torch.rand(24, config.n_agents, 3, generator=generator, dtype=F64) * 4 - 2
        want, got = plain.step(wheels), graphed.step(wheels)
        for w, g in zip(want[:3], got[:3]):
            assert torch.equal(g, w), step
        for name, value in want[3].items():
            assert torch.equal(got[3][name], value), (step, name)
        if step == 30:
            assert torch.equal(graphed.reset(state=start.clone()), plain.reset(state=start))
    assert fake.replays == 60
