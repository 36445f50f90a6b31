"""The evaluator's threads: each plays its own shard of the population, as that shard alone would."""
import pytest
import torch

from algorithms.mlp import MLPPolicy, layer_sizes_for, n_parameters
from envs import TASKS, ForagingConfig, ForagingEnv
from lifelong_evo.evaluate import (BesideReference, Evaluation, evaluate, evaluate_together, rollout, sample_episodes,
                                   shard_bounds)

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


class _Seen:
    """A policy that keeps the observations it is given, step by step."""

    def __init__(self, policy):
        self.policy, self.population_size, self.seen = policy, policy.population_size, []

    def __call__(self, observations):
        self.seen.append(observations.clone())
        return self.policy(observations)


def _mean_difference(policy, reference, seen, episodes, lengths):
    """Per controller of ``policy``: the mean, over the first ``episodes`` episodes, the steps
    ``seen`` that each episode was still going (its first ``lengths[controller, episode]``) and
    the agents, of sum_k |output_k - reference output_k|, the reference run on the same rows."""
    total = 0
    for step, observations in enumerate(seen):
        population, n_episodes, agents, width = observations.shape
        mine = policy(observations)
        theirs = reference(observations.reshape(1, population * n_episodes, agents, width)).view(mine.shape)
        going = step < lengths
        total = total + ((mine - theirs).abs().sum(dim=(2, 3)).double() * going)[:, :episodes].sum(dim=1)
    return total / (lengths[:, :episodes].sum(dim=1) * agents)


def _every_step(seen, population, episodes):
    """Episode lengths for ``_mean_difference`` where every step ``seen`` counts."""
    return torch.full((population, episodes), len(seen))


def test_functional_penalty_is_on_the_observations_each_controller_saw():
    """BesideReference plays the population unchanged and, per controller, averages over its own
    training episodes (the first ones), steps and agents the summed absolute output difference to
    the reference on the observations that controller saw, not on the reference's own episodes;
    the same bits in any evaluation thread."""
    sizes = layer_sizes_for(DENSE.obs_dim)
    generator = torch.Generator().manual_seed(7)
    population = MLPPolicy(torch.randn(5, n_parameters(sizes), generator=generator) * 3, sizes)
    reference = MLPPolicy(torch.randn(1, n_parameters(sizes), generator=generator) * 3, sizes)
    tasks, training = [TASKS["red"], TASKS["green"]], 3  # 3 training episodes (red), then 3 scored on green

    def play(policy, threads=1):
        return evaluate(policy, DENSE, tasks, training, torch.Generator().manual_seed(5), eval_threads=threads)

    beside = BesideReference(population, reference)
    seen = _Seen(population)
    plain = play(seen)
    assert torch.equal(play(beside), plain), "the reference beside changes nothing the population does"
    got = beside.penalty(training)
    # DENSE's episodes run their 120 steps (none reaches max_retrieves): every step seen is live
    lengths = _every_step(seen.seen, 5, 2 * training)
    expected = _mean_difference(population, reference, seen.seen, training, lengths)
    assert torch.allclose(got, expected, atol=1e-6, rtol=0)
    assert len(set(got.tolist())) == 5
    # what the test tells apart: the reference's own episodes, and every episode played
    alone = _Seen(reference)
    evaluate(alone, DENSE, tasks, training, torch.Generator().manual_seed(5))
    on_its_own = _mean_difference(population, reference, [o.expand(5, *o.shape[1:]) for o in alone.seen], training,
                                  lengths)
    assert not torch.allclose(got, on_its_own, atol=1e-3, rtol=0)
    assert not torch.allclose(got, _mean_difference(population, reference, seen.seen, 2 * training, lengths), atol=1e-3)
    for threads in (2, 3):
        sharded = BesideReference(population, reference)
        assert torch.equal(play(sharded, threads), plain)
        assert torch.equal(sharded.penalty(training), got), threads


EARLY = ForagingConfig(duration=120, max_wheel_velocity=20.0, n_boxes=12, size=14.0, max_retrieves=1, rate_target=1.0)
"""DENSE with every box of the target colour and one delivery ending an episode: random
controllers end some of their episodes early, a few all of them."""


def _early_scene(rows):
    """Controllers ``rows`` of 256 random ones, and a reference. On ``_early_evaluation``'s
    episodes rows 6, 20, 28 and 59 end some early (28 and 59 all four, by step 66), row 0 one (at
    step 113), row 3 none."""
    sizes = layer_sizes_for(EARLY.obs_dim)
    generator = torch.Generator().manual_seed(7)
    weights = torch.randn(256, n_parameters(sizes), generator=generator) * 3
    reference = MLPPolicy(torch.randn(1, n_parameters(sizes), generator=generator) * 3, sizes)
    return MLPPolicy(weights[rows], sizes), reference


_EARLY_TASKS = [TASKS["red"], TASKS["green"]]


def _early_evaluation(policy, threads=1):
    """2 episodes of red, then 2 of green, as a generation under rehearsal trains on."""
    return Evaluation(policy, EARLY, _EARLY_TASKS, 2, torch.Generator().manual_seed(5), eval_threads=threads)


def _replayed(policy):
    """``_early_evaluation``'s play, by hand: the observations of every step the rollout hands the
    policy, and each episode's length, ``(population, episodes)``, by the environment's own count
    of the steps it was going."""
    episodes = sample_episodes(EARLY, _EARLY_TASKS, 2, torch.Generator().manual_seed(5))
    seen = _Seen(policy)
    env = ForagingEnv(EARLY, batch_size=policy.population_size * 4)
    rollout(seen, env, env.reset(state=episodes.index(torch.arange(4).repeat(policy.population_size))))
    return seen.seen, env.state.steps.view(policy.population_size, 4)


def test_functional_penalty_counts_only_the_steps_an_episode_is_going():
    """An episode that reaches max_retrieves ends, but the rollout goes on calling the policy on
    its frozen last observation while other episodes go on: those calls must not count. Each
    controller's penalty is its summed difference over the live agent-steps of its training
    episodes (several, of two tasks) divided by its own count of them."""
    population, reference = _early_scene([59, 6, 20, 3])
    seen, lengths = _replayed(population)
    assert len(seen) == EARLY.duration and (lengths < EARLY.duration).sum() >= 4, "episodes must end early"
    assert (lengths[3] == EARLY.duration).all(), "and one controller's never do"
    beside = BesideReference(population, reference)
    _early_evaluation(beside).run()
    for training in (2, 4):  # red's episodes only, as a plain generation; red's and green's, as under rehearsal
        got = beside.penalty(training)
        assert torch.allclose(got, _mean_difference(population, reference, seen, training, lengths), atol=1e-6, rtol=0)
        counting_ended = _mean_difference(population, reference, seen, training, _every_step(seen, 4, 4))
        assert not torch.allclose(got[:3], counting_ended[:3], atol=1e-3, rtol=0), training


def test_functional_penalty_is_the_same_whatever_stops_the_rollout():
    """The rollout stops when every episode of its batch has ended (checked every 25 steps): a
    shard (evaluation thread) whose controllers all end early stops before the other, and a run
    played with another whose episodes go on stops later than alone. The penalty is the same bits
    in 1 and 2 evaluation threads, alone and together."""
    population, reference = _early_scene([59, 28, 3, 0])
    _, lengths = _replayed(population)
    assert lengths[:2].max() < 75 and lengths[2:].max() == EARLY.duration, "the shards must stop apart"
    one, two = BesideReference(population, reference), BesideReference(population, reference)
    _early_evaluation(one).run()  # one rollout, to step 120
    _early_evaluation(two, threads=2).run()  # the first shard's stops at step 75, the second's at 120
    assert torch.equal(two.penalty(4), one.penalty(4))
    early, going_on = _early_scene([59, 28])[0], _early_scene([3, 0])[0]
    alone = BesideReference(early, reference)
    _early_evaluation(alone).run()  # its rollout stops at step 75
    together = BesideReference(early, reference)
    # the batch plays to step 120; the other run's environments first, so that ``together``'s lie further in
    evaluate_together([_early_evaluation(going_on), _early_evaluation(together)])
    assert torch.equal(together.penalty(4), alone.penalty(4))
    assert torch.equal(alone.penalty(4), one.penalty(4)[:2])
