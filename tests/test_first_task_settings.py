"""Which settings act only from the first task's end (``RunConfig.after_first_task``), so that runs
differing only in them share their first task (``--start-from``, ``sweep --share-first-task``).

Each optimiser's declarations are played: for every option in its ``after_first_task_options``, and
every pair of its regularisers the rule lets share a first task, a first task with each of two values,
whose state at its end (first-task-end.pt: the optimiser's, the generator's and the loop's), metrics.csv
and species.csv up to it and its controllers must be the same bytes. What the rule keeps apart (an
ES's ``ewc``, which gathers its sensitivities during the task, and ``reference=best``, which the
first task's end keeps) really does differ there. Options that only some regularisers read
(``options_used_by``) change nothing under the others, and change the numbers under those."""
from __future__ import annotations

import hashlib
import io
import json
from dataclasses import fields
from pathlib import Path
from typing import Literal, get_args, get_origin, get_type_hints

import pytest
import torch

from algorithms import REGISTRY, make_optimizer
from algorithms.base import FUNCTIONAL
from lifelong_evo import checkpoint
from lifelong_evo.commands.cli import main
from lifelong_evo.config import RunConfig, configure
from lifelong_evo.rundir import RunDir

FIRST = 2
"""Generations of the first task."""
COMMON = ["--preset", "smoke", "--schedule", f"red:{FIRST}", "--population", "8", "--reg", "2", "--env", "duration=50",
          "--held-out-episodes", "1", "--no-record", "--quiet"]
"""A first task alone, played small: the task end takes the regulariser's reference all the same."""


def _spread(algo: str) -> list[str]:
    """An ES samples widely, so that in so short episodes its controllers' fitness is not all alike."""
    return ["--option", "sigma=2"] if any(f.name == "sigma" for f in fields(REGISTRY[algo].Options)) else []


def _values(options_class, name: str) -> tuple[str, str]:
    """Option ``name``'s default and another value, as ``--option`` takes them."""
    default = next(f for f in fields(options_class) if f.name == name).default
    hint = get_type_hints(options_class)[name]
    if get_origin(hint) is Literal:
        return str(default), next(str(choice) for choice in get_args(hint) if choice != default)
    return str(default), str(default + 2)


def _config(algo: str, argv: list[str]) -> RunConfig:
    from lifelong_evo.commands.cli import build_parser
    from lifelong_evo.commands.flags import resolve_run_config

    return resolve_run_config(build_parser().parse_args(["run", "--algo", algo, *COMMON, *_spread(algo), *argv]))


def _declared_options():
    for algo, cls in sorted(REGISTRY.items()):
        for name in cls.after_first_task_options:
            users = cls.options_used_by.get(name)
            chosen = ["--regulariser", users[0]] if users else []  # where it is read
            one, other = ([*chosen, "--option", f"{name}={value}"] for value in _values(cls.Options, name))
            yield pytest.param(algo, one, other, id=f"{algo}-{name}")


SHARING_REGULARISERS = {"neat": ("gd", ["wp", "functional"]), **{
    algo: ("l2", ["functional"]) for algo, cls in REGISTRY.items() if "l2" in cls.regularisers}}
"""Per optimiser, its default regulariser and those that share its first task: NEAT's three act
only from the first task's end; an ES's L2 and functional ones too, not its EWC-style one, whose
importance the first task gathers."""


def _sharing_regularisers():
    for algo, (first, others) in sorted(SHARING_REGULARISERS.items()):
        for other in others:
            yield pytest.param(algo, ["--regulariser", first], ["--regulariser", other], id=f"{algo}-{first}-{other}")


@pytest.fixture(scope="module")
def played(tmp_path_factory):
    """``play(algo, argv)``: the run directory of that run, played once per configuration."""
    out = tmp_path_factory.mktemp("first-task")
    runs: dict[str, Path] = {}

    def play(algo: str, argv: list[str]) -> Path:
        config = _config(algo, argv)
        key = json.dumps({**config.to_dict(), "algo_options": config.algo_options_resolved()}, sort_keys=True)
        if key not in runs:
            name = hashlib.sha1(key.encode()).hexdigest()[:12]
            assert main(["--algo", algo, *COMMON, *_spread(algo), *argv, "--out", str(out), "--name", name]) == 0
            runs[key] = out / name
        return runs[key]

    return play


def _first_task(run: Path) -> dict[str, bytes]:
    """What a run holds of its first task: the state at its end (first-task-end.pt but its
    configuration and wall time), its rows of metrics.csv and species.csv, its controllers."""
    payload = checkpoint.load(run / "checkpoints/first-task-end.pt")
    held = {}
    for part in ("optimizer", "generator", "loop"):
        value = payload[part] if part != "loop" else {k: v for k, v in payload[part].items() if k != "wall_time_s"}
        buffer = io.BytesIO()
        torch.save(value, buffer)
        held[f"first-task-end.pt {part}"] = buffer.getvalue()
    for log in ("metrics.csv", "species.csv"):
        if (run / log).is_file():
            header, *rows = (run / log).read_text().splitlines()
            column = header.split(",").index("generation")
            held[log] = "\n".join([header, *(r for r in rows if int(r.split(",")[column]) < FIRST)]).encode()
    for path in sorted((run / "controllers").glob("*.json")):
        if path.name.startswith(("initial-", "task0-")):
            held[path.name] = path.read_bytes()
    return held


@pytest.mark.parametrize("algo, one, other", [*_declared_options(), *_sharing_regularisers()])
def test_what_acts_only_from_the_first_tasks_end_leaves_the_first_task_as_it_was(played, algo, one, other):
    """Each declared option, and each pair of regularisers the rule lets share a first task: the rule
    lets them (no first-task difference), and the first task is the same bytes either way."""
    runs = [played(algo, argv) for argv in (one, other)]
    assert runs[0] != runs[1]  # two configurations
    assert RunDir(runs[0]).first_task_differences(_config(algo, other).to_dict()) == []
    assert _first_task(runs[0]) == _first_task(runs[1])


@pytest.mark.parametrize("algo, argv, says", [
    ("openai-es", ["--regulariser", "ewc"], "--regulariser 'ewc' (stored: 'l2')"),
    ("sep-cmaes", ["--regulariser", "ewc"], "--regulariser 'ewc' (stored: 'l2')"),
    ("openai-es", ["--option", "reference=best"], "--option reference='best' (stored: 'centre')"),
])
def test_what_acts_in_the_first_task_keeps_runs_apart(played, algo, argv, says):
    """The EWC-style importance gathers its sensitivities during the task (or reads the search's
    variances at its end) and the best-controller reference is what the first task's end keeps: the
    rule refuses to share the first task, and the state at its end does differ."""
    runs = [played(algo, []), played(algo, argv)]
    assert RunDir(runs[0]).first_task_differences(_config(algo, argv).to_dict()) == [says]
    mine, theirs = _first_task(runs[0]), _first_task(runs[1])
    assert mine["first-task-end.pt optimizer"] != theirs["first-task-end.pt optimizer"]


def test_a_reference_taken_in_the_first_task_keeps_the_regulariser_in_it(tmp_path):
    """With ``--reference-every`` shorter than the first task the regulariser acts in it: lambda and
    the regulariser are first-task settings there, the baselines that start at its end are not."""
    config = RunConfig(algo="neat", reg=1.0, generations=3, reference_every=2).validate(machine=False)
    run = RunDir(tmp_path / "run")
    run.path.mkdir()
    run.write_config(config)
    assert run.first_task_differences({"reg": 3.0, "regulariser": "wp"}) == [
        "--reg 3.0 (stored: 1.0)", "--regulariser 'wp' (stored: 'gd')"]
    assert run.first_task_differences({"rehearsal": 0.5}) == []
    assert "reg" in RunConfig(reference_every=200).after_first_task()  # taken at the first task's end: after it


def _used_by():
    for algo, cls in sorted(REGISTRY.items()):
        for name, users in cls.options_used_by.items():
            for regulariser in cls.regularisers:
                yield pytest.param(algo, name, regulariser, regulariser in users, id=f"{algo}-{name}-{regulariser}")


@pytest.mark.parametrize("algo, name, regulariser, reads", list(_used_by()))
def test_an_option_only_some_regularisers_read_changes_nothing_under_the_others(algo, name, regulariser, reads):
    """``options_used_by``, why an option is refused under another regulariser: played past two task
    ends with two values of it (with fitness drawn from one stream), the optimiser under a regulariser
    that does not read it selects on the same fitness and keeps the same reference (all the functional
    regulariser reads); under one that reads it, the selection fitness differs."""
    cls = REGISTRY[algo]
    config = configure({"algo": algo, "regulariser": regulariser}, machine=False)
    trails = []
    for value in _values(cls.Options, name):
        options = {**config.algo_options_resolved(), name: type(getattr(cls.Options(), name))(value)}
        optimizer = make_optimizer(algo, obs_dim=config.env_config().obs_dim, population_size=20, seed=3,
                                   reg=0.0 if regulariser == FUNCTIONAL else 0.05, **options)
        fitness = torch.Generator().manual_seed(5)
        trail = []
        for generation in range(6):  # lambda small beside the fitness: each task's reference another controller
            optimizer.ask()
            raw = 100 * torch.rand(optimizer.population_size, generator=fitness)
            selection = optimizer.regularise(raw)
            optimizer.tell(raw, selection)
            trail.append((selection.tolist(), optimizer.reference_export()))
            if generation % 2 == 1:
                optimizer.end_task()
        trails.append(trail)
    assert (trails[0] != trails[1]) is reads
