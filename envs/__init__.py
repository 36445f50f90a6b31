"""The batched swarm-foraging environment and its Gymnasium / PettingZoo adapters."""
from .config import (COLOR_IDS, COLOR_NAMES, COLOR_RGB, DROP_ZONES, MAX_REWARD, MIN_MOTOR_GAIN, TASKS, UNKNOWN_RGB,
                     ConfigError, ForagingConfig, Rewards, Task, color_rgb, colors_for_tasks, task_by_name, task_rgb)
from .foraging import ForagingEnv, outputs_to_wheels
from .state import ForagingState

__all__ = ["COLOR_IDS", "COLOR_NAMES", "COLOR_RGB", "DROP_ZONES", "MAX_REWARD", "MIN_MOTOR_GAIN", "TASKS", "UNKNOWN_RGB",
           "ConfigError",
           "ForagingConfig", "ForagingEnv", "ForagingState", "Rewards", "Task", "color_rgb", "colors_for_tasks", "outputs_to_wheels",
           "task_by_name", "task_rgb"]

from .gym_env import ENV_ID, SwarmForagingEnv, SwarmForagingVectorEnv, register_envs
from .pettingzoo_env import ForagingParallelEnv, parallel_env

__all__ += ["ENV_ID", "ForagingParallelEnv", "SwarmForagingEnv", "SwarmForagingVectorEnv", "parallel_env",
            "register_envs"]
register_envs()  # gymnasium.make("lifelong_evo/SwarmForaging-v0") after `import envs`
