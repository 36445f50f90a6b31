"""The batched swarm-foraging environment and its Gymnasium / PettingZoo adapters."""
from .config import COLOR_IDS, COLOR_NAMES, TASKS, ConfigError, ForagingConfig, Task, colors_for_tasks, task_by_name
from .foraging import ForagingEnv, ForagingState, outputs_to_wheels

__all__ = ["COLOR_IDS", "COLOR_NAMES", "TASKS", "ConfigError", "ForagingConfig", "ForagingEnv", "ForagingState",
           "Task", "colors_for_tasks", "outputs_to_wheels", "task_by_name"]
