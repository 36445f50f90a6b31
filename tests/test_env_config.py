"""Configuration validation: bad options raise ConfigError naming the problem; observation sizes."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from envs import (MAX_REWARD, MIN_MOTOR_GAIN, TASKS, ConfigError, ForagingConfig, ForagingEnv, Rewards, Task,
                  colors_for_tasks, task_by_name)

EIGHT = tuple(range(3, 11))


def test_defaults_are_the_papers():
    c = ForagingConfig()
    assert (c.size, c.n_agents, c.n_boxes, c.n_neighbors) == (20.0, 5, 20, 3)
    assert (c.sensor_range, c.max_wheel_velocity, c.sensitivity, c.time_step) == (4.0, 2.0, 0.5, 0.1)
    assert (c.duration, c.max_retrieves, c.rate_target) == (500, 20, 0.5)
    assert c.repositioning is True and c.see_other_agents is False
    assert c.colors == (3, 4, 5, 6)
    assert TASKS["red"] == Task(3, (3, 4)) and TASKS["green"] == Task(5, (5, 6))
    assert TASKS["purple"] == Task(7, (7, 8)) and TASKS["cyan"] == Task(9, (9, 10))


@pytest.mark.parametrize("colors, n_neighbors, expected", [((3, 4, 5, 6), 3, 41), (EIGHT, 3, 61),
                                                            ((3, 4, 5, 6), 5, 7 * 5 + 15 + 2 + 5 + 4),
                                                            ((3,), 2, 4 * 2 + 6 + 2 + 2 + 1)])
def test_obs_dim(colors, n_neighbors, expected):
    c = ForagingConfig(colors=colors, n_neighbors=n_neighbors, rate_target=1.0 if len(colors) == 1 else 0.5)
    assert c.obs_dim == expected
    env = ForagingEnv(c, batch_size=2, dtype=torch.float64)
    task = Task(3, (3,)) if len(colors) == 1 else TASKS["red"]
    assert env.reset(tasks=task, generator=0).shape == (2, c.n_agents, expected)


@pytest.mark.parametrize("colors", [(3, 4, 6), (4, 5, 6, 7), (3, 5), (4, 3, 5, 6), ()])
def test_non_contiguous_colors(colors):
    with pytest.raises(ConfigError, match="colors"):
        ForagingConfig(colors=colors)


@pytest.mark.parametrize("field", ["n_agents", "n_boxes", "n_neighbors", "duration", "max_retrieves"])
@pytest.mark.parametrize("value", [0, -3])
def test_sizes_below_one(field, value):
    with pytest.raises(ConfigError, match=field):
        ForagingConfig(**{field: value})


@pytest.mark.parametrize("field", ["sensor_range", "max_wheel_velocity", "sensitivity", "time_step"])
@pytest.mark.parametrize("value", [-1.0, 0.0])
def test_non_positive_lengths(field, value):
    with pytest.raises(ConfigError, match=field):
        ForagingConfig(**{field: value})


def test_sensitivity_beyond_one_cell():
    ForagingConfig(sensitivity=0.5)
    with pytest.raises(ConfigError, match="sensitivity must be <= 0.5"):
        ForagingConfig(sensitivity=0.51)


@pytest.mark.parametrize("rate", [-0.1, 1.01, 2.0])
def test_rate_target_outside_unit_interval(rate):
    with pytest.raises(ConfigError, match="rate_target"):
        ForagingConfig(rate_target=rate)


def test_rate_target_edges_are_valid():
    ForagingConfig(rate_target=0.0)
    ForagingConfig(rate_target=1.0)


def test_too_many_boxes_for_the_arena():
    with pytest.raises(ConfigError, match="n_boxes"):
        ForagingConfig(n_boxes=1000)
    with pytest.raises(ConfigError, match="n_boxes"):
        ForagingConfig(size=10.0, n_boxes=20)
    with pytest.raises(ConfigError, match="size"):
        ForagingConfig(size=5.0)
    with pytest.raises(ConfigError, match="at most 30 boxes"):
        ForagingConfig(n_boxes=31)
    # the most the paper's arena allows can always be placed (a jam would hang reset)
    from envs import TASKS, ForagingEnv

    env = ForagingEnv(ForagingConfig(n_boxes=30), batch_size=64)
    env.reset(TASKS["red"], generator=0)
    assert env.state.box_present.all()


def test_task_target_outside_its_season():
    """A task whose target no box can have is refused where it is made, whatever arena it would
    run in: in Python as from a task file."""
    with pytest.raises(ConfigError, match=r"task 'red': target red is not in its season \[blue, green\]"):
        Task(3, (4, 5))


def test_task_color_unknown_to_the_arena():
    env = ForagingEnv(ForagingConfig(), 2)
    with pytest.raises(ConfigError, match="colour id 9"):
        env.reset(tasks=TASKS["cyan"], generator=0)
    with pytest.raises(ConfigError, match="does not know"):
        env.reset(tasks=[TASKS["red"], TASKS["purple"]], generator=0)
    ForagingEnv(ForagingConfig(colors=EIGHT), 2).reset(tasks=[TASKS["red"], TASKS["cyan"]], generator=0)


def test_season_with_only_the_target_needs_rate_one():
    with pytest.raises(ConfigError, match="season"):
        ForagingConfig().check_task(Task(3, (3,)))
    ForagingConfig(rate_target=1.0).check_task(Task(3, (3,)))


def test_the_drift_fields_default_to_the_papers():
    task = Task(3, (3, 4))
    assert (task.drop_zone, task.failed_robots, task.motor_gain) == ("top", 0, 1.0)
    assert task.rewards.values() == (1.0, -1.0, 2.0, 0.0) and task == TASKS["red"]
    assert Task(3, (3, 4), rewards={"deliver_target": 5}).rewards == Rewards(deliver_target=5.0)


@pytest.mark.parametrize("fields, message", [
    ({"drop_zone": "north"}, "drop_zone 'north' is not an edge: choose one of top, bottom, left, right"),
    ({"rewards": {"pick_target": math.inf}}, "task 'bad': reward pick_target must be a number from -1e6 to 1e6"),
    ({"rewards": {"deliver_other": math.nan}}, "reward deliver_other must be a number from -1e6 to 1e6"),
    ({"rewards": {"pick_other": "1"}}, "reward pick_other must be a number"),
    ({"rewards": {"pick_other": True}}, "reward pick_other must be a number"),
    # finite in float64, but not in the step's float32 (or not summable in it)
    ({"rewards": {"pick_target": 1e39}}, "reward pick_target must be a number from -1e6 to 1e6"),
    ({"rewards": {"pick_target": 3e38, "pick_other": -3e38}}, "reward pick_target must be a number"),
    ({"rewards": {"deliver_target": 10 ** 400}}, r"reward deliver_target .*, got 1000000000000.*\.\.\.0000000000$"),
    ({"rewards": {"bonus": 1.0}}, r"unknown reward\(s\) \['bonus'\]: valid ones are pick_target, pick_other"),
    ({"failed_robots": -1}, "failed_robots must be an integer >= 0"),
    ({"failed_robots": 1.5}, "failed_robots must be an integer >= 0"),
    ({"failed_robots": np.bool_(True)}, "failed_robots must be an integer >= 0"),
    ({"motor_gain": 0.0}, "motor_gain must be a number from 1e-6 to 1"),
    ({"motor_gain": 1.01}, "motor_gain must be a number from 1e-6 to 1"),
    ({"motor_gain": math.nan}, "motor_gain must be a number from 1e-6 to 1"),
    ({"motor_gain": 1e-50}, "motor_gain must be a number from 1e-6 to 1"),  # 0 in float32
    ({"motor_gain": 10 ** 400}, "motor_gain must be a number from 1e-6 to 1"),
])
def test_bad_drift_fields_are_refused(fields, message):
    with pytest.raises(ConfigError, match=message):
        Task(3, (3, 4), name="bad", **fields)


def test_numpy_numbers_are_numbers():
    task = Task(3, (3, 4), rewards={"pick_other": np.float32(-0.5)}, failed_robots=np.int64(2),
                motor_gain=np.float32(0.5))
    assert (task.rewards.pick_other, task.failed_robots, task.motor_gain) == (-0.5, 2, 0.5)
    assert type(task.failed_robots) is int and type(task.motor_gain) is float and type(task.rewards.pick_other) is float
    assert Task(3, (3, 4), rewards={"pick_target": MAX_REWARD, "pick_other": -MAX_REWARD},
                motor_gain=MIN_MOTOR_GAIN).rewards.values()[:2] == (1e6, -1e6)


def test_failed_robots_leave_at_least_one_robot_working():
    ForagingConfig(n_agents=5).check_task(Task(3, (3, 4), failed_robots=4))
    with pytest.raises(ConfigError, match="failed_robots=5, but at least one of the 5 robots must work: use 0 to 4"):
        ForagingConfig(n_agents=5).check_task(Task(3, (3, 4), failed_robots=5))
    with pytest.raises(ConfigError, match="failed_robots"):
        ForagingEnv(ForagingConfig(n_agents=2), 1).reset(Task(3, (3, 4), failed_robots=2), generator=0)


def test_explicit_state_with_bad_task_fields():
    env, state = _valid_state()
    for name, value, message in (("drop_zone", 4, "drop_zone"), ("rewards", math.inf, "rewards"),
                                 ("failed_robots", 5, "failed_robots"), ("motor_gain", 0.0, "motor_gain")):
        bad = state.clone()
        getattr(bad, name)[1] = value
        with pytest.raises(ConfigError, match=message):
            env.reset(state=bad)


def test_wrong_number_of_tasks_and_missing_tasks():
    env = ForagingEnv(ForagingConfig(), 3)
    with pytest.raises(ConfigError, match="tasks"):
        env.reset(tasks=[TASKS["red"], TASKS["green"]], generator=0)
    with pytest.raises(ConfigError, match="tasks"):
        env.reset()


def test_batch_size_and_dtype():
    with pytest.raises(ConfigError, match="batch_size"):
        ForagingEnv(ForagingConfig(), 0)
    with pytest.raises(ConfigError, match="dtype"):
        ForagingEnv(ForagingConfig(), 2, dtype=torch.float16)


def _valid_state(batch=2):
    env = ForagingEnv(ForagingConfig(), batch, dtype=torch.float64)
    env.reset(tasks=TASKS["red"], generator=0)
    return env, env.state


@pytest.mark.parametrize("field, shape", [("agent_pos", (2, 6, 2)), ("heading", (2, 4)), ("carrying", (3, 5)),
                                          ("box_pos", (2, 19, 2)), ("box_color", (2, 21)),
                                          ("box_present", (2,)), ("target", (2, 1)), ("season", (2, 8)),
                                          ("steps", (1,)), ("done", (2, 2)), ("respawn_key", ())])
def test_wrong_shaped_explicit_state(field, shape):
    env, state = _valid_state()
    old = getattr(state, field)
    bad = dataclasses.replace(state, **{field: torch.zeros(shape, dtype=old.dtype)})
    with pytest.raises(ConfigError, match=field):
        env.reset(state=bad)
    env.reset(state=state)  # the untouched state is fine


def test_non_integer_box_positions():
    env, state = _valid_state()
    state.box_pos[1, 3, 0] += 0.5
    with pytest.raises(ConfigError, match="box_pos"):
        env.reset(state=state)


@pytest.mark.parametrize("cell", [-1.0, 21.0])
def test_box_positions_outside_the_arena(cell):
    env, state = _valid_state()
    state.box_pos[0, 2, 1] = cell
    with pytest.raises(ConfigError, match="box_pos must lie in the arena"):
        env.reset(state=state)


def test_explicit_state_with_unknown_colors_or_boxes():
    env, state = _valid_state()
    bad = state.clone()
    bad.box_color[0, 0] = 9
    with pytest.raises(ConfigError, match="box_color"):
        env.reset(state=bad)
    bad = state.clone()
    bad.target[1] = 2
    with pytest.raises(ConfigError, match="target"):
        env.reset(state=bad)
    bad = state.clone()
    bad.carrying[0, 0] = 20
    with pytest.raises(ConfigError, match="carrying"):
        env.reset(state=bad)


def test_explicit_state_round_trip():
    env, state = _valid_state()
    obs = env.reset(state=state)
    other = ForagingEnv(ForagingConfig(), 2, dtype=torch.float64)
    assert torch.equal(other.reset(state=state.clone()), obs)
    for f in dataclasses.fields(state):
        assert torch.equal(getattr(other.state, f.name), getattr(state, f.name)), f.name


def test_from_dict_and_task_names():
    c = ForagingConfig(n_agents=3, colors=EIGHT)
    assert ForagingConfig.from_dict(c.to_dict()) == c
    with pytest.raises(ConfigError, match="n_robots"):
        ForagingConfig.from_dict({"n_robots": 3})
    assert task_by_name("green") == TASKS["green"]
    assert task_by_name("red-nest-bottom").drop_zone == "bottom" and task_by_name("red-two-failed").failed_robots == 2
    with pytest.raises(ConfigError, match="magenta"):
        task_by_name("magenta")
    assert colors_for_tasks([TASKS["red"], TASKS["green"]]) == (3, 4, 5, 6)
    assert colors_for_tasks([TASKS["red"], TASKS["cyan"]]) == EIGHT
