"""Bad input: every run, ``--env`` and ``--option`` value (and every TOML value) is parsed to its
option's declared type or refused with one line, ``error: ...``, exit status 2, before anything is
built or written; a property test generates bad values for every option."""
from __future__ import annotations

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
from lifelong_evo import loop
from lifelong_evo.cli import build_parser, main
from lifelong_evo.config import RunConfig, resolve
from lifelong_evo.flags import resolve_run_config
from lifelong_evo.options import parse_value, schema

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
    (["--algo", "openai-es", "--option", "sigma=-1"], "--option sigma must be a number > 0, got -1.0"),
    (["--algo", "openai-es", "--option", "hidden=abc"], "--option hidden: 'abc' is not a list of integers"),
    (["--algo", "openai-es", "--option", "hidden=[0]"], "--option hidden must list integers >= 1"),
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
    (["--config", "."], "cannot be read"),
])
def test_each_is_one_line_before_anything_is_written(argv, message, tmp_path, capsys):
    assert message in refused(argv, tmp_path / "runs", capsys)


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

OUT_OF_RANGE = {
    **{name: st.integers(max_value=0) for name in ("generations", "population", "evals", "retention_every",
                                                    "checkpoint_every", "threads", "eval_threads", "n_agents",
                                                    "n_neighbors", "duration", "max_retrieves", "references")},
    "episodes_every": st.integers(max_value=-1),
    "n_boxes": st.one_of(st.integers(max_value=0), st.integers(min_value=31)),  # 30 fit 2 apart in 20 x 20
    "reg": st.floats(max_value=-1e-6, min_value=-1e9),
    "size": st.floats(max_value=7.99, min_value=-1e9),
    "rate_target": st.one_of(st.floats(max_value=-1e-6, min_value=-1e9), st.floats(min_value=1.001, max_value=1e9)),
    "sensitivity": st.one_of(st.floats(max_value=0, min_value=-1e9), st.floats(min_value=0.501, max_value=1e9)),
    **{name: st.floats(max_value=0, min_value=-1e9) for name in ("sensor_range", "max_wheel_velocity", "time_step",
                                                                 "sigma", "learning_rate")},
    "hidden": st.lists(st.integers(max_value=0), min_size=1, max_size=3).map(lambda h: str(h)),
    "colors": st.lists(st.integers(min_value=0, max_value=12), max_size=5).filter(
        lambda c: c != list(range(3, 3 + len(c))) or not c).map(lambda c: str(c)),
}
"""Values of the right type that each option refuses."""

TEXT = {
    "algo": st.text().filter(lambda t: t.strip() not in REGISTRY),
    "schedule": st.text(alphabet="xyz:,-0123456789", min_size=1).filter(lambda t: re.search("[xyz]", t)),
    "device": st.sampled_from(["nonsense", "gpu", "cuda:99", "cpu:x", "", " "] + ([] if CUDA else ["cuda", "cuda:0"])),
}
"""Bad values of the run options that are text."""


def _bad(name: str, kind) -> st.SearchStrategy[str]:
    if kind is str:
        not_a = TEXT[name]
    elif get_origin(kind) is Literal:
        not_a = st.text().filter(lambda t: t.strip() not in get_args(kind))
    else:
        not_a = NOT_A[kind]
    return st.one_of(not_a, OUT_OF_RANGE[name].map(str)) if name in OUT_OF_RANGE else not_a


OPTIONS = [*((lambda v, n=n: [f"--{n.replace('_', '-')}={v}"], n, k) for n, k in schema(RunConfig).items()
             if k not in (bool, dict)),
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
    for expected in ("--population POPULATION", "(default: 300)", "see_other_agents=false", "references=1",
                     "unconnected_outputs=zero", "cmaes, sep-cmaes options", "sigma=0.5", "openai-es options",
                     "learning_rate=0.03", "hidden=[16]"):
        assert expected in shown
    assert main(["options", "--algo", "neat"]) == 0
    listed = capsys.readouterr().out
    assert "references=1" in listed and "sigma" not in listed and "environment" not in listed

