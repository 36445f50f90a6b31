"""Benchmark: seconds per paper generation. ``python -m lifelong_evo.bench --help``.

Without ``--algo``: the environment alone, with a random batched MLP controller (41-16-3),
at several batch sizes, with the split between sensing, controller and dynamics.
``--eval-threads N`` splits the controllers over N threads as the lifelong run's evaluator does.
With ``--algo NAME``: one full generation of that optimiser (ask, evaluate, regularise, tell);
with ``--compile`` as well, first eagerly, then compiled.
The last line is always ``s_per_generation=<seconds>`` for the chosen workload.
"""
from __future__ import annotations

import argparse
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import torch

from algorithms.base import BatchedPolicy
from envs import TASKS, ForagingConfig, ForagingEnv, outputs_to_wheels
from lifelong_evo.bench_reference import ReferenceStep
from lifelong_evo.evaluate import evaluate, shard_bounds, update_threads


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


def bench_env(n_envs: int, steps: int, config: ForagingConfig, device: str, compile_env: bool,
              eval_threads: int = 1, reference: bool = False) -> dict:
    """Time ``steps`` steps of ``n_envs`` environments driven by one random MLP per 10 envs,
    split over ``eval_threads`` threads as the evaluator splits a population; ``reference``:
    of ``ReferenceStep`` instead (see ``lifelong_evo.bench_reference``)."""
    from algorithms.mlp import MLPPolicy, layer_sizes_for, n_parameters

    generator = torch.Generator().manual_seed(0)
    population = max(1, n_envs // 10)
    sizes = layer_sizes_for(config.obs_dim)
    policy = MLPPolicy(torch.randn(population, n_parameters(sizes), generator=generator).to(device), sizes)
    shards = []
    for start, stop in shard_bounds(population, eval_threads):
        env = (ReferenceStep if reference else ForagingEnv)(config, batch_size=(stop - start) * 10, device=device)
        if compile_env:
            env.compile()
        shards.append(_Shard(env, policy.shard(start, stop), env.reset(TASKS["red"], generator=generator)))
    with ThreadPoolExecutor(len(shards)) as pool:
        list(pool.map(lambda shard: shard.drive(WARM_UP_STEPS, config), shards))  # compiles, with --compile
        total = _timed(lambda: list(pool.map(lambda shard: shard.drive(steps, config), shards)))[1]
    controller = sum(shard.controller for shard in shards)
    dynamics = sum(shard.dynamics for shard in shards)
    busy = controller + dynamics  # summed over the threads
    result = {"envs": population * 10, "s_per_generation": total * config.duration / steps,
              "agent_steps_per_s": population * 10 * config.n_agents * steps / total,
              "controller": controller / busy, "step": dynamics / busy}
    if not compile_env:  # compiled, the sensing is fused with the drops into one graph
        sensing = sum(min(_timed(shard.env.observe)[1] for _ in range(5)) for shard in shards) * steps
        result["sensing"] = min(sensing, dynamics) / busy
        result["dynamics"] = max(dynamics - sensing, 0.0) / busy
    return result


@dataclass
class _Shard:
    """One thread's environments and controllers, and the seconds it spent in each."""

    env: ForagingEnv | ReferenceStep
    policy: BatchedPolicy
    observations: torch.Tensor
    controller: float = 0.0
    dynamics: float = 0.0

    def drive(self, steps: int, config: ForagingConfig) -> None:
        shape = (self.policy.population_size, 10, config.n_agents, config.obs_dim)
        self.controller = self.dynamics = 0.0
        for _ in range(steps):
            outputs, spent = _timed(lambda: self.policy(self.observations.view(shape)))
            self.controller += spent
            wheels = outputs_to_wheels(outputs, config).view(-1, config.n_agents, 3)
            (self.observations, *_), spent = _timed(lambda: self.env.step(wheels))
            self.dynamics += spent


def _split(result: dict) -> str:
    if "sensing" in result:
        return (f"sensing {result['sensing']:.0%}, controller {result['controller']:.0%}, "
                f"dynamics {result['dynamics']:.0%}")
    return f"controller {result['controller']:.0%}, step (dynamics and sensing, fused) {result['step']:.0%}"


def bench_algo(algo: str, population: int, n_envs: int, generations: int, device: str, compiled: bool,
               eval_threads: int = 1) -> dict:
    """Time full generations of ``algo`` at the paper's size (after one warm-up generation)."""
    from algorithms import make_optimizer

    config = ForagingConfig()
    optimizer = make_optimizer(algo, obs_dim=config.obs_dim, population_size=population, seed=0, device=device)
    generator = torch.Generator().manual_seed(0)
    totals = {"ask": 0.0, "evaluate": 0.0, "tell": 0.0}
    threads = torch.get_num_threads()
    for generation in range(generations + 1):
        with update_threads(threads, eval_threads):  # as the lifelong loop does
            policy, t_ask = _timed(optimizer.ask)
        fitness, t_eval = _timed(lambda: evaluate(policy, config, [TASKS["red"]], n_envs, generator, device,
                                                  compiled=compiled, eval_threads=eval_threads)[0])
        with update_threads(threads, eval_threads):
            _, t_tell = _timed(lambda: optimizer.tell(fitness, optimizer.regularise(fitness)))
        if generation:  # the first generation warms up
            totals["ask"] += t_ask
            totals["evaluate"] += t_eval
            totals["tell"] += t_tell
    per = {k: v / generations for k, v in totals.items()}
    per["controllers"] = policy.population_size
    per["s_per_generation"] = sum(v for k, v in per.items() if k != "controllers")
    return per


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m lifelong_evo.bench", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", default=None, help="time a full generation of this optimiser (default: env only)")
    parser.add_argument("--envs", type=int, default=3000, help="environments of the reported workload (env only)")
    parser.add_argument("--also", default="300,12000", help="other batch sizes to print (env only; '' for none)")
    parser.add_argument("--steps", type=int, default=100, help="steps timed per batch size, scaled to 500 (env only)")
    parser.add_argument("--population", type=int, default=300, help="population size (--algo)")
    parser.add_argument("--evals", type=int, default=10, help="environments per controller (--algo)")
    parser.add_argument("--generations", type=int, default=2, help="generations timed after a warm-up (--algo)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--eval-threads", type=int, default=1,
                        help="threads that each play a slice of the controllers (use with --compile --threads 1)")
    parser.add_argument("--compile", action="store_true", help="torch.compile the environment's step (compiled during the untimed warm-up)")
    parser.add_argument("--device", default="cpu", help="torch device, e.g. cpu or cuda")
    parser.add_argument("--reference", action="store_true",
                        help="time the plain step the speed goals were set with, not this env (env only; "
                             "compares a machine with theirs, see lifelong_evo/bench_reference.py)")
    args = parser.parse_args(argv)
    if args.reference and args.algo:
        parser.error("--reference times the environment step alone: drop --algo or --reference")
    torch.set_num_threads(args.threads)
    print(f"threads={torch.get_num_threads()} eval_threads={args.eval_threads} device={args.device} "
          f"compile={'on' if args.compile else 'off'}" + (" step=reference" if args.reference else ""))
    if args.algo:
        # under --compile the eager figure comes first, so that one call shows what compiling buys
        for compiled in ([False, True] if args.compile else [False]):
            result = bench_algo(args.algo, args.population, args.evals, args.generations, args.device, compiled,
                                args.eval_threads)
            print(f"algo={args.algo} compile={'on' if compiled else 'off'} controllers={result['controllers']} "
                  f"x {args.evals} envs x 500 steps: ask {result['ask']:.3f} s, evaluate {result['evaluate']:.3f} s, "
                  f"regularise+tell {result['tell']:.3f} s; {result['s_per_generation']:.3f} s/generation")
        print(f"s_per_generation={result['s_per_generation']:.3f}")
        return
    config = ForagingConfig()
    sizes = [int(s) for s in args.also.split(",") if s] + [args.envs]
    result = {}
    for n_envs in sizes:
        result = bench_env(n_envs, args.steps, config, args.device, args.compile, args.eval_threads, args.reference)
        print(f"envs={result['envs']:>6} x 500 steps: {result['s_per_generation']:.3f} s/generation, "
              f"{result['agent_steps_per_s'] / 1e6:.2f} M agent-steps/s; split: {_split(result)}")
    print(f"s_per_generation={result['s_per_generation']:.3f}")


if __name__ == "__main__":
    main()
