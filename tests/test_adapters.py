"""The Gymnasium (single and vector) and PettingZoo adapters over ForagingEnv."""
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils import seeding
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode, VectorEnv
from pettingzoo import ParallelEnv
from pettingzoo.test import parallel_api_test

import envs
from envs import ENV_ID, TASKS, ConfigError, ForagingConfig, ForagingEnv, Rewards, Task
from envs.gym_env import observation_bounds, torch_seed

EIGHT = {"colors": tuple(range(3, 11)), "task": "cyan"}
SMALL = {"size": 14.0, "n_boxes": 8, "n_agents": 4, "duration": 60}   # walls and boxes are reached quickly
DRIFT = {"task": Task(5, (5, 6), name="green-west", drop_zone="left", failed_robots=2, motor_gain=0.5,
                       rewards=Rewards(pick_other=-2.0, deliver_other=-1.0))}
"""A task with every drift field set (issue #61)."""
OPTION_SETS = [{}, EIGHT, {"see_other_agents": True, "task": "green"}, DRIFT]


def config_of(options):
    return ForagingConfig(**{k: v for k, v in options.items() if k != "task"})


def torch_generator_seed(seed):
    """The torch seed the adapters draw for their first sampling after ``reset(seed=seed)``."""
    return torch_seed(seeding.np_random(seed)[0])


def driving_actions(rng, n_envs, n_agents, v):
    """Wheel speeds that drive the agents across the arena (random actions barely move them)."""
    base = rng.choice([-v, v], size=(n_envs, 1, 3))
    return np.clip(base + rng.normal(0, 0.3 * v, size=(n_envs, n_agents, 3)), -v, v).astype(np.float32)


# ---------------------------------------------------------------------- single Gymnasium env
@pytest.mark.parametrize("options", OPTION_SETS, ids=["default", "8-colours", "see-agents", "drift-task"])
def test_check_env(options):
    env = gym.make(ENV_ID, **options)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
        check_env(env)
    messages = [str(w.message) for w in caught]
    # the only warning left is check_env's own note that `env` (from make) is wrapped
    assert [m for m in messages if "different from the unwrapped" not in m] == []
    assert len(messages) == 1
    config = config_of(options)
    assert env.observation_space.shape == (config.n_agents, config.obs_dim)
    assert env.observation_space.dtype == np.float32
    assert env.action_space.shape == (config.n_agents, 3)
    assert env.action_space.high.max() == config.max_wheel_velocity == -env.action_space.low.min()


def test_observation_bounds_are_the_spec_ranges():
    config = ForagingConfig(sensor_range=4.0)
    low, high = observation_bounds(config)
    c, n = config.n_colors, config.n_neighbors
    distances = slice((c + 3) * n, (c + 3) * n + n)
    assert np.all(low[distances] == -0.25) and np.all(high[distances] == 1.0)
    assert np.all(low[: (c + 3) * n] == 0) and np.all(low[-(2 * c + 1):] == 0)
    assert np.all(low[(c + 4) * n:(c + 6) * n + 2] == -1.0)
    assert np.all(high == 1.0)


def test_gym_reset_matches_foraging_env_and_steps_alike():
    env = gym.make(ENV_ID, task="green").unwrapped
    obs, info = env.reset(seed=5)
    direct = ForagingEnv(ForagingConfig(), batch_size=1)
    expected = direct.reset(TASKS["green"], generator=torch_generator_seed(5))
    np.testing.assert_array_equal(obs, expected[0].numpy())
    rng = np.random.default_rng(0)
    for _ in range(30):
        wheels = driving_actions(rng, 1, 5, 2.0)
        obs, reward, terminated, truncated, info = env.step(wheels[0])
        d_obs, d_reward, d_done, d_info = direct.step(torch.from_numpy(wheels))
        np.testing.assert_array_equal(obs, d_obs[0].numpy())
        assert reward == float(d_reward[0]) and not (terminated or truncated)
        np.testing.assert_array_equal(info["picked"], d_info["picked"][0].numpy())


def test_gym_determinism_and_truncation():
    def rollout(seed):
        env = gym.make(ENV_ID, duration=40)
        env.action_space.seed(seed)
        out = [env.reset(seed=seed)[0]]
        for t in range(40):
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            out += [obs, reward]
            assert truncated == (t == 39) and not terminated
            assert set(info) == {"picked", "dropped", "drop_correct", "respawn_cell"}
            assert all(isinstance(v, np.ndarray) for v in info.values())
        return out

    a, b, c = rollout(3), rollout(3), rollout(4)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not np.array_equal(a[0], c[0])


def test_terminated_when_max_retrieves_reached():
    """An agent in the drop zone carrying a target box: the step's drop ends the episode."""
    env = gym.make(ENV_ID, max_retrieves=1).unwrapped
    env.reset(seed=0)
    state = env.foraging.state
    k = int((state.box_color[0] == state.target[0]).nonzero()[0, 0])
    state.carrying[0, 0], state.box_present[0, k], state.agent_pos[0, 0, 0] = k, False, 0.5
    env.foraging.reset(state=state)
    obs, reward, terminated, truncated, info = env.step(np.zeros((5, 3), np.float32))
    assert terminated and not truncated and reward == 2.0
    assert info["dropped"][0] == k and info["drop_correct"][0]
    assert np.all(info["respawn_cell"][0] >= 0) and np.all(info["respawn_cell"][1:] == -1)


def test_reset_option_and_set_task():
    env = gym.make(ENV_ID, **EIGHT).unwrapped
    config = config_of(EIGHT)
    obs, _ = env.reset(seed=0, options={"task": "purple"})
    target = obs[0, -config.n_colors:]
    assert target.argmax() == TASKS["purple"].target - 3
    env.set_task("red")
    obs, *_ = env.step(np.zeros((5, 3), np.float32))
    assert obs[0, -config.n_colors:].argmax() == 0
    with pytest.raises(ConfigError, match="unknown reset option"):
        env.reset(options={"tsak": "red"})


def test_rgb_array_render():
    env = gym.make(ENV_ID, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.shape == (320, 320, 3)

    def shaded(pixels):  # the share of the nest's colour: robots may stand in the nest
        return (pixels == (170, 200, 170)).all(-1).mean()

    assert shaded(frame[:16]) > 0.8 and shaded(frame[16:]) == 0, "the nest on top, 1 unit deep"
    right = gym.make(ENV_ID, render_mode="rgb_array", task=Task(3, (3, 4), name="red-east", drop_zone="right"))
    right.reset(seed=0)
    frame = right.render()
    assert shaded(frame[:, -16:]) > 0.8 and shaded(frame[:, :-16]) == 0, "the nest on the right"


# ---------------------------------------------------------------------- vector env
def make_vec(n, **options):
    return gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point", **options)


def test_make_vec_spaces_and_shapes():
    venv = make_vec(3, **EIGHT)
    assert isinstance(venv, VectorEnv) and venv.num_envs == 3
    assert venv.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    config = config_of(EIGHT)
    assert venv.single_observation_space == gym.make(ENV_ID, **EIGHT).observation_space
    assert venv.single_action_space.shape == (config.n_agents, 3)
    assert venv.observation_space.shape == (3, config.n_agents, config.obs_dim)
    assert venv.action_space.shape == (3, config.n_agents, 3)
    obs, info = venv.reset(seed=0)
    assert obs.shape == venv.observation_space.shape and obs.dtype == np.float32 and info == {}
    venv.action_space.seed(0)
    obs, reward, terminated, truncated, info = venv.step(venv.action_space.sample())
    assert obs.shape == (3, config.n_agents, config.obs_dim) and obs.dtype == np.float32
    assert reward.shape == terminated.shape == truncated.shape == (3,)
    assert reward.dtype == np.float64 and terminated.dtype == truncated.dtype == np.bool_
    assert info["picked"].shape == (3, config.n_agents) and info["respawn_cell"].shape == (3, config.n_agents, 2)
    assert info["_picked"].all()
    with pytest.raises(ValueError, match="shape"):
        venv.step(np.zeros((3, 3), np.float32))
    # the default vectorization of an id with a vector entry point is the batched env too
    assert isinstance(gym.make_vec(ENV_ID, num_envs=2), type(venv))


def test_vector_parity_with_foraging_env_through_autoreset():
    """Same seed handling and wheel actions: the same observations and rewards as ForagingEnv,
    and at the step after the end the reset observations, reward 0, flags False."""
    n, duration = 4, 3
    tasks = ["red", "green", "red", "green"]
    venv = make_vec(n, duration=duration, task=tasks)
    obs, _ = venv.reset(seed=11)
    np_random = seeding.np_random(11)[0]
    direct = ForagingEnv(ForagingConfig(duration=duration), batch_size=n)
    task_list = [TASKS[t] for t in tasks]
    expected = direct.reset(task_list, generator=torch_seed(np_random))
    np.testing.assert_array_equal(obs, expected.numpy())
    rng = np.random.default_rng(1)
    for t in range(2 * duration + 2):
        wheels = driving_actions(rng, n, 5, 2.0)
        obs, reward, terminated, truncated, info = venv.step(wheels)
        d_obs, d_reward, d_done, _ = direct.step(torch.from_numpy(wheels))
        if t % (duration + 1) == duration:       # the step after the end: autoreset
            d_obs = direct.reset_done(task_list, generator=torch_seed(np_random))
            np.testing.assert_array_equal(reward, 0.0)
            assert not terminated.any() and not truncated.any() and not info["_picked"].any()
        else:
            np.testing.assert_array_equal(reward, d_reward.numpy())
            assert np.array_equal(truncated, d_done.numpy()) and not terminated.any()
            assert truncated.all() == (t % (duration + 1) == duration - 1)
        np.testing.assert_array_equal(obs, d_obs.numpy())


def test_vector_autoreset_of_one_env_leaves_the_others():
    """One sub-environment ends early (max retrievals): only it is reset at the next step."""
    venv = make_vec(3, max_retrieves=1, duration=50)
    venv.reset(seed=2)
    inner = venv.unwrapped.foraging
    state = inner.state
    k = int((state.box_color[1] == state.target[1]).nonzero()[0, 0])
    state.carrying[1, 0], state.box_present[1, k], state.agent_pos[1, 0, 0] = k, False, 0.5
    inner.reset(state=state)
    still = np.zeros((3, 5, 3), np.float32)
    obs, reward, terminated, truncated, info = venv.step(still)
    assert terminated.tolist() == [False, True, False] and not truncated.any() and reward[1] == 2.0
    before = inner.state
    obs, reward, terminated, truncated, info = venv.step(still)
    after = inner.state
    assert reward[1] == 0 and not terminated.any() and info["_picked"].tolist() == [True, False, True]
    assert after.steps.tolist() == [2, 0, 2] and after.retrieved.tolist() == [0, 0, 0]
    assert not torch.equal(after.box_pos[1], before.box_pos[1])
    assert torch.equal(after.box_pos[[0, 2]], before.box_pos[[0, 2]])


def test_vector_determinism_and_reset_mask():
    def rollout(seed):
        venv = make_vec(3, duration=5)
        out = [venv.reset(seed=seed)[0]]
        rng = np.random.default_rng(0)
        for _ in range(12):
            obs, reward, *_ = venv.step(driving_actions(rng, 3, 5, 2.0))
            out += [obs, reward]
        return out

    a, b, c = rollout(7), rollout(7), rollout(8)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not np.array_equal(a[0], c[0])

    venv = make_vec(3)
    first, _ = venv.reset(seed=0)
    moved, *_ = venv.step(np.full((3, 5, 3), 1.0, np.float32))
    obs, _ = venv.reset(options={"reset_mask": np.array([False, True, False])})
    np.testing.assert_array_equal(obs[[0, 2]], moved[[0, 2]])
    assert not np.array_equal(obs[1], moved[1]) and not np.array_equal(obs[1], first[1])
    assert venv.unwrapped.foraging.state.steps.tolist() == [1, 0, 1]


# ---------------------------------------------------------------------- PettingZoo
@pytest.mark.parametrize("options", [{}, EIGHT, DRIFT], ids=["default", "8-colours", "drift-task"])
def test_parallel_api(options):
    env = envs.parallel_env(duration=60, **options)
    assert isinstance(env, ParallelEnv)
    parallel_api_test(env, num_cycles=80)
    config = config_of(options)
    assert env.possible_agents == [f"agent_{i}" for i in range(config.n_agents)]
    assert env.observation_space("agent_0").shape == (config.obs_dim,)
    assert env.action_space("agent_0").shape == (3,)


def test_parallel_rewards_flags_and_end():
    env = envs.parallel_env(duration=4)
    obs, infos = env.reset(seed=1)
    gym_env = gym.make(ENV_ID, duration=4).unwrapped
    gym_obs, _ = gym_env.reset(seed=1)
    np.testing.assert_array_equal(np.stack([obs[a] for a in env.possible_agents]), gym_obs)
    rng = np.random.default_rng(0)
    for t in range(4):
        wheels = driving_actions(rng, 1, 5, 2.0)[0]
        obs, rewards, terms, truncs, infos = env.step({a: wheels[i] for i, a in enumerate(env.agents)})
        gym_obs, gym_reward, _, gym_trunc, _ = gym_env.step(wheels)
        assert set(rewards.values()) == {gym_reward} and set(truncs.values()) == {gym_trunc}
        assert not any(terms.values()) and set(infos["agent_0"]) == {"picked", "dropped", "drop_correct", "respawn_cell"}
        np.testing.assert_array_equal(env.state(), gym_obs)
    assert env.agents == []
    with pytest.raises(RuntimeError):
        env.step({})
    env.reset()
    with pytest.raises(ValueError, match="missing"):
        env.step({"agent_0": np.zeros(3, np.float32)})


# ---------------------------------------------------------------------- observations in their spaces
@pytest.mark.parametrize("options", [SMALL, {**SMALL, **EIGHT, "see_other_agents": True},
                                     {**SMALL, "task": Task(5, (5, 6), name="green-east", drop_zone="right",
                                                            failed_robots=1)}],
                         ids=["small", "small-8-agents", "small-drift-task"])
def test_observations_stay_in_their_spaces(options):
    config = config_of(options)
    dist = slice((config.n_colors + 3) * config.n_neighbors, (config.n_colors + 4) * config.n_neighbors)
    rng = np.random.default_rng(0)
    v = config.max_wheel_velocity
    lowest = []

    env = gym.make(ENV_ID, **options).unwrapped
    obs, _ = env.reset(seed=0)
    for t in range(200):
        assert env.observation_space.contains(obs), t
        lowest.append(obs[..., dist].min())
        obs, _, terminated, truncated, _ = env.step(driving_actions(rng, 1, config.n_agents, v)[0])
        if terminated or truncated:
            obs, _ = env.reset()

    venv = make_vec(4, **options)
    obs, _ = venv.reset(seed=0)
    for t in range(200):
        assert venv.observation_space.contains(obs), t
        assert all(venv.single_observation_space.contains(o) for o in obs)
        lowest.append(obs[..., dist].min())
        obs, *_ = venv.step(driving_actions(rng, 4, config.n_agents, v))

    penv = envs.parallel_env(**options)
    obs, _ = penv.reset(seed=0)
    for t in range(200):
        assert all(penv.observation_space(a).contains(o) for a, o in obs.items()), t
        wheels = driving_actions(rng, 1, config.n_agents, v)[0]
        obs, *_ = penv.step({a: wheels[i] for i, a in enumerate(penv.agents)})
        if not penv.agents:
            obs, _ = penv.reset()
    # the run reached the bottom/right walls, where the spec's `- 1` makes distances negative
    assert min(lowest) < 0


# ---------------------------------------------------------------------- bad options
@pytest.mark.parametrize("make", [
    lambda **kw: gym.make(ENV_ID, **kw),
    lambda **kw: make_vec(2, **kw),
    lambda **kw: envs.parallel_env(**kw),
], ids=["gym", "vector", "pettingzoo"])
def test_bad_options_give_one_clear_error(make):
    with pytest.raises(ConfigError, match=r"unknown environment option\(s\) \['n_agent'\].*'n_agents'"):
        make(n_agent=3)
    with pytest.raises(ConfigError, match="unknown task 'magenta': choose one of red, green, purple, cyan"):
        make(task="magenta")
    with pytest.raises(ConfigError, match="colour id 9, which this arena does not know"):
        make(task="cyan")
    with pytest.raises(ConfigError, match="task 'red-two-failed'.*failed_robots"):  # a built-in drift, by name
        make(task="red-two-failed", n_agents=2)
    with pytest.raises(ConfigError, match="n_agents must be"):
        make(n_agents=0)


def test_registered_once():
    from envs.gym_env import register_envs
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        register_envs()
    assert gym.spec(ENV_ID).vector_entry_point == "envs.gym_env:SwarmForagingVectorEnv"
