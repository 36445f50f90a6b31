"""Two paper-size generations of NEAT (0.92's genetics) and of sep-CMA-ES, under different speed
settings (eager and compiled, one and two evaluation threads, one and two torch threads), each
writing byte for byte the metrics.csv, species.csv and controllers stored in
``tests/data/same-numbers/`` (made under the portable arithmetic, ``envs.numerics``; the machine
is named in its README). The promise (docs/usage.md, Reproducibility): the same seed and
settings give the same bytes on any x86-64 CPU with AVX2, whatever the speed settings.

To store them anew after a change that is meant to change the numbers:
``LIFELONG_EVO_STORE_NUMBERS=1 python -m pytest tests/test_same_numbers_anywhere.py -n 0``, then
name the machine in the README and the commit in docs/usage.md (Reproducibility)."""
from __future__ import annotations

import csv
import io
import os
import shutil
from pathlib import Path

import pytest

from lifelong_evo.commands.cli import main

STORED = Path(__file__).resolve().parent / "data" / "same-numbers"
PAPER_SIZE = ["--schedule", "red:2", "--population", "300", "--evals", "10", "--seed", "42",
              "--held-out-episodes", "10", "--no-record", "--quiet"]
"""The paper's population, N and 500-step episodes, for two generations of one task."""
SPEEDS = {
    "eager-1": ["--no-compile", "--eval-threads", "1", "--threads", "1"],
    "compiled-2": ["--compile", "--eval-threads", "2", "--threads", "1"],
    "eager-2x2": ["--no-compile", "--eval-threads", "2", "--threads", "2"],
}
CASES = [("neat", ["--reg", "11"], "eager-1"), ("neat", ["--reg", "11"], "compiled-2"),
         ("sep-cmaes", [], "compiled-2"), ("sep-cmaes", [], "eager-2x2")]


def _written(run: Path) -> dict[str, bytes]:
    files = [run / "metrics.csv", run / "species.csv", *sorted((run / "controllers").glob("*.json"))]
    return {str(path.relative_to(run)): path.read_bytes() for path in files if path.exists()}


@pytest.mark.parametrize("algo,settings,speed", CASES, ids=[f"{a}-{s}" for a, _, s in CASES])
def test_a_run_writes_the_stored_bytes_under_every_speed_setting(tmp_path, algo, settings, speed):
    assert main(["--algo", algo, *settings, *PAPER_SIZE, *SPEEDS[speed], "--out", str(tmp_path),
                 "--name", "run"]) == 0
    written = _written(tmp_path / "run")
    stored_run = STORED / algo
    if os.environ.get("LIFELONG_EVO_STORE_NUMBERS") and not stored_run.exists():
        shutil.copytree(tmp_path / "run", stored_run, ignore=shutil.ignore_patterns(
            "checkpoints", "*.rrd", "config.json", "summary.json", ".lock", ".lifelong-evo-run"))
    assert written.keys() == _written(stored_run).keys()
    assert [name for name in written if written[name] != _written(stored_run)[name]] == []
    rows = list(csv.DictReader(io.StringIO(written["metrics.csv"].decode())))
    assert len(rows) == 2 and max(float(row["best"]) for row in rows) > 0  # evolution met rewards


def test_full_cmaes_updates_alike_on_any_thread_count(tmp_path):
    """Full CMA-ES's update (its eigendecomposition and covariance update: MKL's linear algebra,
    which splits its sums by the thread count) ran on ``--threads`` x ``--eval-threads`` torch
    threads, so two evaluation threads sampled other populations than one from the first update
    on. Under the portable arithmetic it runs on one thread: every thread setting writes the same
    bytes. Small (population 50, 20-step episodes), but with the default 723 parameters, at which
    the update's threads mattered; lambda 1, so that the distances to the reference show it."""
    tiny = ["--algo", "cmaes", "--reg", "1", "--population", "50", "--evals", "1", "--env", "duration=20",
            "--schedule", "red:2,green:2", "--held-out-episodes", "1", "--no-compile", "--no-record", "--quiet"]
    for name, speed in (("one", ["--eval-threads", "1"]), ("two", ["--eval-threads", "2", "--threads", "2"])):
        assert main([*tiny, *speed, "--out", str(tmp_path), "--name", name]) == 0
    assert _written(tmp_path / "one") == _written(tmp_path / "two")


@pytest.mark.parametrize("algo,settings", [
    ("sep-cmaes", ["--regulariser", "functional", "--reg", "5"]),
    ("neat", ["--regulariser", "functional", "--reg", "2"]),
    ("neat", ["--regulariser", "wp", "--reg", "0.4", "--archive"]),
], ids=["sep-cmaes-functional", "neat-functional", "neat-wp-archive"])
def test_the_newer_regularisers_and_the_archive_write_the_same_bytes_under_every_speed_setting(
        tmp_path, algo, settings):
    """What acts only after a drift: the functional penalty (the reference played beside the
    population in the rollout, each evaluation thread's share of it with its own candidates),
    weight protection, and the archive putting red's controller back when red returns. A small
    drifting run writes the same bytes under every speed setting, and its penalty acts."""
    small = ["--algo", algo, *settings, "--preset", "smoke", "--schedule", "red:2,green:2,red:2",
             "--env", "duration=30", "--no-record", "--quiet"]
    written = {}
    for speed, flags in SPEEDS.items():
        assert main([*small, *flags, "--out", str(tmp_path), "--name", speed]) == 0
        written[speed] = _written(tmp_path / speed)
    assert [speed for speed in SPEEDS if written[speed] != written["eager-1"]] == []
    rows = list(csv.DictReader(io.StringIO(written["eager-1"]["metrics.csv"].decode())))
    assert any(float(row["reg_best"]) < float(row["best"]) for row in rows)  # the penalty changed a selection


def _compensated_sum(values, start=0):
    """Python 3.12's ``sum``: floats added with Neumaier's compensation of each rounding."""
    values = list(values)
    if not any(isinstance(value, float) for value in values):
        return _PLAIN_SUM(values, start)
    total, compensation = float(start), 0.0
    for value in values:
        added = total + value
        compensation += (total - added) + value if abs(total) >= abs(value) else (value - added) + total
        total = added
    return total + compensation


_PLAIN_SUM = sum


def test_neat_writes_the_same_bytes_on_python_3_12(tmp_path, monkeypatch):
    """Python 3.12's ``sum`` compensates its roundings, so floats summed with it can end in other
    bits than on 3.11. With ``sum`` made 3.12's, NEAT writes the stored bytes (its species means,
    spawn counts, mean distances and diagnostics add in order: ``numerics.ordered_sum``)."""
    monkeypatch.setattr("builtins.sum", _compensated_sum)
    assert _compensated_sum([0.1] * 10) != _PLAIN_SUM([0.1] * 10)  # the stand-in differs from 3.11's
    assert main(["--algo", "neat", "--reg", "11", *PAPER_SIZE, *SPEEDS["eager-1"], "--out", str(tmp_path),
                 "--name", "run"]) == 0
    assert _written(tmp_path / "run") == _written(STORED / "neat")
