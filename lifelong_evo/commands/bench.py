"""Benchmark: seconds per paper generation. ``python -m lifelong_evo.bench --help``.

Without ``--algo``: the environment alone, with a random batched MLP controller (41-16-3),
at several batch sizes, with the split between sensing, controller and dynamics.
``--eval-threads N`` splits the controllers over N threads as the lifelong run's evaluator does.
With ``--algo NAME``: one full generation of that optimiser (ask, evaluate, regularise, tell);
with ``--compile`` as well, first eagerly, then compiled. ``--cuda-graphs`` (with ``--device cuda``)
replays the environment's step as a CUDA graph (``ForagingEnv.graph_step``); ``--runs N`` times N
runs at once, evaluated in one batch (``sweep --together``), the figures being for all N.
The last line is always ``s_per_generation=<seconds>`` for the chosen workload.
The flags are typed and bounded as a run's (``BenchSettings``, ``lifelong_evo.commands.flags.add_flags``)
and checked as a run's (the algorithm, its population, the device, a C++ compiler, the memory
the workload needs: ``lifelong_evo.memory``): a bad one is one line, ``error: ...``, exit status 2.
``benchmarks/reference_step.py`` (a script outside the package) runs the environment part on
another step: ``main(env_class=...)``.
"""
from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import torch

from algorithms import UnknownAlgorithmError, make_optimizer
from algorithms.base import BatchedPolicy
from algorithms.mlp import MLPPolicy, layer_sizes_for, n_parameters
from envs import TASKS, ConfigError, ForagingConfig, ForagingEnv, numerics
from envs.numerics import Numerics
from lifelong_evo import memory
from lifelong_evo.commands.flags import add_flags, typed
from lifelong_evo.config import RunConfig
from lifelong_evo.errors import Parser, UserError
from lifelong_evo.evaluate import Evaluation, evaluate_together, rollout, shard_bounds, update_threads

WARM_UP_STEPS = 3
"""Untimed steps before the timed ones (they compile the step under --compile)."""
ENV_ROWS = 10
"""Environments each random controller drives in the environment benchmark."""


def _timed(fn):
    _wait_for_gpu()
    start = time.perf_counter()
    result = fn()
    _wait_for_gpu()
    return result, time.perf_counter() - start


def _wait_for_gpu() -> None:
    """CUDA kernels run asynchronously: a time read before they finish would miss them."""
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        torch.cuda.synchronize()


class _TimedPolicy:
    """A policy that adds the seconds each call takes to ``seconds``."""

    def __init__(self, policy: BatchedPolicy):
        self.policy, self.population_size, self.seconds = policy, policy.population_size, 0.0

    def __call__(self, observations: torch.Tensor) -> torch.Tensor:
        outputs, spent = _timed(lambda: self.policy(observations))
        self.seconds += spent
        return outputs


class _TimedEnv:
    """An environment whose ``step`` adds the seconds it takes to ``seconds``."""

    def __init__(self, env: ForagingEnv):
        self.env, self.config, self.seconds = env, env.config, 0.0

    def step(self, wheels: torch.Tensor):
        result, spent = _timed(lambda: self.env.step(wheels))
        self.seconds += spent
        return result


def bench_env(n_envs: int, steps: int, config: ForagingConfig, device: str, compile_env: bool,
              eval_threads: int = 1, env_class: type = ForagingEnv, cuda_graphs: bool = False) -> dict:
    """Time ``steps`` steps (``evaluate.rollout``'s) of ``n_envs`` environments driven by one
    random MLP per 10 envs, split over ``eval_threads`` threads as the evaluator splits a
    population. ``env_class``: the step to time, ``ForagingEnv`` or one with its ``reset``,
    ``step``, ``observe`` and ``compile``; ``cuda_graphs``: its step replayed as a CUDA graph
    (captured during the untimed warm-up)."""
    generator = torch.Generator().manual_seed(0)
    population = max(1, n_envs // ENV_ROWS)
    sizes = layer_sizes_for(config.obs_dim)
    policy = MLPPolicy(torch.randn(population, n_parameters(sizes), generator=generator).to(device), sizes)
    shards = []
    for start, stop in shard_bounds(population, eval_threads):
        env = env_class(config, batch_size=(stop - start) * ENV_ROWS, device=device)
        if compile_env:
            env.compile()
        if cuda_graphs:
            env.graph_step(capture=True)
        shards.append((policy.shard(start, stop), env, env.reset(TASKS["red"], generator=generator)))
    with ThreadPoolExecutor(len(shards)) as pool:
        list(pool.map(lambda shard: rollout(*shard, steps=WARM_UP_STEPS), shards))  # compiles, with --compile
        timed = [(_TimedPolicy(shard_policy), _TimedEnv(env), env.observe()) for shard_policy, env, _ in shards]
        total = _timed(lambda: list(pool.map(lambda shard: rollout(*shard, steps=steps), timed)))[1]
    controller = sum(shard_policy.seconds for shard_policy, _, _ in timed)
    dynamics = sum(env.seconds for _, env, _ in timed)
    busy = controller + dynamics  # summed over the threads
    result = {"envs": population * ENV_ROWS, "s_per_generation": total * config.duration / steps,
              "agent_steps_per_s": population * ENV_ROWS * config.n_agents * steps / total,
              "controller": controller / busy, "step": dynamics / busy}
    if not compile_env:  # compiled, the sensing is fused with the drops into one graph
        sensing = sum(min(_timed(env.observe)[1] for _ in range(5)) for _, env, _ in shards) * steps
        result["sensing"] = min(sensing, dynamics) / busy
        result["dynamics"] = max(dynamics - sensing, 0.0) / busy
    return result


def _split(result: dict) -> str:
    if "sensing" in result:
        return (f"sensing {result['sensing']:.0%}, controller {result['controller']:.0%}, "
                f"dynamics {result['dynamics']:.0%}")
    return f"controller {result['controller']:.0%}, step (dynamics and sensing, fused) {result['step']:.0%}"


def bench_algo(algo: str, population: int, n_envs: int, generations: int, device: str, compiled: bool,
               eval_threads: int = 1, cuda_graphs: bool = False, runs: int = 1) -> dict:
    """Time full generations of ``algo`` at the paper's size (after one warm-up generation); with
    ``runs`` > 1, of that many runs (seeds 0, 1, ...) at once, their evaluations played together
    in one batch as ``sweep --together`` plays them (``evaluate_together``)."""
    config = ForagingConfig()
    optimizers = [make_optimizer(algo, obs_dim=config.obs_dim, population_size=population, seed=seed, device=device)
                  for seed in range(runs)]
    generators = [torch.Generator().manual_seed(seed) for seed in range(runs)]
    totals = {"ask": 0.0, "evaluate": 0.0, "tell": 0.0}
    threads = torch.get_num_threads()
    for generation in range(generations + 1):
        with update_threads(threads, eval_threads, numerics.mode()):  # as the lifelong loop does
            policies, t_ask = _timed(lambda: [optimizer.ask() for optimizer in optimizers])
        evaluations = [Evaluation(policy, config, [TASKS["red"]], n_envs, generator, device, compiled=compiled,
                                  eval_threads=eval_threads, cuda_graphs=cuda_graphs, numerics=numerics.mode())
                       for policy, generator in zip(policies, generators)]
        play = (lambda: [evaluations[0].run()]) if runs == 1 else (lambda: evaluate_together(evaluations))
        fitness, t_eval = _timed(play)
        with update_threads(threads, eval_threads, numerics.mode()):
            _, t_tell = _timed(lambda: [optimizer.tell(f[0], optimizer.regularise(f[0]))
                                        for optimizer, f in zip(optimizers, fitness)])
        if generation:  # the first generation warms up
            totals["ask"] += t_ask
            totals["evaluate"] += t_eval
            totals["tell"] += t_tell
    per = {k: v / generations for k, v in totals.items()}
    per["controllers"] = policies[0].population_size
    per["s_per_generation"] = sum(v for k, v in per.items() if k != "controllers")
    return per


def _run_bounds(name: str) -> dict:
    """The bounds RunConfig declares for its field ``name``: the benchmark's flag of the same name takes what a run takes."""
    return dict(RunConfig.__dataclass_fields__[name].metadata)


@dataclass(frozen=True)
class BenchSettings:
    """The benchmark's flags (``--algo`` aside): each field's type and bounds parse its value, as a
    run's flags are parsed (``lifelong_evo.commands.flags.add_flags``), and its docstring is its help."""

    envs: int = field(default=3000, metadata={"min": ENV_ROWS, "max": 10_000_000})
    """Environments of the reported workload, a multiple of 10: one random controller drives 10 (env only)."""
    also: tuple[int, ...] = field(default=(300, 12000), metadata={"min": ENV_ROWS, "max": 10_000_000, "max_items": 16})
    """Other batch sizes to print first, multiples of 10 (env only; [] for none)."""
    steps: int = field(default=100, metadata={"min": 1, "max": ForagingConfig().duration - WARM_UP_STEPS})
    """Steps timed per batch size, scaled to the 500 of an episode; they follow the warm-up within one episode (env only)."""
    population: int = field(default=300, metadata=_run_bounds("population"))
    """Population size (--algo)."""
    evals: int = field(default=10, metadata=_run_bounds("evals"))
    """Environments per controller (--algo)."""
    generations: int = field(default=2, metadata={"min": 1, "max": 1000})
    """Generations timed after a warm-up (--algo)."""
    runs: int = field(default=1, metadata={"min": 1, "max": 1000})
    """Time this many runs at once, evaluated in one batch as sweep --together does (--algo, with --eval-threads 1; the figures are for all of them)."""
    threads: int = field(default=1, metadata=_run_bounds("threads"))
    """Torch threads."""
    eval_threads: int = field(default=1, metadata=_run_bounds("eval_threads"))
    """Threads that each play a slice of the controllers (use with --compile --threads 1)."""
    device: str = "cpu"
    """Torch device: cpu, cuda or cuda:N."""
    compile: bool = False
    """torch.compile the environment's step (compiled during the untimed warm-up)."""
    cuda_graphs: bool = False
    """Replay the environment's step as a CUDA graph (captured during the warm-up; --device cuda)."""
    numerics: Numerics = "portable"
    """Arithmetic of the environment and the controllers: portable or native (docs/usage.md, Reproducibility)."""


def _parse_args(argv, env_class: type) -> argparse.Namespace:
    """The flags, parsed and checked as a run's are: one line, ``error: ...``, exit status 2 otherwise."""
    parser = Parser(prog="python -m lifelong_evo.bench", description=__doc__,
                    formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", default=None, type=typed(str),
                        help="time a full generation of this optimiser (default: the environment alone)")
    add_flags(parser, BenchSettings)
    parser.add_argument("--no-memory-check", dest="memory_check", action="store_false",
                        help="time a workload that the memory check estimates this machine cannot hold")
    args = parser.parse_args(argv)
    if env_class is not ForagingEnv and args.algo:
        raise UserError(f"{env_class.__name__} is timed as the environment step alone: drop --algo")
    if args.runs > 1 and (not args.algo or args.eval_threads != 1):
        raise UserError("--runs N times N runs of an --algo in one batch: give --algo, N >= 1 and --eval-threads 1")
    if args.cuda_graphs and env_class is not ForagingEnv:
        raise UserError(f"--cuda-graphs replays ForagingEnv's step, not {env_class.__name__}'s: drop --cuda-graphs")
    for flag, sizes in (("--envs", [args.envs]), ("--also", args.also)):
        if any(n % ENV_ROWS for n in sizes):
            raise UserError(f"{flag} {','.join(map(str, sizes))}: one random controller drives {ENV_ROWS} "
                            f"environments, so give multiples of {ENV_ROWS}")
    # the run's own checks: the algorithm and its population, the device, a compiler, CUDA graphs on CUDA
    numerics.use(args.numerics)
    workload = replace(RunConfig(), schedule="red", record=False, threads=args.threads, eval_threads=args.eval_threads,
                       device=args.device, compile=args.compile, cuda_graphs=args.cuda_graphs, numerics=args.numerics,
                       **({"algo": args.algo, "population": args.population, "evals": args.evals} if args.algo
                          else {})).validate()
    if args.memory_check:
        if not args.algo:  # the environment alone: random 41-16-3 MLPs, whose needs an ES's estimate covers
            workload = replace(workload, algo="snes", population=max([args.envs, *args.also]) // ENV_ROWS,
                               evals=ENV_ROWS)
        fix = "lower --population or --evals" if args.algo else "lower --envs or --also"
        memory.check([workload] * args.runs, together=True, what="this benchmark",
                     fix=f"{fix}, or pass --no-memory-check to time it anyway")
    return args


def main(argv=None, env_class: type = ForagingEnv) -> None:
    """The benchmark's command line; ``env_class``: the step the environment benchmark times."""
    try:
        args = _parse_args(argv, env_class)
    except (UserError, ConfigError, UnknownAlgorithmError) as error:
        print(f"error: {error}", file=sys.stderr)
        raise SystemExit(2) from None
    torch.set_num_threads(args.threads)
    print(f"threads={torch.get_num_threads()} eval_threads={args.eval_threads} device={args.device} "
          f"compile={'on' if args.compile else 'off'} cuda_graphs={'on' if args.cuda_graphs else 'off'}"
          + ("" if env_class is ForagingEnv else f" step={env_class.__name__}"))
    if args.algo:
        # under --compile the eager figure comes first, so that one call shows what compiling buys
        for compiled in ([False, True] if args.compile else [False]):
            result = bench_algo(args.algo, args.population, args.evals, args.generations, args.device, compiled,
                                args.eval_threads, args.cuda_graphs, args.runs)
            runs = f"runs={args.runs} together, " if args.runs > 1 else ""
            print(f"algo={args.algo} compile={'on' if compiled else 'off'} {runs}controllers={result['controllers']} "
                  f"x {args.evals} envs x 500 steps: ask {result['ask']:.3f} s, evaluate {result['evaluate']:.3f} s, "
                  f"regularise+tell {result['tell']:.3f} s; {result['s_per_generation']:.3f} s/generation")
        print(f"s_per_generation={result['s_per_generation']:.3f}")
        return
    sizes = [*args.also, args.envs]
    result = {}
    for n_envs in sizes:
        result = bench_env(n_envs, args.steps, ForagingConfig(), args.device, args.compile, args.eval_threads, env_class,
                           args.cuda_graphs)
        print(f"envs={result['envs']:>6} x 500 steps: {result['s_per_generation']:.3f} s/generation, "
              f"{result['agent_steps_per_s'] / 1e6:.2f} M agent-steps/s; split: {_split(result)}")
    print(f"s_per_generation={result['s_per_generation']:.3f}")


if __name__ == "__main__":
    main()
