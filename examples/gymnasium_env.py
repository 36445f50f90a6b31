"""The foraging arena through Gymnasium: one environment, then a vector of them.

    python examples/gymnasium_env.py
"""
from __future__ import annotations

import gymnasium
import numpy as np

import envs  # noqa: F401  (registers lifelong_evo/SwarmForaging-v0)


def main(steps: int = 200, num_envs: int = 8, task: str = "green") -> None:
    env = gymnasium.make("lifelong_evo/SwarmForaging-v0", task=task, duration=steps)
    observation, info = env.reset(seed=0)
    episode_return, done = 0.0, False
    while not done:
        observation, reward, terminated, truncated, info = env.step(env.action_space.sample())
        episode_return += reward
        done = terminated or truncated
    print(f"one environment, random wheels: return {episode_return:+.1f} over {steps} steps, "
          f"observation {observation.shape}")

    vector = gymnasium.make_vec("lifelong_evo/SwarmForaging-v0", num_envs=num_envs,
                                vectorization_mode="vector_entry_point", task=task, duration=steps)
    observations, infos = vector.reset(seed=0)
    returns = np.zeros(num_envs)
    for _ in range(steps):
        observations, rewards, terminated, truncated, infos = vector.step(vector.action_space.sample())
        returns += rewards
    print(f"{num_envs} environments in one torch batch: returns {np.round(returns, 1).tolist()}")
    vector.close()


if __name__ == "__main__":
    main()
