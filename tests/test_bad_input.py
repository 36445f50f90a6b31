"""Bad input: every run, ``--env`` and ``--option`` value (and every TOML value) is parsed to its
option's declared type, within its declared bounds, or refused with one line, ``error: ...``, exit
status 2, before anything is built or written; so is a run that cannot fit in memory. A property
test generates bad values for every option: text of another type, and values beyond its bounds."""
from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Literal, get_args, get_origin

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from algorithms import REGISTRY
from envs import ConfigError, ForagingConfig
from lifelong_evo import loop, memory
from lifelong_evo.commands.cli import build_parser, main
from lifelong_evo.commands.flags import resolve_run_config
from lifelong_evo.config import RunConfig, resolve
from lifelong_evo.options import Bounds, parse_value, schema, unbounded

ROOT = Path(__file__).resolve().parents[1]
BOOLEANS = {"true": True, "yes": True, "on": True, "1": True, "false": False, "no": False, "off": False, "0": False}
"""The spelling of booleans the command line promises."""


@pytest.fixture(autouse=True)
def nothing_runs(monkeypatch):
    """A refused value must be refused before the loop builds anything."""
    def run(*args, **kwargs):
        raise AssertionError("the run started although its configuration is bad")
    monkeypatch.setattr(loop, "run", run)


def refused(argv: list[str], out: Path, capsys) -> str:
    """``main(argv)`` exits 2 with one ``error:`` line, writing nothing under ``out``; the line."""
    code = main([*argv, "--preset", "smoke", "--no-record", "--quiet", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 2, captured
    assert captured.out == "" and captured.err.startswith("error: ") and captured.err.count("\n") == 1, captured.err
    assert not out.exists(), "a refused run leaves no run directory"
    return captured.err


def configured(*argv: str) -> RunConfig:
    return resolve_run_config(build_parser().parse_args(["run", *argv, "--preset", "smoke"]))


# ------------------------------------------------------------------------------------------ parsing

@given(st.sampled_from(sorted(BOOLEANS)).flatmap(
    lambda word: st.tuples(st.just(word), st.lists(st.booleans(), min_size=len(word), max_size=len(word)))))
def test_booleans_are_the_listed_words_in_any_case(case):
    word, upper = case
    text = "".join(c.upper() if u else c for c, u in zip(word, upper))
    assert parse_value(bool, f" {text} ") is BOOLEANS[word]


def test_no_means_off():
    """The issue's silent bug: ``--env see_other_agents=no`` ran with agents that see each other."""
    env = configured("--env", "see_other_agents=no", "--env", "repositioning=OFF").env_config()
    assert env.see_other_agents is False and env.repositioning is False
    assert configured("--env", "see_other_agents=Yes").env_config().see_other_agents is True


def test_values_get_their_declared_types():
    config = configured("--algo", "openai-es", "--reg", "2", "--env", "size=24", "--env", "colors=[3,4,5,6]",
                        "--option", "hidden=[32, 16]", "--option", "sigma=1", "--option", "importance=ewc")
    assert config.reg == 2.0 and isinstance(config.reg, float)
    assert config.env["size"] == 24.0 and isinstance(config.env["size"], float)
    assert config.env["colors"] == (3, 4, 5, 6)
    assert config.algo_options == {"hidden": (32, 16), "sigma": 1.0, "importance": "ewc"}
    assert configured("--algo", "snes", "--option", "hidden=[]").algo_options["hidden"] == ()
    assert configured("--algo", "snes", "--option", "hidden=8").algo_options["hidden"] == (8,)


def test_toml_values_follow_the_same_rule():
    config = resolve("smoke", {"algo": "cmaes", "reg": 1, "env": {"see_other_agents": "no", "size": 24},
                               "algo_options": {"hidden": [8, 8], "sigma": 1}})
    assert config.reg == 1.0 and config.env["see_other_agents"] is False and config.env["size"] == 24.0
    assert config.algo_options == {"hidden": (8, 8), "sigma": 1.0}
    for values, message in (({"env": {"repositioning": "nah"}}, "--env repositioning: 'nah' is not a boolean"),
                            ({"population": 2.5}, "--population: 2.5 is not an integer"),
                            ({"compile": 1}, "--compile: 1 is not a boolean"),
                            ({"algo": "openai-es", "algo_options": {"hidden": [8.5]}}, "--option hidden"),
                            # a TOML number where the choice is a word that looks like one
                            ({"algo_options": {"genetics": 0.92}},
                             '--option genetics: 0.92 is not one of 0.92, 2.0: write it in quotes, "0.92"'),
                            ({"env": 5}, "env in the config file must be a table")):
        with pytest.raises(ConfigError, match=re.escape(message)):
            resolve("smoke", values)


# -------------------------------------------------------------------------------- the cases

CUDA = torch.cuda.is_available()


@pytest.mark.parametrize("argv, message", [
    (["--env", "see_other_agents=nah"], "--env see_other_agents: 'nah' is not a boolean: true/false, yes/no"),
    (["--env", "repositioning=nah"], "--env repositioning: 'nah' is not a boolean"),
    (["--option", "nosuchkey=1"], "unknown neat option 'nosuchkey': the neat options are references, "),
    (["--option", "sigma=0.05"], "python -m lifelong_evo options --algo neat describes them"),
    (["--algo", "openai-es", "--option", "sigma=-1"], "--option sigma: '-1' is not a finite number > 0 and <= 1000"),
    (["--algo", "openai-es", "--option", "hidden=abc"], "--option hidden: 'abc' is not a list of at most 16 integers"),
    (["--algo", "openai-es", "--option", "hidden=[0]"], "--option hidden: '[0]' is not a list of at most 16 integers "
                                                        "from 1 to 4096"),
    (["--algo", "openai-es", "--option", "importance=foo"], "--option importance: 'foo' is not one of l2, ewc"),
    (["--env", "duration=abc"], "--env duration: 'abc' is not an integer"),
    (["--env", "size=abc"], "--env size: 'abc' is not a finite number"),
    (["--device", "nonsense"], "--device 'nonsense' is not a torch device"),
    (["--device", "cuda:99"], "--device cuda:99: this machine has"),
    pytest.param(["--device", "cuda"], "--device cuda: this machine has no CUDA device",
                 marks=pytest.mark.skipif(CUDA, reason="this machine has CUDA")),
    (["--cuda-graphs"], "--cuda-graphs needs --device cuda, not 'cpu': drop --cuda-graphs or run on a GPU"),
    (["--algo", "openai-es", "--population", "21"], "the population must be even, got 21"),
    (["--population", "abc"], "argument --population: 'abc' is not an integer"),
    (["--option", "references"], "--option 'references' is not KEY=VALUE"),
    # each family refuses the regularisers it cannot apply, and a synonym that says otherwise
    (["--algo", "sep-cmaes", "--regulariser", "wp"], "--regulariser 'wp': sep-cmaes applies l2, ewc, functional"),
    (["--regulariser", "l2"], "--regulariser 'l2': neat applies gd, wp, functional"),
    (["--algo", "snes", "--regulariser", "ewc", "--option", "importance=l2"],
     "--regulariser 'ewc' and --option importance=l2 choose different regularisers: give one of them"),
    # the functional regulariser too: such an option made two configurations of one run (ewc: its bookkeeping for
    # nothing)
    (["--regulariser", "functional", "--option", "penalty=wp"],
     "--regulariser 'functional' and --option penalty=wp choose different regularisers: give one of them"),
    (["--algo", "openai-es", "--regulariser", "functional", "--option", "importance=ewc"],
     "--regulariser 'functional' and --option importance=ewc choose different regularisers: give one of them"),
    # an option that only another regulariser reads (Optimizer.options_used_by)
    (["--option", "lambda_2=0.5"], "--option lambda_2=0.5 is read only by --regulariser wp, and this run's is 'gd': "
                                   "drop the option, or give --regulariser wp"),
    # lambda_2 weighs weight protection's penalty beside lambda_1 (--reg): at --reg 0 it would promise a penalty that
    # no run applies (a lambda-0 run is fine-tuning), its default stated included
    (["--regulariser", "wp", "--reg", "0", "--option", "lambda_2=0.5"],
     "--option lambda_2=0.5 weighs --regulariser wp's penalty beside lambda, and at --reg 0 no regulariser plays (the "
     "run is fine-tuning): give --reg above 0, or drop the option"),
    (["--option", "penalty=wp", "--option", "lambda_2=0.3"], "--option lambda_2=0.3 weighs --regulariser wp's penalty"),
    (["--regulariser", "functional", "--option", "references=2"],
     "--option references=2 is read only by --regulariser gd or wp, and this run's is 'functional': drop the option, "
     "or give --regulariser gd"),
    (["--config", "."], "cannot be read"),
    # the overflows: each gave a traceback after config.json and metrics.csv were written
    (["--seed", str(10**23)], "argument --seed: '100000000000000000000000' is not an integer from 0 to 4294967295"),
    (["--seed", str(2**32)], "is not an integer from 0 to 4294967295"),
    (["--seed", "-1"], "is not an integer from 0 to 4294967295"),
    (["--env", f"duration={10**23}"], "--env duration: '100000000000000000000000' is not an integer from 1 to 100000"),
    (["--env", f"max_retrieves={10**23}"], "--env max_retrieves: '100000000000000000000000' is not an integer from 1 "),
    (["--algo", "openai-es", "--option", f"hidden=[{10**23}]"], "--option hidden: '[100000000000000000000000]' is not "
                                                                "a list of at most 16 integers from 1 to 4096"),
    (["--env", "n_neighbors=1000000"], "--env n_neighbors: '1000000' is not an integer from 1 to 100"),
    (["--schedule", f"red:{10**23}"], "every task of schedule 'red:100000000000000000000000' needs from 1 to 1000000 "
                                      "generations"),
    (["--reg", "1e300"], "argument --reg: '1e300' is not a finite number from 0 to 1e9"),
    # digits are ASCII's everywhere: a schedule's count took any script's, --seed did not
    (["--seed", "٤٢"], "argument --seed: '٤٢' is not an integer"),
    (["--schedule", "red:١٠"], "bad generation count '١٠' in schedule item 'red:١٠': write it in the digits 0-9"),
    (["--schedule", "red:５"], "bad generation count '５'"),
    # a key given twice kept its last value
    (["--env", "duration=30", "--env", "duration=40"], "--env duration is given twice (duration=30 and duration=40): "
                                                       "give it once"),
    (["--option", "references=2", "--option", "references=2"], "--option references is given twice"),
    # NEAT keeps 5 genomes per species (elitism): population 1 was a traceback after config.json was written
    (["--population", "1"], "--population: NEAT with genetics 0.92 needs a population of at least 5 (every species "
                            "keeps its 5 best genomes: elitism in algorithms/neat/config.ini), got 1"),
    (["--population", "9", "--option", "genetics=2.0"], "NEAT with genetics 2.0 needs a population of at least 10 "
                                                        "(room for two species of 5 genomes"),
    # a population whose first speciation alone would take terabytes: memory grew with no output
    (["--population", "1000000"], "needs about "),
    # a word before the options is a verb: a misspelt one was "unrecognized arguments", the benchmark's verb-like
    # name too (it is a module of its own)
    (["swep", "--config", "examples/sweep.toml"], "unknown verb 'swep': the verbs are run, replay, view, plot, "
                                                  "compare, score, sweep, options; did you mean sweep?"),
    (["bench", "--algo", "neat"], "unknown verb 'bench': the verbs are run, replay, view, plot, compare, score, "
                                  "sweep, options; the benchmark is a module of its own: python -m lifelong_evo.bench"),
])
def test_each_is_one_line_before_anything_is_written(argv, message, tmp_path, capsys):
    assert message in refused(argv, tmp_path / "runs", capsys)


def test_a_config_file_that_is_not_utf8_is_one_line(tmp_path, capsys):
    path = tmp_path / "latin1.toml"
    path.write_bytes("seed = 1\n# r\xe9glage\n".encode("latin-1"))
    assert f"config file {path} is not UTF-8 text (byte 12 cannot be decoded): save it as UTF-8" in refused(
        ["--config", str(path)], tmp_path / "runs", capsys)


def test_bounds_are_listed_and_in_help(capsys):
    assert main(["options", "--algo", "openai-es"]) == 0
    assert "(a list of at most 16 integers from 1 to 4096, written [a,b,...])" in " ".join(capsys.readouterr().out.split())
    assert main(["options"]) == 0
    listed = " ".join(capsys.readouterr().out.split())
    assert "duration=500 Steps per episode. (an integer from 1 to 100000)" in listed
    assert "sensitivity=0.5 Pick-up radius (strict), in (0, 0.5]. (a finite number > 0 and <= 0.5)" in listed
    assert main(["--help"]) == 0
    assert "(an integer from 0 to 4294967295; default: 42)" in " ".join(capsys.readouterr().out.split())


def test_the_seed_bound_keeps_training_streams_below_the_held_out_ones():
    """Held-out episodes draw from generators seeded from 2**63 up; recorded episodes use
    seed * 1_000_003 + generation: the largest seed and generation stay below."""
    seed_max = unbounded(schema(RunConfig)["seed"])[1].max
    generations_max = unbounded(schema(RunConfig)["generations"])[1].max
    assert seed_max == 2**32 - 1
    assert seed_max * 1_000_003 + generations_max * 100 < 2**63


# ------------------------------------------------------------------------------------- memory check

def configured_for(*argv: str, preset: str = "paper") -> RunConfig:
    return resolve_run_config(build_parser().parse_args(["run", *argv, "--preset", preset]))


def test_the_paper_and_the_smoke_preset_fit_a_few_gigabytes(monkeypatch):
    monkeypatch.setattr(memory, "available", lambda: 3 * 2**30)
    for config in (configured_for(), configured_for("--eval-threads", "2", "--schedule", "four-tasks"),
                   configured_for("--algo", "sep-cmaes"), configured_for(preset="smoke")):
        memory.check([config])
    assert memory.estimate(configured_for()).total < 2 * 2**30


def test_a_run_that_cannot_fit_is_refused_and_the_flag_overrides(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(memory, "available", lambda: 200 * 2**20)
    err = refused([], tmp_path / "runs", capsys)
    assert re.fullmatch(r"error: this run needs about \d+ MiB of memory \(most of it for .*\) and this machine has "
                        r"200 MiB available: lower --population, .* or pass --no-memory-check to run anyway\n", err), err
    with pytest.raises(AssertionError, match="the run started"):  # loop.run is reached: nothing refused it
        main(["--preset", "smoke", "--no-record", "--quiet", "--out", str(tmp_path / "runs"), "--no-memory-check"])


def test_a_sweep_that_cannot_fit_is_refused_before_it_writes(monkeypatch, tmp_path, capsys):
    from lifelong_evo.commands import sweep

    out = tmp_path / "sweeps"
    argv = ["sweep", "--preset", "smoke", "--seed", "1,2,3", "--no-record", "--out", str(out), "--name", "s"]
    one = memory.estimate(configured_for("--no-record", preset="smoke")).total
    monkeypatch.setattr(memory, "available", lambda: one + 2**20)  # room for one trial, not for three in one process
    assert main([*argv, "--together", "--eval-threads", "1"]) == 2
    assert re.search(r"^error: --together with 3 trial\(s\) needs about \d+ MiB of memory", capsys.readouterr().err, re.M)
    monkeypatch.setattr(memory, "available", lambda: one - 2**20)
    assert main([*argv, "--workers", "1"]) == 2
    assert re.search(r"^error: the sweep, with 1 trial\(s\) at once, needs about", capsys.readouterr().err, re.M)
    assert not out.exists()
    # on a cluster each trial checks the node it lands on, and fails with the line
    result = sweep.run_trial(configured_for(preset="smoke").to_dict(), str(tmp_path / "trial"), False)
    assert result["status"] == "failed" and result["error"].startswith("UserError: trial trial needs about ")
    assert not (tmp_path / "trial").exists()


def test_on_a_gpu_the_arenas_are_checked_against_its_free_memory(monkeypatch):
    """No GPU here: the device's free memory is stood in for (torch.cuda.mem_get_info on one)."""
    from dataclasses import replace

    config = replace(configured_for("--population", "3000"), device="cuda")
    needs = memory.estimate(config)
    assert needs.host() == needs.shared + needs.recording < needs.total
    monkeypatch.setattr(memory, "available", lambda: 64 * 2**30)
    monkeypatch.setattr(memory, "device_free", lambda device: 2**30)
    with pytest.raises(memory.UserError, match=r"needs about [\d.]+ GiB of memory on cuda and it has 1.0 GiB free"):
        memory.check([config])
    monkeypatch.setattr(memory, "device_free", lambda device: 80 * 2**30)
    memory.check([config])


@pytest.mark.parametrize("argv, grows", [
    (["--population", "200"], ["--population", "400"]),
    (["--evals", "2"], ["--evals", "20"]),
    (["--env", "n_agents=5"], ["--env", "n_agents=50"]),
    (["--env", "n_boxes=20"], ["--env", "n_boxes=200", "--env", "size=60"]),
    (["--env", "n_neighbors=3"], ["--env", "n_neighbors=30"]),
    (["--algo", "cmaes", "--option", "hidden=[16]"], ["--algo", "cmaes", "--option", "hidden=[128]"]),
    (["--env", "duration=200"], ["--env", "duration=20000"]),
    (["--schedule", "red-green-red"], ["--schedule", "four-tasks"]),
])
def test_the_estimate_grows_with_what_a_run_holds(argv, grows):
    assert memory.estimate(configured_for(*grows, preset="smoke")).total > memory.estimate(
        configured_for(*argv, preset="smoke")).total


PEAK = """import resource, sys
from lifelong_evo.commands.cli import main
code = main(sys.argv[1:])
print(code, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
"""


@pytest.mark.parametrize("argv", [[], ["--algo", "cmaes", "--option", "hidden=[128]", "--population", "60"],
                                  ["--algo", "openai-es", "--env", "n_neighbors=100", "--population", "200",
                                   "--evals", "4"]])
def test_the_estimate_is_above_the_real_peak(argv, tmp_path, monkeypatch):
    """The calibration, kept honest: a real run's peak resident memory (``ru_maxrss``) stays below
    what the check expects (each run in its own process, one generation per task: both tasks are
    scored at once in each, as at a task end; the peak does not depend on the episode length)."""
    argv = [*argv, "--schedule", "red:1,green:1", "--env", "duration=20"]  # two tasks scored at once, briefly
    result = subprocess.run([sys.executable, "-c", PEAK, *argv, "--preset", "smoke", "--quiet", "--out", str(tmp_path),
                             "--name", "x"], capture_output=True, text=True, cwd=ROOT,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=600)
    code, peak = result.stdout.split()[-2:]
    assert code == "0", result.stderr
    assert int(peak) < memory.estimate(configured_for(*argv, preset="smoke")).total


@pytest.mark.parametrize("argv, message", [
    (["--retries", str(10**20)], "argument --retries: '100000000000000000000' is not an integer from 0 to 100"),
    (["--workers", "0"], "argument --workers: '0' is not an integer from 1 to 100000"),
    (["--gpus-per-trial", "1e300"], "argument --gpus-per-trial: '1e300' is not a finite number from 0 to 1024"),
])
def test_the_sweeps_own_numbers_are_bounded_too(argv, message, tmp_path, capsys):
    assert main(["sweep", *argv, "--preset", "smoke", "--out", str(tmp_path / "sweeps"), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {message}") and err.count("\n") == 1, err


@pytest.mark.parametrize("device", [[], ["--device", "cpu"]], ids=["no-device", "device-cpu"])
def test_gpus_per_trial_without_cuda_says_to_drop_it(device, tmp_path, monkeypatch, capsys):
    """``--gpus-per-trial 1`` without CUDA said "use --device cpu", which then said "drop --device or
    set it to cuda": neither is the fix. Each names --gpus-per-trial, and without it the sweep runs."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    sweep = ["sweep", "--preset", "smoke", "--out", str(tmp_path / "sweeps"), "--dry-run", *device]
    assert main([*sweep, "--gpus-per-trial", "1"]) == 2
    captured = capsys.readouterr()
    assert captured.err == ("error: --gpus-per-trial 1 runs the trials on CUDA, and this machine has no CUDA device "
                            "that torch can use: drop --gpus-per-trial to run them on the CPU, or give --address of a "
                            "cluster with GPUs\n") and captured.out == "", captured
    assert not (tmp_path / "sweeps").exists()
    assert main(sweep) == 0


def test_gpus_per_trial_with_a_cpu_device_names_both_fixes(tmp_path, capsys):
    """On a cluster (or a CUDA machine), --device cpu and --gpus-per-trial contradict each other."""
    assert main(["sweep", "--preset", "smoke", "--out", str(tmp_path / "sweeps"), "--dry-run", "--device", "cpu",
                 "--gpus-per-trial", "0.5", "--address", "head:6379"]) == 2
    assert capsys.readouterr().err == ("error: --gpus-per-trial 0.5 runs the trials on CUDA, but --device is cpu: "
                                       "drop --gpus-per-trial to run them on cpu, or drop --device\n")
    assert not (tmp_path / "sweeps").exists()


def test_an_earlier_run_is_left_untouched(tmp_path, capsys):
    earlier = tmp_path / "runs" / "earlier"
    earlier.mkdir(parents=True)
    (earlier / "config.json").write_text("{}")
    code = main(["--env", "see_other_agents=nah", "--preset", "smoke", "--out", str(tmp_path / "runs"),
                 "--name", "earlier", "--overwrite", "--quiet", "--no-record"])
    assert code == 2 and capsys.readouterr().err.count("\n") == 1
    assert [p.name for p in earlier.iterdir()] == ["config.json"] and (earlier / "config.json").read_text() == "{}"


# ------------------------------------------------------------------------ bad values of every option

def _not_number(text: str) -> bool:
    try:
        return not abs(float(text)) < float("inf")
    except ValueError:
        return True


NOT_A = {
    bool: st.text().filter(lambda t: t.strip().lower() not in BOOLEANS),
    int: st.text().filter(lambda t: not re.fullmatch(r"\s*[+-]?[0-9]+\s*", t)),
    float: st.one_of(st.text().filter(_not_number), st.sampled_from(["nan", "inf", "-Infinity", "1e999"])),
    tuple[int, ...]: st.one_of(st.text(alphabet="abc.x -").filter(str.strip).map(lambda t: f"[{t}]"),  # [ ] is []
                               st.sampled_from(["", "[1,,2]", "[1.5]", "[1,true]", "[[1]]"])),
}
"""Text that no value of the type is written as."""

def _beyond(bounds) -> st.SearchStrategy:
    """Numbers outside ``bounds`` (an ``options.Bounds``), from just past them to absurd sizes."""
    sides = []
    if bounds.min is not None:
        sides.append(st.integers(max_value=math.ceil(bounds.min) - 1))
    if bounds.above is not None:
        sides.append(st.floats(max_value=bounds.above, min_value=-1e300))
    if bounds.max is not None:
        sides.append(st.integers(min_value=math.floor(bounds.max) + 1))
        sides.append(st.sampled_from([10**23, 2**63, 2**64]))  # past every tensor integer
        if not float(bounds.max).is_integer():
            sides.append(st.floats(min_value=bounds.max, max_value=1e300, exclude_min=True))
    return st.one_of(sides)


def _out_of_bounds(kind) -> st.SearchStrategy[str] | None:
    """Text of values of the right type that ``kind``'s declared bounds refuse (None: it has none)."""
    plain_kind, bounds = unbounded(kind)
    if bounds is None:
        return None
    if get_origin(plain_kind) is tuple:
        good = st.integers(min_value=int(bounds.min or 1), max_value=int(bounds.min or 1) + 3)
        bad_item = st.lists(_beyond(Bounds(bounds.min, bounds.max, bounds.above)), min_size=1, max_size=3)
        too_many = st.lists(good, min_size=bounds.max_items + 1, max_size=bounds.max_items + 3)
        return st.one_of(bad_item, too_many).map(lambda items: "[" + ",".join(map(str, items)) + "]")
    return _beyond(bounds).map(str)


SEMANTIC = {
    "population": st.integers(min_value=1, max_value=4),  # NEAT (the default algorithm) keeps 5 elites per species
    "n_boxes": st.integers(min_value=31, max_value=10_000),  # 30 fit 2 apart in 20 x 20
    "colors": st.lists(st.integers(min_value=3, max_value=10), min_size=1, max_size=5).filter(
        lambda c: c != list(range(3, 3 + len(c)))).map(lambda c: str(c)),
}
"""Values within the declared bounds that an option still refuses, for a reason of its own."""

TEXT = {
    "algo": st.text().filter(lambda t: t.strip() not in REGISTRY),
    "schedule": st.text(alphabet="xyz:,-0123456789", min_size=1).filter(lambda t: re.search("[xyz]", t)),
    "regulariser": st.text().filter(lambda t: t.strip() not in ("default", *REGISTRY["neat"].regularisers)),
    "device": st.sampled_from(["nonsense", "gpu", "cuda:99", "cpu:x", "", " "] + ([] if CUDA else ["cuda", "cuda:0"])),
}
"""Bad values of the run options that are text."""


def _bad(name: str, kind) -> st.SearchStrategy[str]:
    plain_kind = unbounded(kind)[0]
    if plain_kind is str:
        not_a = TEXT[name]
    elif get_origin(plain_kind) is Literal:
        not_a = st.text().filter(lambda t: t.strip() not in get_args(plain_kind))
    else:
        not_a = NOT_A[plain_kind]
    others = [s for s in (_out_of_bounds(kind), SEMANTIC.get(name)) if s is not None]
    return st.one_of(not_a, *(s.map(str) for s in others))


OPTIONS = [*((lambda v, n=n: [f"--{n.replace('_', '-')}={v}"], n, k) for n, k in schema(RunConfig).items()
             if unbounded(k)[0] not in (bool, dict)),
           *((lambda v, n=n: ["--env", f"{n}={v}"], n, k) for n, k in schema(ForagingConfig).items()),
           *((lambda v, n=n, a=a: ["--algo", a, "--option", f"{n}={v}"], n, k)
             for a in REGISTRY for n, k in schema(REGISTRY[a].Options).items())]
"""(argv for a value, option name, its type) of every run flag, environment and optimiser option."""


@pytest.mark.parametrize("argv, name, kind", OPTIONS, ids=[" ".join(o[0]("V")) for o in OPTIONS])
def test_every_bad_value_of_every_option_is_refused(argv, name, kind, tmp_path, capsys):
    @settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(_bad(name, kind))
    def check(value):
        refused(argv(value), tmp_path / "runs", capsys)
    check()


def test_every_option_has_a_bad_value_and_a_meaning():
    from lifelong_evo.options import field_docs

    names = {name for _, name, _ in OPTIONS}
    assert {"see_other_agents", "hidden", "references", "unconnected_outputs", "population"} <= names
    for cls in (RunConfig, ForagingConfig, *(c.Options for c in REGISTRY.values())):
        assert set(field_docs(cls)) == set(schema(cls)), f"{cls.__qualname__} has a field without a docstring"


# ------------------------------------------------------------------------------ the real command line

@pytest.mark.parametrize("argv", [["--env", "see_other_agents=nah"], ["--option", "sigma=0.05"],
                                  ["--device", "nonsense"]])
def test_the_real_command_line(argv, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    result = subprocess.run([sys.executable, "-m", "lifelong_evo", *argv, "--preset", "smoke", "--no-record",
                             "--out", str(tmp_path / "runs")],
                            capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.startswith("error: ") and result.stderr.count("\n") == 1, result.stderr
    assert not (tmp_path / "runs").exists()


def test_help_lists_every_option_with_its_default(capsys):
    assert main(["--help"]) == 0
    shown = capsys.readouterr().out
    assert "``" not in shown
    for expected in ("--population POPULATION", "default: 300)", "see_other_agents=false", "references=1",
                     "unconnected_outputs=zero", "cmaes, sep-cmaes options", "sigma=0.5", "openai-es options",
                     "learning_rate=0.03", "hidden=[16]"):
        assert expected in shown
    assert main(["options", "--algo", "neat"]) == 0
    listed = capsys.readouterr().out
    assert "references=1" in listed and "sigma" not in listed and "environment" not in listed

