"""What the lifelong loop tells a recorder; the Rerun recorder lives in ``rerun_recorder``."""
from __future__ import annotations

from envs import Task

from .episodes import Episode
from .metrics import GenerationRecord
from .networks import NetworkView


class Recorder:
    """Receives the run as it happens. The base class records nothing."""

    wants_episodes: bool = False
    """Whether the loop should play and pass top-individual episodes, and networks, at task ends."""

    def log_generation(self, record: GenerationRecord) -> None:
        """What the generation measured (the metrics.csv row, and every scalar the optimiser reported)."""

    def log_drift(self, generation: int, previous: str, task: str) -> None:
        """The task changes before ``generation``."""

    def log_episode(self, generation: int, phase_index: int, phase_task: str, task: Task, episode: Episode) -> None:
        """An episode of phase ``phase_index``'s top individual on ``task``."""

    def log_network(self, generation: int, view: NetworkView) -> None:
        """The top individual's network at the task end in ``generation``, against its reference."""

    def close(self) -> None:
        """Flush and finish."""

