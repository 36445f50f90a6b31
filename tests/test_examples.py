"""Every example runs, at a tiny size."""
from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from algorithms import REGISTRY
from lifelong_evo.commands.cli import main
from lifelong_evo.config import load_toml, resolve

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
TINY = ["--generations", "2", "--population", "8", "--evals", "1", "--retention-every", "1", "--env", "duration=30",
        "--no-compile", "--no-record", "--quiet"]


SWEEPS = sorted(p.name for p in EXAMPLES.glob("sweep*.toml"))
"""Sweep files (a [grid] table over run options); every other .toml is a run configuration."""


SMOKE_SIZED = ("robot_failure_smoke.toml",)
"""Run configurations meant to run in seconds, at the smoke preset's size; the others are the paper's size."""


@pytest.mark.parametrize("name", sorted(p.name for p in EXAMPLES.glob("*.toml") if p.name not in SWEEPS))
def test_experiment_configs_resolve(name):
    config = resolve("paper", load_toml(EXAMPLES / name))
    size = (config.generations, config.population, config.evals)
    assert size == ((5, 20, 2) if name in SMOKE_SIZED else (200, 300, 10))


def test_every_example_task_runs(tmp_path):
    """Each task of examples/tasks.toml, one generation each, in one run."""
    tasks = load_toml(EXAMPLES / "tasks.toml")["tasks"]
    schedule = ",".join(f"{name}:1" for name in tasks)
    assert main(["--tasks", str(EXAMPLES / "tasks.toml"), "--schedule", schedule, *TINY, "--out", str(tmp_path),
                 "--name", "x"]) == 0
    config = json.loads((tmp_path / "x/config.json").read_text())
    assert list(config["task_definitions"]) == list(tasks) and len(tasks) >= 4


@pytest.mark.parametrize("name", ["paper_reg11.toml", "paper_four_tasks.toml", "es_comparison.toml",
                                  "robot_failure_smoke.toml"])
def test_experiment_configs_run(name, tmp_path):
    assert main(["--config", str(EXAMPLES / name), *TINY, "--out", str(tmp_path), "--name", "x"]) == 0
    config = json.loads((tmp_path / "x/config.json").read_text())
    expected = load_toml(EXAMPLES / name)
    assert config["algo"] == expected["algo"] and config["schedule"] == expected["schedule"]
    if name == "paper_four_tasks.toml":
        assert config["env_resolved"]["colors"] == list(range(3, 11))


@pytest.mark.parametrize("name", SWEEPS)
def test_sweep_files_list_their_trials(name, tmp_path, capsys):
    grid = load_toml(EXAMPLES / name)["grid"]
    assert main(["sweep", "--config", str(EXAMPLES / name), "--out", str(tmp_path), "--dry-run"]) == 0
    trials = [line for line in capsys.readouterr().out.splitlines() if line.startswith("would run")]

    def combinations(table: dict) -> int:  # lists are axes, nested option tables too; [grid.<algo>] apart
        count = 1
        for key, value in table.items():
            if isinstance(value, list):
                count *= len(value)
            elif isinstance(value, dict) and key not in REGISTRY:
                count *= combinations(value)
        return count

    shared = combinations({key: value for key, value in grid.items() if key != "algo"})
    algos = grid.get("algo", [load_toml(EXAMPLES / name).get("algo", "neat")])
    assert len(trials) == sum(shared * combinations(grid.get(algo, {})) for algo in algos)
    assert not any(tmp_path.iterdir())


def test_custom_optimizer_example(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(EXAMPLES.parent)}
    subprocess.run([sys.executable, str(EXAMPLES / "custom_optimizer.py"), *TINY, "--out", str(tmp_path),
                    "--name", "hill"], check=True, env=env)
    summary = json.loads((tmp_path / "hill/summary.json").read_text())
    assert summary["phases"] == ["red", "green", "red"]
    rows = (tmp_path / "hill/metrics.csv").read_text().splitlines()
    assert len(rows) == 1 + 6


def test_gymnasium_example(capsys):
    spec = importlib.util.spec_from_file_location("gymnasium_example", EXAMPLES / "gymnasium_env.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.main(steps=20, num_envs=2)
    out = capsys.readouterr().out
    assert "one environment" in out and "2 environments in one torch batch" in out


def test_analysis_example_prints_compares_tables(capsys):
    """The analysis from Python gives the same tables ``compare`` prints, on the data the docs keep."""
    from lifelong_evo.commands import compare
    from lifelong_evo.commands.cli import build_parser

    spec = importlib.util.spec_from_file_location("analysis_example", EXAMPLES / "analysis.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.main([str(module.DATA)])
    out = capsys.readouterr().out
    expected = compare.requested_comparison(build_parser().parse_args(["compare", str(module.DATA)])).markdown
    assert out.startswith(expected + "\n")
    assert "red R_top at the end of green, neat reg=11 red-green-red minus neat reg=0 red-green-red" in out
