"""The evaluator's threads: each plays its own shard of the population, as that shard alone would."""
import pytest
import torch

from algorithms.mlp import MLPPolicy, layer_sizes_for, n_parameters
from envs import TASKS, ForagingConfig
from lifelong_evo.evaluate import evaluate, shard_bounds

DENSE = ForagingConfig(duration=120, max_wheel_velocity=20.0, n_boxes=12, size=14.0)
"""A small crowded arena with fast robots: random controllers pick, drop and score within 120 steps."""


def _fitness(policy, threads):
    return evaluate(policy, DENSE, [TASKS["red"], TASKS["green"]], 4, torch.Generator().manual_seed(5),
                    eval_threads=threads)


def test_eval_threads_play_each_shard_as_its_own_population():
    sizes = layer_sizes_for(DENSE.obs_dim)
    policy = MLPPolicy(torch.randn(5, n_parameters(sizes), generator=torch.Generator().manual_seed(3)) * 3, sizes)
    alone = _fitness(policy, 1)
    assert alone.shape == (2, 5)
    assert len(set(alone.flatten().tolist())) >= 4, "controllers must score differently for the test to bite"
    for threads in (2, 3, 8):  # even and uneven shards, and more threads than controllers
        together = _fitness(policy, threads)
        shards = [_fitness(policy.shard(start, stop), 1) for start, stop in shard_bounds(5, threads)]
        assert torch.equal(together, torch.cat(shards, dim=1)), threads
        assert torch.equal(_fitness(policy, threads), together), "same threads, same numbers"


@pytest.mark.parametrize("population, threads", [(10, 1), (10, 2), (301, 2), (5, 3), (3, 8)])
def test_shard_bounds_cover_the_population_evenly(population, threads):
    bounds = shard_bounds(population, threads)
    assert len(bounds) == min(population, threads)
    assert bounds[0][0] == 0 and bounds[-1][1] == population
    assert all(stop == start for (_, stop), (start, _) in zip(bounds, bounds[1:]))
    sizes = {stop - start for start, stop in bounds}
    assert max(sizes) - min(sizes) <= 1 and min(sizes) >= 1


def test_a_policy_without_shard_is_played_in_one_thread():
    sizes = layer_sizes_for(DENSE.obs_dim)
    mlp = MLPPolicy(torch.randn(4, n_parameters(sizes), generator=torch.Generator().manual_seed(3)) * 3, sizes)

    class Unsharded:
        population_size = mlp.population_size

        def __call__(self, observations):
            return mlp(observations)

    alone = _fitness(Unsharded(), 1)
    assert alone.abs().sum() > 0, "the controllers must score for the test to bite"
    assert torch.equal(_fitness(Unsharded(), 2), alone)


def test_a_reset_from_a_state_leaves_that_state_as_given():
    """The arena shares tensors with the state it is made from (``Arena.from_state``): a step must
    never write into them, or the caller's episodes (a fixed held-out set, say) change under it."""
    from dataclasses import fields

    from envs import ForagingEnv

    env = ForagingEnv(DENSE, batch_size=4)
    state = env.sample_state(TASKS["red"], torch.Generator().manual_seed(2))
    given = {f.name: getattr(state, f.name).clone() for f in fields(state)}
    env.reset(state=state)
    wheels = torch.ones(4, DENSE.n_agents, 3)
    for _ in range(DENSE.duration):
        env.step(wheels)
    assert int(env.state.steps.min()) > 0, "the episodes must have run for the test to bite"
    for name, value in given.items():
        assert torch.equal(getattr(state, name), value), name
