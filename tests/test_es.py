"""Evolution strategies behind ask/tell, and the shared regulariser (synthetic objectives only)."""
import io
import math

import pytest
import torch
from evotorch.algorithms import CMAES as EvoCMAES

from algorithms import REGISTRY, ESOptimizer
from algorithms.mlp import MLPPolicy
from algorithms.regularizers import FISHER_WINDOW, Regularizer, gaussian_sensitivity, penalty, regularised_fitness

ES_ALGORITHMS = {name: cls for name, cls in REGISTRY.items() if issubclass(cls, ESOptimizer)}
ALGOS = sorted(ES_ALGORITHMS)
SMALL = {"obs_dim": 6, "hidden": (8,), "population_size": 20}

# a fixed observation batch and target outputs: maximise -mean (output - target)^2
_g = torch.Generator().manual_seed(123)
OBS = torch.rand(1, 4, 2, 6, generator=_g)
TARGET_A = 0.1 + 0.8 * torch.rand(1, 4, 2, 3, generator=_g)
TARGET_B = 0.1 + 0.8 * torch.rand(1, 4, 2, 3, generator=_g)


def output_fitness(policy, target=TARGET_A):
    out = policy(OBS.expand(policy.population_size, -1, -1, -1))
    return -((out - target) ** 2).mean(dim=(1, 2, 3))


def make(name, **kw):
    return ES_ALGORITHMS[name](**{**SMALL, "seed": 0, **kw})


def generation(opt, target=TARGET_A):
    policy = opt.ask()
    fitness = output_fitness(policy, target)
    selection = opt.regularise(fitness)
    opt.tell(fitness, selection)
    return policy.params.clone(), selection


# ---- the adapter ------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ALGOS)
def test_population_is_samples_plus_centre(name):
    opt = make(name)
    assert opt.population_size == 21 and opt.centre_index == 20
    centre = opt.centre.clone()
    policy = opt.ask()
    assert policy.population_size == 21 and policy.params.shape == (21, opt.n_parameters)
    assert policy.params.dtype == torch.float32
    torch.testing.assert_close(policy.params[opt.centre_index], centre, rtol=0, atol=0)
    assert opt.ask().params.equal(policy.params)  # asking again before tell: same population
    assert not policy.params[0].equal(policy.params[1])
    exported = opt.export(opt.centre_index)
    assert exported["layer_sizes"] == [6, 8, 3]
    assert len(exported["parameters"]) == opt.n_parameters
    assert torch.tensor(exported["parameters"]).equal(centre)
    obs = OBS.expand(21, -1, -1, -1)
    torch.testing.assert_close(MLPPolicy.from_export(opt.export(3))(obs[:1])[0], policy(obs)[3])


@pytest.mark.parametrize("name", ALGOS)
def test_improves_synthetic_objective(name):
    opt = make(name)
    start = None
    for _ in range(30):  # at 20 generations SNES's draw at seed 0 falls by 2% only
        _, selection = generation(opt)
        start = float(selection[opt.centre_index]) if start is None else start
    end = float(output_fitness(MLPPolicy(opt.centre.unsqueeze(0), opt.layer_sizes)))
    assert start < 0 and end > 0.9 * start, (start, end)  # the centre's loss fell by > 10%


@pytest.mark.parametrize("name", ALGOS)
def test_same_seed_same_numbers(name):
    runs = []
    for seed in (0, 0, 1):
        opt = make(name, seed=seed)
        runs.append(torch.stack([generation(opt)[0] for _ in range(3)]))
    assert runs[0].equal(runs[1])
    assert not runs[0][0].equal(runs[2][0])


@pytest.mark.parametrize("name", ALGOS)
@pytest.mark.parametrize("pending", [False, True], ids=["after-tell", "between-ask-and-tell"])
def test_checkpoint_continues_bit_for_bit(name, pending):
    kw = {"reg": 0.5, "importance": "ewc", "reference": "best"}
    a = make(name, **kw)
    for g in range(4):
        generation(a)
        if g == 1:
            a.end_task()
    if pending:
        a.ask()
    buffer = io.BytesIO()
    torch.save(a.state_dict(), buffer)
    buffer.seek(0)
    state = torch.load(buffer, weights_only=True)  # tensors and plain values only
    b = make(name, **kw)
    b.load_state_dict(state)
    assert b.generation == a.generation == 4
    for _ in range(3):
        pa, sa = generation(a, TARGET_B)
        pb, sb = generation(b, TARGET_B)
        assert pa.equal(pb) and sa.equal(sb)
    a.end_task()
    b.end_task()
    assert a.regularizer.reference.equal(b.regularizer.reference)
    assert a.regularizer.importance.equal(b.regularizer.importance)
    assert a.state_dict()["rng_state"].equal(b.state_dict()["rng_state"])


def test_checkpoint_of_another_algorithm_is_refused():
    state = make("snes").state_dict()
    with pytest.raises(ValueError, match="algorithm"):
        make("pgpe").load_state_dict(state)
    with pytest.raises(ValueError, match="layer_sizes"):
        make("snes", hidden=(4,)).load_state_dict(state)


@pytest.mark.parametrize("name", ALGOS)
def test_tell_checks(name):
    opt = make(name)
    with pytest.raises(RuntimeError):
        opt.tell(torch.zeros(21), torch.zeros(21))  # no ask yet
    opt.ask()
    with pytest.raises(ValueError):
        opt.tell(torch.zeros(20), torch.zeros(20))
    bad = torch.zeros(21)
    bad[3] = float("nan")
    with pytest.raises(ValueError):
        opt.tell(torch.zeros(21), bad)


@pytest.mark.parametrize("name", ["openai-es", "pgpe"])
def test_mirrored_sampling_needs_even_samples(name):
    with pytest.raises(ValueError, match="even"):
        make(name, population_size=21)
    params = make(name).ask().params
    centre = params[-1]
    torch.testing.assert_close(params[0] - centre, centre - params[1])


@pytest.mark.parametrize("h_sig", [0.0, 1.0])
def test_full_cma_covariance_update_equals_evotorchs(h_sig):
    """The rank-mu sum as one matmul gives EvoTorch's covariance update (active weights included)."""
    opt = make("cmaes")
    searcher = opt.searcher
    g = torch.Generator().manual_seed(5)
    searcher.C = torch.eye(opt.n_parameters) + 0.01 * torch.ones(opt.n_parameters, opt.n_parameters)
    searcher.p_c = torch.randn(opt.n_parameters, generator=g)
    zs = torch.randn(opt.n_samples, opt.n_parameters, generator=g)
    ys = zs @ torch.linalg.cholesky(searcher.C).T
    weights = searcher.weights[torch.randperm(opt.n_samples, generator=g)]
    assert (weights < 0).any() and searcher.active
    before = searcher.C.clone()
    EvoCMAES.update_C(searcher, zs, ys, weights, torch.tensor(h_sig))
    expected, searcher.C = searcher.C, before
    searcher.update_C(zs, ys, weights, torch.tensor(h_sig))
    assert not expected.equal(before)
    torch.testing.assert_close(searcher.C, expected, rtol=1e-6, atol=1e-7)
    assert searcher.C.equal(searcher.C.T)


# ---- the regulariser --------------------------------------------------------------------------

def test_penalty_formula_by_hand():
    params = torch.tensor([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])
    ref = torch.tensor([1.0, 0.0, 1.0])
    w = torch.tensor([3.0, 0.5, 1.0])
    # row 0: (3*0 + 0.5*4 + 1*4) / 3 = 2; row 1: (3*1 + 0 + 1*1) / 3 = 4/3
    torch.testing.assert_close(penalty(params, ref, w), torch.tensor([2.0, 4.0 / 3.0]))
    # l2: row 0: (0 + 4 + 4) / 3; row 1: (1 + 0 + 1) / 3
    torch.testing.assert_close(penalty(params, ref), torch.tensor([8.0 / 3.0, 2.0 / 3.0]))
    fitness = torch.tensor([10.0, 5.0])
    torch.testing.assert_close(regularised_fitness(fitness, params, 1.5, ref, w),
                               torch.tensor([10.0 - 3.0, 5.0 - 2.0]))
    assert regularised_fitness(fitness, params, 1.5, None, w).equal(fitness)
    assert regularised_fitness(fitness, params, 0.0, ref, w).equal(fitness)


@pytest.mark.parametrize("name", ALGOS)
def test_no_penalty_before_first_drift_then_centre_reference(name):
    reg = 2.0
    opt = make(name, reg=reg)
    for _ in range(3):
        policy = opt.ask()
        fitness = output_fitness(policy)
        assert opt.regularise(fitness).equal(fitness)  # no reference yet
        opt.tell(fitness, fitness)
    centre_at_drift = opt.centre.clone()
    opt.end_task()
    assert opt.regularizer.reference.equal(centre_at_drift)
    generation(opt, TARGET_B)
    assert opt.regularizer.reference.equal(centre_at_drift)  # a copy, not the moving centre
    policy = opt.ask()
    fitness = output_fitness(policy, TARGET_B)
    by_hand = torch.tensor([
        float(fitness[i]) - reg * sum((float(policy.params[i, j]) - float(centre_at_drift[j])) ** 2
                                      for j in range(opt.n_parameters)) / opt.n_parameters
        for i in range(opt.population_size)])
    torch.testing.assert_close(opt.regularise(fitness), by_hand, rtol=1e-5, atol=1e-6)
    assert bool((opt.regularise(fitness) < fitness).all())


@pytest.mark.parametrize("name", ["snes", "cmaes"])
def test_best_reference_is_best_selection_fitness_of_the_task(name):
    opt = make(name, reg=1.0, reference="best")
    best, best_params = -float("inf"), None
    for _ in range(4):
        params, selection = generation(opt)
        i = int(torch.argmax(selection))
        if float(selection[i]) > best:
            best, best_params = float(selection[i]), params[i]
    opt.end_task()
    assert opt.regularizer.reference.equal(best_params)
    assert not opt.regularizer.reference.equal(opt.centre)
    # the next task's best starts afresh: its reference comes from its own generations only
    params, selection = generation(opt, TARGET_B)
    opt.end_task()
    assert opt.regularizer.reference.equal(params[int(torch.argmax(selection))])


@pytest.mark.parametrize("name", ALGOS)
def test_regularisation_holds_the_centre_near_the_reference(name):
    distances = {}
    for reg in (0.0, 50.0):
        opt = make(name, reg=reg)
        for _ in range(8):
            generation(opt, TARGET_A)
        opt.end_task()
        ref = opt.centre.clone()
        for _ in range(15):
            generation(opt, TARGET_B)
        distances[reg] = float((opt.centre - ref).norm())
    assert distances[50.0] < 0.6 * distances[0.0], distances


@pytest.mark.parametrize("name", ALGOS)
@pytest.mark.parametrize("reg", [0.0, 3.0])
def test_diagnostics_are_the_distance_to_the_reference(name, reg):
    """Every generation reports the mean and spread of the regulariser's distance over the asked
    controllers, with or without a penalty; before the first drift there is none."""
    opt = make(name, reg=reg, importance="ewc")
    policy = opt.ask()
    fitness = output_fitness(policy)
    report = opt.tell(fitness, opt.regularise(fitness))
    assert set(opt.diagnostics) <= set(report.extra)
    assert all(math.isnan(report.extra[key]) for key in opt.diagnostics)
    for _ in range(3):
        generation(opt)
    opt.end_task()
    policy = opt.ask()
    params, fitness = policy.params.clone(), output_fitness(policy, TARGET_B)
    selection = opt.regularise(fitness)
    report = opt.tell(fitness, selection)
    by_hand = torch.stack([(opt.regularizer.importance * (p - opt.regularizer.reference) ** 2).mean() for p in params])
    assert report.extra["distance_mean"] == pytest.approx(by_hand.mean().item(), rel=1e-5)
    assert report.extra["distance_std"] == pytest.approx(by_hand.std(unbiased=False).item(), rel=1e-4)
    assert report.extra["distance_mean"] > 0
    torch.testing.assert_close(fitness - selection, reg * by_hand, rtol=1e-4, atol=1e-7)


@pytest.mark.parametrize("name", ["cmaes", "sep-cmaes"])
def test_cma_ewc_importance_is_normalised_precision(name):
    opt = make(name, reg=1.0, importance="ewc")
    for _ in range(3):
        generation(opt)
    s = opt.searcher
    variance = s.sigma ** 2 * (s.C if s.C.ndim == 1 else torch.diagonal(s.C))
    opt.end_task()
    expected = (1 / variance) / (1 / variance).mean()
    torch.testing.assert_close(opt.regularizer.importance, expected)
    assert opt.regularizer.importance.std() > 0  # three generations already shaped C


@pytest.mark.parametrize("name", ALGOS)
def test_ewc_importance_marks_the_parameters_the_fitness_depends_on(name):
    relevant = 4
    opt = ES_ALGORITHMS[name](obs_dim=2, hidden=(2,), population_size=30, seed=0,
                              reg=1.0, importance="ewc")
    for _ in range(20):
        theta = opt.ask().params
        fitness = -((theta[:, :relevant] - 1.0) ** 2).sum(dim=1)  # the other parameters do not matter
        opt.tell(fitness, opt.regularise(fitness))
    opt.end_task()
    w = opt.regularizer.importance
    assert w.shape == (opt.n_parameters,) and bool((w >= 0).all())
    torch.testing.assert_close(w.mean(), torch.tensor(1.0))
    assert float(w[:relevant].mean()) > 2 * float(w[relevant:].mean()), w


def test_gaussian_sensitivity_formula_by_hand():
    mu, sigma = torch.tensor([0.0, 1.0]), torch.tensor([1.0, 0.5])
    samples = torch.tensor([[1.0, 1.5], [-1.0, 0.5], [0.0, 2.0]])  # z = (1, 1), (-1, -1), (0, 2)
    fitness = torch.tensor([3.0, 2.0, 1.0])  # centred ranks u = +0.5, 0, -0.5
    # a = mean u z         = (0.5 + 0 + 0, 0.5 + 0 - 1) / 3 = (1/6, -1/6)
    # b = mean u (z^2 - 1) = (0 + 0 + 0.5, 0 + 0 - 1.5) / 3 = (1/6, -1/2)
    # s = (a^2 + b^2 / 2) / sigma^2 = (1/36 + 1/72, (1/36 + 1/8) * 4) = (1/24, 11/18)
    torch.testing.assert_close(gaussian_sensitivity(samples, mu, sigma, fitness),
                               torch.tensor([1 / 24, 11 / 18]))


def test_fisher_window_keeps_the_last_generations():
    regularizer = Regularizer(1.0, n_parameters=2, importance="ewc")
    mu, sigma = torch.zeros(2), torch.ones(2)
    samples = torch.tensor([[1.0, 0.0], [-1.0, 0.0]])
    for g in range(FISHER_WINDOW + 5):
        scale = 1.0 if g < 5 else 2.0  # the first 5 generations leave the window
        regularizer.observe_gaussian(samples * scale, mu, sigma, torch.tensor([1.0, 0.0]))
    # every kept generation: u = (+0.5, -0.5), z = (+-2, 0): a = (1, 0), b = (0, 0)
    torch.testing.assert_close(regularizer.fisher_diagonal(), torch.tensor([1.0, 0.0]))
    regularizer.end_task(torch.zeros(2))
    torch.testing.assert_close(regularizer.importance, torch.tensor([2.0, 0.0]))
    assert regularizer.fisher_diagonal() is None  # the next task starts a new window


def test_a_regulariser_state_carries_the_reference_not_lambda():
    """Lambda is the run's setting: a state (also one written with ``reg`` or, older, ``lam`` in it)
    loads into a regulariser of another lambda, which keeps its own lambda and takes the reference
    and importance; a different reference or importance mode is refused."""
    written = Regularizer(1.5, n_parameters=2)
    written.end_task(torch.tensor([1.0, -1.0]))
    for state in (written.state_dict(), {**written.state_dict(), "reg": 1.5}, {**written.state_dict(), "lam": 1.5}):
        loaded = Regularizer(4.0, n_parameters=2)
        loaded.load_state_dict(state)
        assert loaded.reg == 4.0
        torch.testing.assert_close(loaded.reference, torch.tensor([1.0, -1.0]))
        fitness = torch.zeros(1)
        assert loaded(fitness, torch.tensor([[1.0, 0.0]])).item() == pytest.approx(-4.0 * 0.5)  # (0^2 + 1^2) / 2
    with pytest.raises(ValueError, match="importance_mode"):
        Regularizer(1.5, n_parameters=2, importance="ewc").load_state_dict(written.state_dict())


def test_regularizer_rejects_bad_options():
    with pytest.raises(ValueError):
        Regularizer(1.0, n_parameters=3, reference="worst")
    with pytest.raises(ValueError):
        Regularizer(1.0, n_parameters=3, importance="fisher")
    with pytest.raises(ValueError):
        Regularizer(-1.0, n_parameters=3)
