"""The state of a batch of foraging arenas, in its two layouts.

``ForagingState`` is the public form: batch first, the only form code outside ``envs/`` should rely
on (``ForagingEnv.state`` returns one, ``ForagingEnv.reset(state=...)`` takes one). ``Arena`` is the
working form the step computes on: batch last (``(agents, B)``, ``(boxes, B)``), because the step's
reductions over boxes then vectorise across environments. Converting one into the other and back
gives the same values.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields

import torch


@dataclass
class ForagingState:
    """The full state of a batch; every field has the batch as its first dimension."""

    agent_pos: torch.Tensor
    """(B, A, 2) float: agent (x, y)."""
    heading: torch.Tensor
    """(B, A) float: heading in degrees, [0, 360)."""
    carrying: torch.Tensor
    """(B, A) long: index of the carried box, -1 for none."""
    box_pos: torch.Tensor
    """(B, K, 2) float: box cell (meaningless while carried or gone)."""
    box_color: torch.Tensor
    """(B, K) long: colour id of each box."""
    box_present: torch.Tensor
    """(B, K) bool: the box lies in the arena (not carried, not gone)."""
    target: torch.Tensor
    """(B,) long: target colour id."""
    season: torch.Tensor
    """(B, n_colors) bool: colours the season may draw (index = colour - 3)."""
    drop_zone: torch.Tensor
    """(B,) long: the nest's edge, an index into ``envs.DROP_ZONES`` (0 top, 1 bottom, 2 left, 3 right)."""
    rewards: torch.Tensor
    """(B, 4) float: the reward of picking a target box, picking another, delivering a target box,
    delivering another (``envs.Rewards.values``)."""
    failed_robots: torch.Tensor
    """(B,) long: how many robots, the highest-index ones, do nothing."""
    motor_gain: torch.Tensor
    """(B,) float: the factor on every wheel speed."""
    steps: torch.Tensor
    """(B,) long: steps taken in this episode."""
    retrieved: torch.Tensor
    """(B,) long: correct retrievals in this episode."""
    done: torch.Tensor
    """(B,) bool: the episode has ended (max retrievals or duration)."""
    respawn_key: torch.Tensor
    """(B,) long: key of the counter-based stream that places respawned boxes."""

    def clone(self) -> ForagingState:
        return ForagingState(**{f.name: getattr(self, f.name).clone() for f in fields(self)})

    def index(self, which) -> ForagingState:
        """The sub-batch ``which`` (an index, slice, list or mask) of every field."""
        return ForagingState(**{f.name: getattr(self, f.name)[which] for f in fields(self)})

    def to(self, device) -> ForagingState:
        return ForagingState(**{f.name: getattr(self, f.name).to(device) for f in fields(self)})

    @staticmethod
    def cat(states: Sequence[ForagingState]) -> ForagingState:
        return ForagingState(**{f.name: torch.cat([getattr(s, f.name) for s in states])
                                for f in fields(ForagingState)})


_BATCH_LAST = {"ax", "ay", "heading", "carrying", "bx", "by", "color", "present"}
"""The ``Arena`` fields whose batch dimension is the last one (the others have only the batch's)."""


@dataclass
class Arena:
    """The working state, batch-last; see ``ForagingState`` for the meaning of each field.
    Box and colour ids are int32 here: compiled CPU code handles them in half the vector
    width of int64 (and indexing accepts them). ``present`` is int32 0/1, not bool, because
    compiled CPU code loads and stores bool vectors element by element."""

    ax: torch.Tensor          # (A, B) agent x
    ay: torch.Tensor          # (A, B) agent y
    heading: torch.Tensor     # (A, B)
    carrying: torch.Tensor    # (A, B) int32, -1 for none
    bx: torch.Tensor          # (K, B) box x
    by: torch.Tensor          # (K, B) box y
    color: torch.Tensor       # (K, B) int32
    present: torch.Tensor     # (K, B) int32 0/1
    target: torch.Tensor      # (B,) int32
    season: torch.Tensor      # (B, n_colors)
    drop_zone: torch.Tensor   # (B,) int32
    rewards: torch.Tensor     # (B, 4)
    failed_robots: torch.Tensor  # (B,) int32
    motor_gain: torch.Tensor  # (B,)
    steps: torch.Tensor       # (B,)
    retrieved: torch.Tensor   # (B,)
    done: torch.Tensor        # (B,)
    respawn_key: torch.Tensor  # (B,)

    @staticmethod
    def from_state(s: ForagingState) -> Arena:
        """The working form of ``s``; it shares the tensors that need no conversion with ``s``."""
        return Arena(
            ax=s.agent_pos[..., 0].T.contiguous(), ay=s.agent_pos[..., 1].T.contiguous(),
            heading=s.heading.T.contiguous(), carrying=s.carrying.T.to(torch.int32).contiguous(),
            bx=s.box_pos[..., 0].T.contiguous(), by=s.box_pos[..., 1].T.contiguous(),
            color=s.box_color.T.to(torch.int32).contiguous(), present=s.box_present.T.to(torch.int32).contiguous(),
            target=s.target.to(torch.int32), season=s.season, drop_zone=s.drop_zone.to(torch.int32),
            rewards=s.rewards, failed_robots=s.failed_robots.to(torch.int32), motor_gain=s.motor_gain,
            steps=s.steps, retrieved=s.retrieved, done=s.done, respawn_key=s.respawn_key)

    def clone(self) -> Arena:
        return Arena(**{f.name: getattr(self, f.name).clone() for f in fields(self)})

    def copy_(self, other: Arena) -> None:
        """Overwrite every field in place with ``other``'s (the buffers a CUDA graph reads)."""
        for f in fields(self):
            getattr(self, f.name).copy_(getattr(other, f.name))

    def replace_environments_(self, which: torch.Tensor, new: Arena) -> None:
        """Overwrite environments ``which`` (indices) in place with the environments of ``new``."""
        for f in fields(self):
            getattr(self, f.name).index_copy_(1 if f.name in _BATCH_LAST else 0, which, getattr(new, f.name))

    def to_state(self) -> ForagingState:
        return ForagingState(
            agent_pos=torch.stack((self.ax.T, self.ay.T), -1), heading=self.heading.T.clone(),
            carrying=self.carrying.T.long(), box_pos=torch.stack((self.bx.T, self.by.T), -1),
            box_color=self.color.T.long(), box_present=self.present.T.bool(),
            target=self.target.long(), season=self.season.clone(), drop_zone=self.drop_zone.long(),
            rewards=self.rewards.clone(), failed_robots=self.failed_robots.long(),
            motor_gain=self.motor_gain.clone(), steps=self.steps.clone(),
            retrieved=self.retrieved.clone(), done=self.done.clone(), respawn_key=self.respawn_key.clone())
