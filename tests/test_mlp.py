"""The batched MLP controller against plain per-controller torch.nn networks."""
import pytest
import torch
from torch import nn

from algorithms.mlp import MLPPolicy, layer_sizes_for, n_parameters, unflatten


def reference_nets(layer_sizes, population, seed=0):
    """Per-controller ``nn.Sequential`` networks and their flat vectors in the documented layout."""
    torch.manual_seed(seed)
    nets, flats = [], []
    for _ in range(population):
        layers = []
        for i, (n_in, n_out) in enumerate(zip(layer_sizes[:-1], layer_sizes[1:])):
            layers.append(nn.Linear(n_in, n_out))
            layers.append(nn.Sigmoid() if i == len(layer_sizes) - 2 else nn.Tanh())
        net = nn.Sequential(*layers)
        with torch.no_grad():  # spread the weights so that the nonlinearities matter
            for p in net.parameters():
                p.mul_(3.0)
        nets.append(net)
        flats.append(torch.cat([t.detach().reshape(-1) for lin in net if isinstance(lin, nn.Linear)
                                for t in (lin.weight, lin.bias)]))
    return nets, torch.stack(flats)


def test_parameter_counts():
    assert n_parameters((41, 16, 3)) == 41 * 16 + 16 + 16 * 3 + 3 == 723
    assert n_parameters(layer_sizes_for(61)) == 61 * 16 + 16 + 16 * 3 + 3
    assert n_parameters((5, 4, 2, 3)) == 5 * 4 + 4 + 4 * 2 + 2 + 2 * 3 + 3
    with pytest.raises(ValueError):
        layer_sizes_for(41, (0,))


@pytest.mark.parametrize("layer_sizes", [(41, 16, 3), (7, 5, 4, 3), (6, 3)])
def test_matches_per_controller_torch_nn(layer_sizes):
    population, envs, agents = 4, 3, 2
    nets, flat = reference_nets(layer_sizes, population)
    assert flat.shape == (population, n_parameters(layer_sizes))
    obs = torch.rand(population, envs, agents, layer_sizes[0]) * 2 - 1  # observations lie in [-1, 1]
    out = MLPPolicy(flat, layer_sizes)(obs)
    assert out.shape == (population, envs, agents, 3)
    for p, net in enumerate(nets):
        with torch.no_grad():
            expected = net(obs[p])
        # the weights and inputs on envs.numerics' grid (steps of 2**-20) move outputs by ~1e-6
        torch.testing.assert_close(out[p], expected, rtol=0, atol=1e-5)
    assert float(out.min()) >= 0.0 and float(out.max()) <= 1.0
    # the outputs really depend on the controller (not one network broadcast)
    assert not torch.allclose(out[0], MLPPolicy(flat[1:2].expand(population, -1), layer_sizes)(obs)[0])


def test_unflatten_layout():
    sizes = (3, 2, 3)
    flat = torch.arange(float(n_parameters(sizes))).unsqueeze(0)
    (w1, b1), (w2, b2) = unflatten(flat, sizes)
    assert w1[0].tolist() == [[0, 1, 2], [3, 4, 5]]
    assert b1[0].tolist() == [6, 7]
    assert w2[0].tolist() == [[8, 9], [10, 11], [12, 13]]
    assert b2[0].tolist() == [14, 15, 16]


def test_shape_errors():
    policy = MLPPolicy(torch.zeros(2, n_parameters((5, 4, 3))), (5, 4, 3))
    with pytest.raises(ValueError):
        policy(torch.zeros(3, 1, 1, 5))  # wrong population
    with pytest.raises(ValueError):
        policy(torch.zeros(2, 1, 1, 6))  # wrong obs_dim
    with pytest.raises(ValueError):
        MLPPolicy(torch.zeros(2, 10), (5, 4, 3))  # wrong parameter count


def test_shard_gives_the_populations_outputs():
    sizes = (41, 16, 3)
    _, flat = reference_nets(sizes, 5, seed=2)
    policy = MLPPolicy(flat, sizes)
    obs = torch.rand(5, 3, 2, 41)
    together = policy(obs)
    for start, stop in ((0, 2), (2, 5), (4, 5)):
        shard = policy.shard(start, stop)
        assert shard.population_size == stop - start
        # vectorised activations round their last few elements apart, so not bit for bit
        torch.testing.assert_close(shard(obs[start:stop]), together[start:stop], rtol=0, atol=1e-6)


def test_from_export_matches_population_row():
    sizes = (6, 4, 3)
    _, flat = reference_nets(sizes, 3, seed=1)
    obs = torch.rand(3, 2, 2, 6)
    out = MLPPolicy(flat, sizes)(obs)
    single = MLPPolicy.from_export({"layer_sizes": list(sizes), "parameters": flat[2].tolist()})
    torch.testing.assert_close(single(obs[2:3])[0], out[2])
