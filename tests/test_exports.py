"""Every optimiser's exported controller (JSON) computes what it computed in the population."""
from __future__ import annotations

import json

import pytest
import torch

from algorithms import REGISTRY, make_optimizer, policy_from_export


@pytest.mark.parametrize("name", sorted(REGISTRY))
def test_export_round_trip(name):
    optimizer = make_optimizer(name, obs_dim=41, population_size=12, seed=3)
    observations = torch.rand(optimizer.population_size, 2, 5, 41, generator=torch.Generator().manual_seed(0))
    for _ in range(3):  # also after some evolution
        policy = optimizer.ask()
        outputs = policy(observations)
        for index in (0, optimizer.population_size - 1):
            exported = json.loads(json.dumps(optimizer.export(index)))  # through real JSON
            single = policy_from_export(exported)
            assert single.population_size == 1
            torch.testing.assert_close(single(observations[index:index + 1]), outputs[index:index + 1],
                                       atol=1e-6, rtol=0)
        fitness = torch.randn(optimizer.population_size, generator=torch.Generator().manual_seed(1))
        optimizer.tell(fitness, fitness)


def test_unknown_export_is_refused():
    with pytest.raises(ValueError, match="not an exported controller"):
        policy_from_export({"weights": [1, 2]})
