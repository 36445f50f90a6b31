"""The step the speed goals were set with: ``python benchmarks/reference_step.py [--envs N ...]``
times it as ``python -m lifelong_evo.bench`` times the environment (the same options but
``--algo``; the last line is ``s_per_generation=<seconds>``).

The speed goals came with figures measured on a prototype step: batch-last tensors,
``torch.topk`` over the sensed candidates, one-hots by ``one_hot`` (the goals and figures:
docs/performance.md). ``ReferenceStep`` is that plain formulation, so that a machine can be
compared with the one those figures came from.
It is *not* the paper's environment, which is why it lives outside the installed packages: two
agents may pick the same box, respawns are drawn from a ``torch.Generator`` (x and y from one
range), tied candidates are sensed in ``topk``'s order, not the spec's index order, and it keeps
no reward. It senses what the environment senses otherwise (tests/test_bench.py) and does about
the same work per step, which is all a benchmark needs. Use ``envs.ForagingEnv`` for anything else.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

from envs import ForagingConfig, Task
from envs.foraging import BOX_LOW, KINEMATICS, WHEEL_RADIUS_FACTOR

_FAR = 1e9
"""Distance given to candidates that are not sensed, so that ``topk`` puts them last."""


class ReferenceStep:
    """``reset``/``step`` over ``batch_size`` arenas, shaped like ``ForagingEnv``'s."""

    def __init__(self, config: ForagingConfig, batch_size: int, device: str | torch.device = "cpu"):
        self.config, self.batch_size, self.device = config, batch_size, torch.device(device)
        self._kinematics_t = torch.tensor(KINEMATICS, device=self.device).T.contiguous()
        self._slot_offsets = (torch.arange(config.n_neighbors, device=self.device) * config.n_types)[:, None, None]
        self._wall_sin = torch.tensor([0.0, 0.0, 1.0, -1.0], device=self.device)  # top, bottom, left, right
        self._wall_cos = torch.tensor([1.0, -1.0, 0.0, 0.0], device=self.device)

    def compile(self) -> None:
        self._advance = torch.compile(self._advance, dynamic=False)

    def reset(self, task: Task, generator: torch.Generator) -> torch.Tensor:
        c, B, dev = self.config, self.batch_size, self.device
        self.generator = generator
        self.ax = (2 + torch.rand(c.n_agents, B, generator=generator) * 2 - 1).to(dev)
        self.ay = (torch.arange(1, c.n_agents + 1)[:, None] * c.size / (c.n_agents + 1)).repeat(1, B).to(dev)
        self.heading = torch.full((c.n_agents, B), 180.0, device=dev)
        self.carrying = torch.full((c.n_agents, B), -1, device=dev)
        self.bx, self.by = (self._cells((c.n_boxes, B)) for _ in range(2))
        self.color = torch.randint(3, 3 + c.n_colors, (c.n_boxes, B), generator=generator).to(dev)
        self.present = torch.ones(c.n_boxes, B, dtype=torch.bool, device=dev)
        self.target = torch.full((B,), task.target, device=dev)
        self._no_reward = torch.zeros(B, device=dev)
        self._not_done = torch.zeros(B, dtype=torch.bool, device=dev)
        return self.observe()

    def step(self, wheels: torch.Tensor):
        """``ForagingEnv.step``'s return, with no reward and no episode end."""
        respawn_x, respawn_y = self._cells(self.carrying.shape), self._cells(self.carrying.shape)
        (observations, self.ax, self.ay, self.heading, self.carrying, self.bx, self.by,
         self.present) = self._advance(wheels, respawn_x, respawn_y, self.ax, self.ay, self.heading,
                                       self.carrying, self.bx, self.by, self.present)
        return observations, self._no_reward, self._not_done, {}

    def _cells(self, shape) -> torch.Tensor:
        high = int(self.config.size) - 1
        return torch.randint(BOX_LOW[0], high, shape, generator=self.generator).float().to(self.device)

    def _advance(self, wheels, respawn_x, respawn_y, ax, ay, heading, carrying, bx, by, present):
        c = self.config
        velocity = (wheels @ self._kinematics_t).permute(2, 1, 0)                          # (3, A, B)
        ax = (ax + velocity[0] * c.time_step).clamp(0.0, c.size)
        ay = (ay + velocity[1] * c.time_step).clamp(0.0, c.size)
        heading = torch.remainder(heading + torch.rad2deg(velocity[2] * c.time_step / WHEEL_RADIUS_FACTOR), 360.0)
        dist = torch.sqrt((ax[None] - bx[:, None]) ** 2 + (ay[None] - by[:, None]) ** 2)  # (K, A, B)
        nearest_dist, nearest = torch.where(present[:, None], dist, _FAR).min(dim=0)
        picks = (carrying < 0) & (nearest_dist < c.sensitivity)
        carrying = torch.where(picks, nearest, carrying)
        present = present & ~F.one_hot(torch.where(picks, nearest, c.n_boxes), c.n_boxes + 1)[..., :-1].any(0).T
        drops = (carrying >= 0) & (ax < 1)
        dropped = F.one_hot(torch.where(drops, carrying, c.n_boxes), c.n_boxes + 1)[..., :-1].permute(2, 0, 1)
        respawned = dropped.any(1)                                                           # (K, B)
        bx = torch.where(respawned, (dropped * respawn_x).sum(1), bx)
        by = torch.where(respawned, (dropped * respawn_y).sum(1), by)
        carrying = torch.where(drops, -1, carrying)
        observations = self._observe_arena(ax, ay, heading, carrying, bx, by, present)  # dropped: unseen yet
        return observations, ax, ay, heading, carrying, bx, by, present | respawned

    def observe(self) -> torch.Tensor:
        return self._observe_arena(self.ax, self.ay, self.heading, self.carrying, self.bx, self.by, self.present)

    def _observe_arena(self, ax, ay, heading, carrying, bx, by, present):
        c = self.config
        A, B = ax.shape
        walls = torch.stack((ax, c.size - ax - 1, ay, c.size - ay - 1))
        dx, dy = ax[None] - bx[:, None], ay[None] - by[:, None]
        dist = torch.sqrt(dx ** 2 + dy ** 2)
        candidates = torch.cat((torch.where(walls < c.sensor_range, walls, _FAR),
                                torch.where(present[:, None] & (dist <= c.sensor_range), dist, _FAR)))
        slot_dist, slot = candidates.topk(c.n_neighbors, dim=0, largest=False)             # (n, A, B)
        seen = slot_dist < _FAR
        is_wall = slot < 4
        box = (slot - 4).clamp(min=0)
        kind = torch.where(is_wall, 1, self.color.gather(0, box.view(-1, B)).view(slot.shape)) * seen
        safe = torch.where(seen, slot_dist, 1.0).clamp(min=1e-6)
        box_sin = dy.view(-1, A * B).gather(0, box.view(-1, A * B)).view(slot.shape) / safe
        box_cos = dx.view(-1, A * B).gather(0, box.view(-1, A * B)).view(slot.shape) / safe
        wall = slot.clamp(max=3)
        sin = torch.where(is_wall, self._wall_sin[wall], box_sin) * seen
        cos = torch.where(is_wall, self._wall_cos[wall], box_cos) * seen
        carried = torch.where(carrying >= 0, self.color.gather(0, carrying.clamp(min=0)) - 2, 0)
        features = torch.cat((
            F.one_hot(kind + self._slot_offsets, c.n_neighbors * c.n_types).sum(0).permute(2, 0, 1),
            slot_dist * seen / c.sensor_range, sin, cos,
            torch.sin(torch.deg2rad(heading))[None], torch.cos(torch.deg2rad(heading))[None],
            F.one_hot(carried, c.n_colors + 1).permute(2, 0, 1),
            F.one_hot(self.target - 3, c.n_colors).T[:, None].expand(-1, A, -1),
        ))
        return features.float().permute(2, 1, 0).contiguous()                             # (B, A, obs_dim)


if __name__ == "__main__":
    from lifelong_evo.commands.bench import main

    main(env_class=ReferenceStep)
