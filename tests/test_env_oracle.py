"""The batched torch environment against the scalar-Python oracle (tests/oracle.py), step for step.

Random explicit initial states (agents anywhere, incl. on the bottom/right edges where the
spec's ``- 1`` makes wall distances negative; boxes on integer cells, some stacked, some already
carried or gone), mixed tasks per environment, 4- and 8-colour arenas, agent sensing and
repositioning on and off, and the tasks' drifts (every nest edge, other reward values, failed
robots, worn motors) mixed in one batch. Actions are biased (steer to the nearest box, carry up
to the drop zone) so that picks, wrong picks, correct and wrong drops and early ends really
happen; the tests count them so that they cannot pass vacuously.
"""
from __future__ import annotations

import math
import random
from collections import Counter

import pytest
import torch

from envs import TASKS, ForagingConfig, ForagingEnv, Rewards, Task

try:
    from oracle import Oracle, OracleState, batched_state_from, oracle_states_from
except ImportError:  # tests/ imported as a package
    from tests.oracle import Oracle, OracleState, batched_state_from, oracle_states_from

# Inverse of the spec's kinematic matrix, to steer agents: wheels = A^-1 @ (vx, vy, r).
A_INV = ((-0.8660254100688773, 0.5000000043301269, 1.0),
         (0.0, -1.0, 1.0),
         (0.8660254100688773, -0.500000004330127, 1.0))

FOUR = (3, 4, 5, 6)
EIGHT = tuple(range(3, 11))
# reward values that are exact in float32 too, so that rewards compare exactly in either dtype
ODD_REWARDS = Rewards(pick_target=0.5, pick_other=-1.5, deliver_target=3.25, deliver_other=-0.75)
DRIFTS = (
    TASKS["red"],
    Task(3, (3, 4), name="red-bottom", drop_zone="bottom"),
    Task(5, (5, 6), name="green-left", drop_zone="left", rewards=ODD_REWARDS),
    Task(3, (3, 4), name="red-right", drop_zone="right", failed_robots=2),
    Task(5, (5, 6), name="green-worn", motor_gain=0.625, failed_robots=1),
    Task(3, (3, 4), name="red-everything", drop_zone="bottom", rewards=ODD_REWARDS, failed_robots=4,
         motor_gain=0.75),
)
"""A task of every kind of drift, and one with all of them."""

# name -> (config, tasks cycled over the batch, batch size, steps to run)
CONFIGS = {
    "c4_paper_repos": (ForagingConfig(colors=FOUR, see_other_agents=False, repositioning=True,
                                      max_retrieves=3, duration=80),
                       ("red", "green"), 70, 80),
    "c8_norepos": (ForagingConfig(colors=EIGHT, see_other_agents=False, repositioning=False,
                                  max_retrieves=2, duration=70),
                   ("red", "green", "purple", "cyan"), 60, 70),
    "c8_agents_repos": (ForagingConfig(colors=EIGHT, see_other_agents=True, repositioning=True,
                                       max_retrieves=3, duration=80),
                        ("cyan", "purple", "green", "red"), 50, 80),
    "c4_agents_norepos_variant": (ForagingConfig(colors=FOUR, size=16.0, n_agents=4, n_boxes=12, sensor_range=3.5,
                                                 see_other_agents=True, repositioning=False,
                                                 max_retrieves=20, duration=60),
                                  ("green", "red"), 40, 65),
    "c4_six_neighbours": (ForagingConfig(colors=FOUR, n_neighbors=6, see_other_agents=False, repositioning=True,
                                         max_retrieves=3, duration=70),
                          ("red", "green"), 30, 75),
    "c4_drifts_mixed": (ForagingConfig(colors=FOUR, see_other_agents=True, repositioning=True,
                                       max_retrieves=3, duration=80),
                        DRIFTS, 72, 80),
}


# ---------------------------------------------------------------------------- random states
def nest_frame(x: float, y: float, size: float, drop_zone: str) -> tuple[float, float]:
    """A point drawn as if the nest were on top, carried to the task's edge."""
    return {"top": (x, y), "bottom": (size - x, y), "left": (y, x), "right": (y, size - x)}[drop_zone]


def random_state(rng: random.Random, c: ForagingConfig, task) -> OracleState:
    size, A, K = c.size, c.n_agents, c.n_boxes
    top = int(size)
    bx, by = [], []
    for k in range(K):
        if k > 0 and rng.random() < 0.15:  # stacked on an earlier box's cell
            j = rng.randrange(k)
            bx.append(bx[j])
            by.append(by[j])
        elif rng.random() < 0.7:  # the spec's spawn cells
            bx.append(float(rng.randint(6, top - 2)))
            by.append(float(rng.randint(2, top - 2)))
        else:  # any integer cell, near walls and the drop zone too
            bx.append(float(rng.randint(0, top)))
            by.append(float(rng.randint(0, top)))
    color_pool = list(task.season) if rng.random() < 0.8 else list(c.colors)
    color = [rng.choice(color_pool) for _ in range(K)]
    present = [True] * K
    carrying = [-1] * A
    free = list(range(K))
    rng.shuffle(free)
    for i in range(A):
        if rng.random() < 0.35 and free:
            k = free.pop()
            carrying[i] = k
            present[k] = False
    for k in free:
        if rng.random() < 0.08:  # gone (dropped earlier with repositioning off)
            present[k] = False
    ax, ay = [], []
    for i in range(A):
        u = rng.random()
        if u < 0.05:  # exactly on an edge
            x, y = rng.choice([0.0, size]), rng.uniform(0, size)
            if rng.random() < 0.5:
                x, y = y, x
        elif u < 0.2:  # near the bottom / right walls: negative distances with the "- 1"
            x = rng.uniform(size - 1.6, size) if rng.random() < 0.7 else rng.uniform(0, size)
            y = rng.uniform(size - 1.6, size) if rng.random() < 0.7 else rng.uniform(0, size)
        elif u < 0.45 or (carrying[i] >= 0 and u < 0.7):  # near the drop zone
            x, y = nest_frame(rng.uniform(0, 2.5), rng.uniform(0, size), size, task.drop_zone)
        elif u < 0.75:  # right next to a box
            k = rng.randrange(K)
            ang = rng.uniform(0, 2 * math.pi)
            rad = rng.uniform(0, 1.0)
            x = min(max(bx[k] + rad * math.cos(ang), 0.0), size)
            y = min(max(by[k] + rad * math.sin(ang), 0.0), size)
        else:
            x, y = rng.uniform(0, size), rng.uniform(0, size)
        ax.append(x)
        ay.append(y)
    heading = [rng.uniform(0, 360) for _ in range(A)]
    return OracleState(
        ax=ax, ay=ay, heading=heading, carrying=carrying, bx=bx, by=by, color=color, present=present,
        target=task.target, season=tuple(task.season),
        steps=rng.randint(0, 15), retrieved=rng.randint(0, c.max_retrieves - 1), done=rng.random() < 0.03,
        respawn_key=rng.randrange(0, 2 ** 31 - 1), drop_zone=task.drop_zone, rewards=task.rewards.values(),
        failed_robots=task.failed_robots, motor_gain=task.motor_gain)


def steer(vx: float, vy: float, r: float, vmax: float) -> list[float]:
    w = [A_INV[j][0] * vx + A_INV[j][1] * vy + A_INV[j][2] * r for j in range(3)]
    m = max(abs(v) for v in w)
    if m > vmax:
        w = [v * vmax / m for v in w]
    return w


def policy(rng: random.Random, o: Oracle) -> list[list[float]]:
    """Biased random wheels: carriers head for the drop zone, others for the nearest box."""
    s, c = o.s, o.c
    vmax = c.max_wheel_velocity
    wheels = []
    for i in range(c.n_agents):
        if rng.random() < 0.3:
            wheels.append([rng.uniform(-vmax, vmax) for _ in range(3)])
            continue
        r = rng.uniform(-1, 1)
        if s.carrying[i] >= 0:  # to the nest, with the motors' gain made up for
            home = {"top": (-1.6, 0.0), "bottom": (1.6, 0.0), "left": (0.0, -1.6), "right": (0.0, 1.6)}[s.drop_zone]
            wheels.append(steer(home[0] / s.motor_gain + rng.uniform(-0.5, 0.5) * (home[0] == 0),
                                home[1] / s.motor_gain + rng.uniform(-0.5, 0.5) * (home[1] == 0), r, vmax))
            continue
        best, best_d = None, math.inf
        for k in range(c.n_boxes):
            if s.present[k]:
                d = math.hypot(s.bx[k] - s.ax[i], s.by[k] - s.ay[i])
                if d < best_d:
                    best, best_d = k, d
        if best is None:
            wheels.append([rng.uniform(-vmax, vmax) for _ in range(3)])
            continue
        dx, dy = s.bx[best] - s.ax[i], s.by[best] - s.ay[i]
        speed = min(1.6, best_d / c.time_step) / max(best_d, 1e-9)
        wheels.append(steer(dx * speed, dy * speed, r, vmax))
    return wheels


# ---------------------------------------------------------------------------- the comparison
def check_obs(got: torch.Tensor, expected: list, atol: float, c: ForagingConfig, where: str) -> None:
    diff = (got.double() - torch.tensor(expected, dtype=torch.float64)).abs()
    err = diff.max().item()
    if err > atol:
        i, j = divmod(int(diff.argmax()), c.obs_dim)
        raise AssertionError(f"{where}: observation of agent {i}, entry {j}: env {got[i, j].item()} vs "
                             f"oracle {expected[i][j]} (max error {err})\nenv    {got[i].tolist()}\n"
                             f"oracle {expected[i]}")


def run_against_oracle(c: ForagingConfig, task_names, batch: int, n_steps: int, seed: int,
                       dtype=torch.float64, obs_atol=1e-5, device="cpu") -> Counter:
    rng = random.Random(seed)
    tasks = [task if isinstance(task, Task) else TASKS[task] for task in task_names]
    tasks = [tasks[b % len(tasks)] for b in range(batch)]
    states = [random_state(rng, c, t) for t in tasks]
    env = ForagingEnv(c, batch_size=batch, device=device, dtype=dtype)
    try:
        obs = env.reset(state=batched_state_from(states, c.n_colors, dtype=dtype)).cpu()
    except RuntimeError as e:
        raise AssertionError(f"BUG: the environment crashed on reset with batch_size={batch}, {c}: {e}") from e
    oracles = [Oracle(c, s) for s in oracle_states_from(env.state)]
    assert obs.shape == (batch, c.n_agents, c.obs_dim)
    for b, o in enumerate(oracles):
        check_obs(obs[b], o.last_obs, obs_atol, c, f"reset, env {b}")
    stats = Counter()
    for t in range(n_steps):
        wheels = [policy(rng, o) for o in oracles]
        try:
            obs, reward, done, info = env.step(torch.tensor(wheels, dtype=dtype, device=device))
        except RuntimeError as e:
            raise AssertionError(f"BUG: the environment crashed on step {t} with batch_size={batch}, {c}: {e}") from e
        obs, reward, done, info = obs.cpu(), reward.cpu(), done.cpu(), {k: v.cpu() for k, v in info.items()}
        assert obs.shape == (batch, c.n_agents, c.obs_dim) and reward.shape == (batch,) and done.shape == (batch,)
        for b, o in enumerate(oracles):
            was_done = o.s.done
            o_obs, o_rew, o_done, ev = o.step(wheels[b])
            where = f"step {t}, env {b} (task {tasks[b].name})"
            assert reward[b].item() == o_rew, f"{where}: reward {reward[b].item()} != oracle {o_rew}"
            assert bool(done[b]) == o_done, f"{where}: done {bool(done[b])} != oracle {o_done}"
            assert info["picked"][b].tolist() == ev["picked"], f"{where}: picked {info['picked'][b].tolist()} != {ev['picked']}"
            assert info["dropped"][b].tolist() == ev["dropped"], f"{where}: dropped {info['dropped'][b].tolist()} != {ev['dropped']}"
            dc = info["drop_correct"][b].tolist()
            for i in range(c.n_agents):
                if ev["dropped"][i] >= 0:
                    assert dc[i] == ev["drop_correct"][i], f"{where}: drop_correct of agent {i}"
                    if c.repositioning:
                        assert tuple(info["respawn_cell"][b, i].tolist()) == ev["respawn_cell"][i], \
                            f"{where}: respawn cell of agent {i}: {info['respawn_cell'][b, i].tolist()} != {ev['respawn_cell'][i]}"
            check_obs(obs[b], o_obs, obs_atol, c, where)
            if was_done:
                stats["frozen_steps"] += 1
                continue  # reward 0, done and no events are checked above; the state is checked below
            for i in range(c.n_agents):
                k = ev["picked"][i]
                if k >= 0:
                    stats["picks"] += 1
                    stats["wrong_picks"] += o.s.color[k] != o.s.target
                k = ev["dropped"][i]
                if k >= 0:
                    stats["correct_drops" if ev["drop_correct"][i] else "wrong_drops"] += 1
                    stats[f"drops_{o.s.drop_zone}"] += 1
                    stats["drops_by_failed_robots"] += i >= c.n_agents - o.s.failed_robots
                    stats["drops_at_odd_rewards"] += o.s.rewards != (1.0, -1.0, 2.0, 0.0)
                    stats["drops_with_worn_motors"] += o.s.motor_gain < 1
            if sum(p >= 0 for p in ev["picked"]) >= 2:
                stats["multi_pick_steps"] += 1
            for row in o_obs:  # a kept neighbour with a negative distance (the "- 1" walls)
                if min(row[(c.n_colors + 3) * c.n_neighbors:(c.n_colors + 4) * c.n_neighbors]) < 0:
                    stats["negative_distance_obs"] += 1
                    break
            if o_done:
                stats["early_ends" if o.s.retrieved >= c.max_retrieves else "duration_ends"] += 1
        stats["env_steps"] += batch
    # the full state agrees at the end (frozen environments included)
    final = env.state.to("cpu")
    for b, o in enumerate(oracles):
        s = o.s
        assert int(final.steps[b]) == s.steps and int(final.retrieved[b]) == s.retrieved, f"env {b}: counters"
        assert final.carrying[b].tolist() == s.carrying, f"env {b}: carrying"
        assert final.box_present[b].tolist() == s.present, f"env {b}: box_present"
        ax = final.agent_pos[b, :, 0].double()
        ay = final.agent_pos[b, :, 1].double()
        tol = 1e-9 if dtype == torch.float64 else 1e-3
        assert torch.allclose(ax, torch.tensor(s.ax, dtype=torch.float64), atol=tol), f"env {b}: agent x"
        assert torch.allclose(ay, torch.tensor(s.ay, dtype=torch.float64), atol=tol), f"env {b}: agent y"
        dh = (final.heading[b].double() - torch.tensor(s.heading, dtype=torch.float64)).abs()
        dh = torch.minimum(dh, 360 - dh)
        assert dh.max().item() <= tol * 100, f"env {b}: heading"
        for k in range(c.n_boxes):
            if s.present[k]:
                assert final.box_pos[b, k].tolist() == [s.bx[k], s.by[k]], f"env {b}: box {k} position"
    stats["episodes"] = batch
    return stats


@pytest.mark.parametrize("name", list(CONFIGS))
def test_env_matches_oracle_float64(name):
    c, task_names, batch, n_steps = CONFIGS[name]
    stats = run_against_oracle(c, task_names, batch, n_steps, seed=list(CONFIGS).index(name) + 7)
    print(name, dict(stats))
    # not vacuous: the rules were really exercised
    assert stats["picks"] >= 30, stats
    assert stats["wrong_picks"] >= 10, stats
    assert stats["correct_drops"] >= 10, stats
    assert stats["wrong_drops"] >= 8, stats
    assert stats["negative_distance_obs"] >= 20, stats
    assert stats["frozen_steps"] >= 50, stats
    assert stats["multi_pick_steps"] >= 1, stats
    if c.max_retrieves <= 3:
        assert stats["early_ends"] >= 5, stats
    assert stats["duration_ends"] >= 5, stats


def test_every_drift_matches_oracle_in_one_batch():
    """``c4_drifts_mixed`` really delivers at every edge, at other reward values and with worn
    motors, and no failed robot ever picks or drops (the oracle's failed robots do nothing)."""
    c, tasks, batch, n_steps = CONFIGS["c4_drifts_mixed"]
    stats = run_against_oracle(c, tasks, batch, n_steps, seed=61)
    for zone in ("top", "bottom", "left", "right"):
        assert stats[f"drops_{zone}"] >= 5, stats
    assert stats["drops_at_odd_rewards"] >= 5 and stats["drops_with_worn_motors"] >= 3, stats
    assert stats["drops_by_failed_robots"] == 0, stats


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_mixed_batch_gives_each_environment_its_numbers_alone(dtype):
    """Every environment of a batch that mixes every kind of task gives, bit for bit, what it
    gives in a batch of its own: the per-environment task fields never leak across the batch."""
    c = ForagingConfig(see_other_agents=True, duration=200)
    batch = len(DRIFTS) * 2
    env = ForagingEnv(c, batch_size=batch, dtype=dtype)
    env.reset([DRIFTS[b % len(DRIFTS)] for b in range(batch)], generator=5)
    start = env.state
    generator = torch.Generator().manual_seed(6)
    held = torch.rand(10, batch, 1, 3, generator=generator, dtype=dtype) * 4 - 2  # each held for 20 steps
    wheels = held.repeat_interleave(20, dim=0) + torch.rand(200, batch, c.n_agents, 3, generator=generator, dtype=dtype)
    together = [env.step(w)[:2] for w in wheels]
    odd = [b for b in range(batch) if DRIFTS[b % len(DRIFTS)].rewards != Rewards()]
    assert any(rewards[b] != 0 for _, rewards in together for b in odd), "other reward values are earned"
    for b in range(batch):
        alone = ForagingEnv(c, batch_size=1, dtype=dtype)
        alone.reset(state=start.index([b]))
        for t, w in enumerate(wheels):
            obs, reward = alone.step(w[b:b + 1])[:2]
            assert torch.equal(obs[0], together[t][0][b]) and torch.equal(reward[0], together[t][1][b]), \
                f"env {b} ({DRIFTS[b % len(DRIFTS)].name}), step {t}"


@pytest.mark.parametrize("name", ["c8_agents_repos", "c4_agents_norepos_variant"])
def test_agent_sensing_matches_oracle_batch_of_one(name):
    """Agent sensing, one environment per batch (isolates batch-size effects from the semantics)."""
    c, task_names, _, n_steps = CONFIGS[name]
    stats = Counter()
    for e in range(6):
        names = task_names[e % len(task_names):] + task_names[:e % len(task_names)]
        stats += run_against_oracle(c, names, 1, 35, seed=500 + e)
    assert stats["picks"] >= 5, stats


def test_oracle_suite_covers_200_episodes():
    assert sum(batch for _, _, batch, _ in CONFIGS.values()) >= 200
    assert {c.n_colors for c, *_ in CONFIGS.values()} == {4, 8}
    assert {c.see_other_agents for c, *_ in CONFIGS.values()} == {True, False}
    assert {c.repositioning for c, *_ in CONFIGS.values()} == {True, False}


def test_env_matches_oracle_with_fewer_boxes_than_neighbour_slots():
    """n_boxes < n_neighbors: slots that no entity fills must be padded with (0, 0, 0)."""
    c = ForagingConfig(n_agents=3, n_boxes=2, max_retrieves=2, duration=40)
    stats = run_against_oracle(c, ("red", "green"), 20, 40, seed=31)
    assert stats["picks"] >= 3, stats


@pytest.mark.parametrize("name", ["c4_paper_repos", "c8_norepos"])
def test_env_float32_matches_oracle_short_horizon(name):
    c, task_names, _, _ = CONFIGS[name]
    stats = run_against_oracle(c, task_names, batch=60, n_steps=20, seed=99, dtype=torch.float32, obs_atol=1e-4)
    assert stats["picks"] >= 5, stats
