"""Benchmark: seconds per paper generation. ``python -m lifelong_evo.bench --help``.

Without ``--algo``: the environment alone, with a random batched MLP controller (41-16-3),
at several batch sizes, with the split between sensing, controller and dynamics.
``--eval-threads N`` splits the controllers over N threads as the lifelong run's evaluator does.
With ``--algo NAME``: one full generation of that optimiser (ask, evaluate, regularise, tell);
with ``--compile`` as well, first eagerly, then compiled. ``--cuda-graphs`` (with ``--device cuda``)
replays the environment's step as a CUDA graph (``ForagingEnv.graph_step``); ``--runs N`` times N
runs at once, evaluated in one batch (``sweep --together``), the figures being for all N.
The last line is always ``s_per_generation=<seconds>`` for the chosen workload.
``benchmarks/reference_step.py`` (a script outside the package) runs the environment part on
another step: ``main(env_class=...)``.
"""
from __future__ import annotations

import argparse
import time
from concurrent.futures import ThreadPoolExecutor

import torch

from algorithms import make_optimizer
from algorithms.base import BatchedPolicy
from algorithms.mlp import MLPPolicy, layer_sizes_for, n_parameters
from envs import TASKS, ForagingConfig, ForagingEnv
from lifelong_evo.evaluate import Evaluation, evaluate_together, rollout, shard_bounds, update_threads

WARM_UP_STEPS = 3
"""Untimed steps before the timed ones (they compile the step under --compile)."""


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
    population = max(1, n_envs // 10)
    sizes = layer_sizes_for(config.obs_dim)
    policy = MLPPolicy(torch.randn(population, n_parameters(sizes), generator=generator).to(device), sizes)
    shards = []
    for start, stop in shard_bounds(population, eval_threads):
        env = env_class(config, batch_size=(stop - start) * 10, device=device)
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
    result = {"envs": population * 10, "s_per_generation": total * config.duration / steps,
              "agent_steps_per_s": population * 10 * config.n_agents * steps / total,
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
        with update_threads(threads, eval_threads):  # as the lifelong loop does
            policies, t_ask = _timed(lambda: [optimizer.ask() for optimizer in optimizers])
        evaluations = [Evaluation(policy, config, [TASKS["red"]], n_envs, generator, device, compiled=compiled,
                                  eval_threads=eval_threads, cuda_graphs=cuda_graphs)
                       for policy, generator in zip(policies, generators)]
        play = (lambda: [evaluations[0].run()]) if runs == 1 else (lambda: evaluate_together(evaluations))
        fitness, t_eval = _timed(play)
        with update_threads(threads, eval_threads):
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


def main(argv=None, env_class: type = ForagingEnv) -> None:
    """The benchmark's command line; ``env_class``: the step the environment benchmark times."""
    parser = argparse.ArgumentParser(prog="python -m lifelong_evo.bench", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", default=None, help="time a full generation of this optimiser (default: env only)")
    parser.add_argument("--envs", type=int, default=3000, help="environments of the reported workload (env only)")
    parser.add_argument("--also", default="300,12000", help="other batch sizes to print (env only; '' for none)")
    parser.add_argument("--steps", type=int, default=100, help="steps timed per batch size, scaled to 500 (env only)")
    parser.add_argument("--population", type=int, default=300, help="population size (--algo)")
    parser.add_argument("--evals", type=int, default=10, help="environments per controller (--algo)")
    parser.add_argument("--generations", type=int, default=2, help="generations timed after a warm-up (--algo)")
    parser.add_argument("--runs", type=int, default=1,
                        help="time this many runs at once, evaluated in one batch as sweep --together does "
                             "(--algo; the figures are for all of them)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--eval-threads", type=int, default=1,
                        help="threads that each play a slice of the controllers (use with --compile --threads 1)")
    parser.add_argument("--compile", action="store_true", help="torch.compile the environment's step (compiled during the untimed warm-up)")
    parser.add_argument("--device", default="cpu", help="torch device, e.g. cpu or cuda")
    parser.add_argument("--cuda-graphs", action="store_true",
                        help="replay the environment's step as a CUDA graph (captured during the warm-up; --device cuda)")
    args = parser.parse_args(argv)
    config = ForagingConfig()
    if env_class is not ForagingEnv and args.algo:
        parser.error(f"{env_class.__name__} is timed as the environment step alone: drop --algo")
    if args.runs < 1 or (args.runs > 1 and (not args.algo or args.eval_threads != 1)):
        parser.error("--runs N times N runs of an --algo in one batch: give --algo, N >= 1 and --eval-threads 1")
    if args.cuda_graphs and (env_class is not ForagingEnv or not args.device.startswith("cuda")):
        parser.error("--cuda-graphs replays ForagingEnv's step on a GPU: add --device cuda, or drop --cuda-graphs")
    if not 1 <= args.steps <= config.duration - WARM_UP_STEPS:
        parser.error(f"--steps must be from 1 to {config.duration - WARM_UP_STEPS}: the timed steps follow the "
                     f"warm-up within one {config.duration}-step episode")
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
    sizes = [int(s) for s in args.also.split(",") if s] + [args.envs]
    result = {}
    for n_envs in sizes:
        result = bench_env(n_envs, args.steps, config, args.device, args.compile, args.eval_threads, env_class,
                           args.cuda_graphs)
        print(f"envs={result['envs']:>6} x 500 steps: {result['s_per_generation']:.3f} s/generation, "
              f"{result['agent_steps_per_s'] / 1e6:.2f} M agent-steps/s; split: {_split(result)}")
    print(f"s_per_generation={result['s_per_generation']:.3f}")


if __name__ == "__main__":
    main()
