"""The metrics.csv and species.csv contract on fixed inputs: a ``GenerationRecord`` becomes the
same bytes a run has always written (the headers are those of real NEAT and OpenAI-ES runs), and
a resumed log keeps only the generations its checkpoint covers. How config.json's settings group
runs into configurations and label them."""
from __future__ import annotations

import json
import math
import os
import shutil
import socket
import subprocess
from pathlib import Path

import pytest

from algorithms.neat.genetics import DEFAULT_GENETICS
from envs import ForagingConfig
from lifelong_evo.config import RunConfig
from lifelong_evo.errors import RunDirError
from lifelong_evo.metrics import FitnessStats, GenerationRecord, Retention
from lifelong_evo.metrics_csv import GenerationLog, MetricsLayout, retention_columns
from lifelong_evo.provenance import library_versions, source_commit
from lifelong_evo.run_lock import LOCK, RunDirInUseError
from lifelong_evo.rundir import MARKER, RunDir
from lifelong_evo.runs import Run, describe_config, group_runs

NEAT = MetricsLayout(("red", "green"), species=True, centre=False,
                     diagnostics=("distance_mean", "distance_std", "disabled_fraction"))
ES = MetricsLayout(("red", "green"), species=False, centre=True, diagnostics=("distance_mean", "distance_std"))


def record(generation: int, **changes) -> GenerationRecord:
    values = dict(task="green", task_index=1, generation=generation, generation_in_task=generation - 5,
                  fitness=FitnessStats(best=1.5, mean=-0.025, median=0.0, std=0.4866980583482947),
                  regularised=FitnessStats(best=1.0, mean=-0.075, median=0.0, std=0.3269174207655505), top=1.0,
                  retention={"red": Retention(pop=3.5, top=0.5, centre=-1.0)}, species_sizes={4: 8, 1: 12},
                  centre=0.25, diagnostics={"distance_mean": math.nan, "distance_std": math.nan,
                                            "disabled_fraction": 0.006368393627778321, "stdev_mean": 0.1})
    return GenerationRecord(**{**values, **changes})


def test_a_record_is_the_row_runs_have_always_written(tmp_path):
    run_dir = RunDir(tmp_path)
    log = GenerationLog(run_dir.path, NEAT, resumed_at=None)
    log.write(record(7))
    log.write(record(8, retention={}))
    log.close()
    assert run_dir.metrics.read_text() == (
        "task,task_index,generation,generation_in_task,best,mean,median,std,reg_best,reg_mean,reg_median,reg_std,"
        "top,species,distance_mean,distance_std,disabled_fraction,retention_pop_red,retention_top_red,"
        "retention_pop_green,retention_top_green\n"
        "green,1,7,2,1.5,-0.025,0.0,0.4866980583482947,1.0,-0.075,0.0,0.3269174207655505,1.0,2,,,"
        "0.006368393627778321,3.5,0.5,,\n"
        "green,1,8,3,1.5,-0.025,0.0,0.4866980583482947,1.0,-0.075,0.0,0.3269174207655505,1.0,2,,,"
        "0.006368393627778321,,,,\n")
    assert run_dir.species.read_text() == "generation,species_id,size\n7,1,12\n7,4,8\n8,1,12\n8,4,8\n"


def test_an_es_row_has_the_centre_and_only_declared_diagnostics(tmp_path):
    run_dir = RunDir(tmp_path)
    log = GenerationLog(run_dir.path, ES, resumed_at=None)
    log.write(record(7, species_sizes=None))
    log.close()
    header, row = run_dir.metrics.read_text().splitlines()
    assert header == ("task,task_index,generation,generation_in_task,best,mean,median,std,reg_best,reg_mean,"
                      "reg_median,reg_std,top,centre,distance_mean,distance_std,retention_pop_red,retention_top_red,retention_centre_red,"
                      "retention_pop_green,retention_top_green,retention_centre_green")
    assert row == "green,1,7,2,1.5,-0.025,0.0,0.4866980583482947,1.0,-0.075,0.0,0.3269174207655505,1.0,0.25,,,3.5,0.5,-1.0,,,"
    assert not run_dir.species.exists()


def test_every_layout_fills_only_its_own_columns():
    for layout in (NEAT, ES, MetricsLayout(("red",), species=False, centre=False)):
        assert set(layout.row(record(7))) <= set(layout.columns)
        assert retention_columns(layout.columns, "pop") == {t: f"retention_pop_{t}" for t in layout.tasks}


def test_a_resumed_log_keeps_the_generations_its_checkpoint_covers(tmp_path):
    run_dir = RunDir(tmp_path)
    log = GenerationLog(run_dir.path, NEAT, resumed_at=None)
    for generation in (5, 6, 7):
        log.write(record(generation))
    log.close()
    whole = run_dir.metrics.read_text()
    with open(run_dir.metrics, "a") as handle:
        handle.write("green,1,8,3,1.5")  # a killed run's half line
    log = GenerationLog(run_dir.path, NEAT, resumed_at=7)
    log.write(record(7))
    log.close()
    assert run_dir.metrics.read_text() == whole
    assert run_dir.species.read_text().splitlines()[-1] == "7,4,8"


def _config(algo="neat", seed=1, given=None, resolved=True, env=None, **settings):
    """A config.json as a run writes it (``resolved=False``: as runs wrote it before
    ``algo_options_resolved`` existed)."""
    config = RunConfig(algo=algo, seed=seed, algo_options=given or {}, env=env or {}, **settings)
    written = {**config.to_dict(), "env_resolved": config.env_config().to_dict(), "versions": {"torch": "x"}}
    if resolved:
        written["algo_options_resolved"] = config.algo_options_resolved()
    return written


def _groups(configs):
    runs = [Run(path=Path(f"run{i}"), config=c, summary={}) for i, c in enumerate(configs)]
    return [[int(r.path.name[3:]) for r in group] for group in group_runs(runs)]


def test_a_default_stated_or_left_out_is_one_configuration():
    stated, implicit = _config(seed=1, given={"genetics": DEFAULT_GENETICS}), _config(seed=2)
    other = _config(seed=3, given={"genetics": "2.0"})
    assert stated["algo_options_resolved"] == implicit["algo_options_resolved"] != other["algo_options_resolved"]
    assert _groups([stated, implicit, other]) == [[0, 1], [2]]
    # the environment too: a stated default is no new configuration, another value is
    env_default = _config(seed=4, env={"n_agents": ForagingConfig().n_agents})
    env_other = _config(seed=5, env={"see_other_agents": True})
    assert _groups([implicit, env_default, env_other]) == [[0, 1], [2]]


def test_runs_written_before_resolved_options_keep_their_options_as_given():
    """Such a run may have run with another default (NEAT's genetics was 2.0's), so it is never
    merged with today's runs on a guess."""
    old = _config(seed=1, resolved=False)
    assert _groups([old, _config(seed=2), _config(seed=3, resolved=False)]) == [[0, 2], [1]]


def test_without_a_regulariser_its_options_make_no_configuration():
    """At lambda 0 the importance and the reference change no controller (test_lifelong_run), so
    an unregularised run is labelled and grouped without them; at lambda > 0 they set runs apart."""
    none_l2 = _config(algo="sep-cmaes", reg=0.0)
    none_ewc = _config(algo="sep-cmaes", seed=2, reg=0.0, given={"importance": "ewc", "reference": "best"})
    l2, ewc = (_config(algo="sep-cmaes", reg=100.0, given={"importance": i}) for i in ("l2", "ewc"))
    neat_one, neat_three = _config(reg=0.0), _config(seed=2, reg=0.0, given={"references": 3})
    configs = [none_l2, none_ewc, l2, ewc, neat_one, neat_three, _config(reg=11.0, given={"references": 3})]
    assert _groups(configs) == [[0, 1], [2], [3], [4, 5], [6]]
    assert [describe_config(c, configs) for c in (none_ewc, l2, ewc, neat_one)] == [
        "sep-cmaes reg=0 red-green-red", "sep-cmaes reg=100 red-green-red regulariser=l2",
        "sep-cmaes reg=100 red-green-red regulariser=ewc", "neat reg=0 red-green-red"]
    # a sweep over lambda with one importance: nothing to name but lambda
    over_lambda = [none_l2, l2, _config(algo="sep-cmaes", reg=10.0)]
    assert [describe_config(c, over_lambda) for c in over_lambda] == [
        "sep-cmaes reg=0 red-green-red", "sep-cmaes reg=100 red-green-red", "sep-cmaes reg=10 red-green-red"]


def test_labels_name_what_sets_a_configuration_apart():
    neat_092, neat_20 = _config(), _config(given={"genetics": "2.0"})
    es, es_sigma = _config(algo="openai-es"), _config(algo="openai-es", given={"sigma": 0.05})
    seen = _config(env={"see_other_agents": True})
    configs = [neat_092, neat_20, es, es_sigma, seen]
    labels = [describe_config(c, configs) for c in configs]
    assert labels == ["neat reg=0 red-green-red genetics=0.92 env.see_other_agents=False",
                      "neat reg=0 red-green-red genetics=2.0 env.see_other_agents=False",
                      "openai-es reg=0 red-green-red sigma=0.1 env.see_other_agents=False",
                      "openai-es reg=0 red-green-red sigma=0.05 env.see_other_agents=False",
                      "neat reg=0 red-green-red genetics=0.92 env.see_other_agents=True"]
    assert describe_config(neat_092, [neat_092, _config(seed=9)]) == "neat reg=0 red-green-red"


def test_labels_name_a_baseline_only_where_it_is_on():
    """Fine-tuning keeps the plain label beside its baselines, and each baseline names only its
    own setting (not every other one off), so the labels stay apart and short."""
    fine_tune, regulariser = _config(), _config(reg=11.0)
    baselines = [_config(rehearsal=0.3), _config(joint=True), _config(from_scratch=True),
                 _config(reg=11.0, reference_every=50)]
    configs = [fine_tune, regulariser, *baselines]
    assert [describe_config(c, configs) for c in configs] == [
        "neat reg=0 red-green-red", "neat reg=11 red-green-red", "neat reg=0 red-green-red rehearsal=0.3",
        "neat reg=0 red-green-red joint=True", "neat reg=0 red-green-red from_scratch=True",
        "neat reg=11 red-green-red reference_every=50"]


# ------------------------------------------------------------------------ names, marker and lock

@pytest.mark.parametrize("name", ["neat-red-green-red-reg11-seed42", "my run", "a.b", "...", ".hidden", "-x"])
def test_a_run_name_is_any_one_folder_name(tmp_path, name):
    assert RunDir.inside(tmp_path, name).path == tmp_path / name


@pytest.mark.parametrize("name", ["", ".", "..", "a/b", "../x", "/abs", "a\\b", "a\0b", 7])
def test_a_run_name_that_is_not_one_folder_name_is_refused(tmp_path, name):
    with pytest.raises(RunDirError, match="is not one folder name"):
        RunDir.inside(tmp_path, name)


def test_one_process_holds_a_run_directory(tmp_path):
    run = RunDir(tmp_path / "run")
    lock = run.create(overwrite=False)
    assert sorted(p.name for p in run.path.iterdir()) == sorted([LOCK, MARKER, "checkpoints", "controllers"])
    holder = f"process {os.getpid()} on host {socket.gethostname()}"
    assert run.in_use_by() == holder
    for taken in (run.lock, lambda: run.create(overwrite=True)):
        with pytest.raises(RunDirInUseError, match=f"is in use by {holder}"):
            taken()
    lock.release()
    assert run.in_use_by() is None and (run.lock_file).read_text() == ""
    with run.lock():
        assert run.in_use_by() == holder


# ------------------------------------------------------------------------------ the code's commit

def _git(folder: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(folder), "-c", "user.name=t", "-c", "user.email=t@t", *args],
                          capture_output=True, text=True, check=True).stdout.strip()


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_a_run_names_the_commit_of_the_code_it_imports(tmp_path):
    repo = tmp_path / "repo"
    package = repo / "lifelong_evo"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("X = 1\n")
    (repo / "notes.md").write_text("a\n")
    _git(repo, "init", "-q")
    _git(repo, "add", ".")
    _git(repo, "commit", "-q", "-m", "first")
    head = _git(repo, "rev-parse", "HEAD")
    assert source_commit(package) == head
    (repo / "notes.md").write_text("b\n")  # not the toolkit's code
    assert source_commit(package) == head
    (package / "__init__.py").write_text("X = 2\n")
    assert source_commit(package) == f"{head} + local changes"
    # an installed copy inside a checkout (a venv's site-packages) is not that checkout's code
    installed = repo / ".venv" / "lifelong_evo"
    shutil.copytree(package, installed)
    assert source_commit(installed) == "unknown"
    assert source_commit(tmp_path) == "unknown"
    # this very checkout, as a run writes it into config.json
    here = Path(__file__).resolve().parents[1]
    if (here / ".git").exists():
        assert library_versions()["lifelong-evo-commit"].split(" + ")[0] == _git(here, "rev-parse", "HEAD")


def written(**stated) -> dict:
    """config.json of a run stated as ``stated`` (``configure``'s keys)."""
    from lifelong_evo.config import configure

    config = configure(stated, machine=False)
    return {**config.to_dict(), "env_resolved": config.env_config().to_dict(),
            "algo_options_resolved": config.algo_options_resolved(), "versions": {"torch": "x"}}


def test_the_regulariser_is_one_setting_its_synonym_included():
    """``--regulariser ewc`` and ``--option importance=ewc`` are one configuration, named by the
    regulariser; a config.json written before the setting existed ran its family's default (NEAT
    gd, an ES l2 or its importance); at lambda 0 the regulariser is no setting."""
    synonym = written(algo="sep-cmaes", reg=1.0, seed=1, algo_options={"importance": "ewc"})
    named = written(algo="sep-cmaes", reg=1.0, seed=2, regulariser="ewc")
    assert synonym["regulariser"] == named["regulariser"] == "ewc"
    assert synonym["algo_options"] == named["algo_options"] == {"importance": "ewc"}
    old_ewc, old_l2, old_neat = (_config(seed=3, algo="sep-cmaes", reg=1.0, given={"importance": "ewc"}),
                                 _config(seed=4, algo="sep-cmaes", reg=1.0), _config(seed=5, reg=1.0))
    for old in (old_ewc, old_l2, old_neat):
        del old["regulariser"]
    gd, wp = written(reg=1.0, seed=6), written(reg=1.0, seed=7, regulariser="wp")
    assert gd["regulariser"] == "gd" and wp["algo_options"] == {"penalty": "wp"}
    functional = written(algo="sep-cmaes", reg=1.0, seed=8, regulariser="functional")
    configs = [synonym, named, old_ewc, old_l2, old_neat, gd, wp, functional]
    assert _groups(configs) == [[0, 1, 2], [3], [4, 5], [6], [7]]
    assert [describe_config(c, configs) for c in (named, wp, functional)] == [
        "sep-cmaes reg=1 red-green-red regulariser=ewc", "neat reg=1 red-green-red regulariser=wp",
        "sep-cmaes reg=1 red-green-red regulariser=functional"]
    at_zero = [written(reg=0.0, seed=1), written(reg=0.0, seed=2, regulariser="wp"), written(reg=0.0, seed=3, regulariser="functional")]
    assert _groups(at_zero) == [[0, 1, 2]]
    assert RunConfig.regulariser_of(old_ewc) == "ewc" and RunConfig.regulariser_of(old_neat) == "gd"


def test_a_label_names_a_regulariser_other_than_the_familys_default_and_only_the_options_it_reads():
    """One configuration per family: the rows of NEAT's and sep-CMA-ES's functional runs both say
    so (a label named the regulariser only among runs of one algorithm), and so do a NEAT wp and an
    ES ewc row; a family's default stays unnamed. A functional row names no ``lambda_2`` or
    ``references`` that only wp (and gd) read, though the runs beside it have other ones (labels
    compare the options as resolved, defaults filled in). ``plot``'s file prefix names the
    regulariser as run names do, so a wp and a gd run at one lambda no longer write the same files."""
    from lifelong_evo.analysis.figures import slug
    from lifelong_evo.runs import config_differences

    def labels(configs):
        return [describe_config(c, configs) for c in configs]

    functional = [written(reg=1.0, regulariser="functional"), written(algo="sep-cmaes", reg=1.0, regulariser="functional")]
    assert labels(functional) == ["neat reg=1 red-green-red regulariser=functional",
                                  "sep-cmaes reg=1 red-green-red regulariser=functional"]
    assert labels([written(reg=1.0, regulariser="wp"), written(algo="sep-cmaes", reg=1.0, regulariser="ewc")]) == [
        "neat reg=1 red-green-red regulariser=wp", "sep-cmaes reg=1 red-green-red regulariser=ewc"]
    assert labels([written(reg=1.0), written(algo="sep-cmaes", reg=1.0)]) == ["neat reg=1 red-green-red",
                                                                             "sep-cmaes reg=1 red-green-red"]
    beside_wp = [functional[0], written(reg=1.0, regulariser="wp", algo_options={"lambda_2": 3.0}),
                 written(reg=1.0, regulariser="wp")]
    assert labels(beside_wp) == ["neat reg=1 red-green-red regulariser=functional",
                                 "neat reg=1 red-green-red lambda_2=3.0 regulariser=wp",
                                 "neat reg=1 red-green-red lambda_2=0.3 regulariser=wp"]
    assert labels([functional[0], written(reg=1.0, algo_options={"references": 2})]) == [
        "neat reg=1 red-green-red regulariser=functional", "neat reg=1 red-green-red references=2 regulariser=gd"]
    alone = [written(reg=0.4, regulariser="wp"), written(reg=0.4)]
    assert [slug(c, config_differences(c, [c])) for c in alone] == ["neat-red-green-red-wp-reg0.4",
                                                                    "neat-red-green-red-reg0.4"]
    assert slug(alone[0], config_differences(alone[0], alone)) == "neat-red-green-red-wp-reg0.4"


def test_an_option_added_since_a_run_was_written_is_its_default(tmp_path):
    """A config.json written before an optimiser's option existed (NEAT's ``lambda_2``,
    ``penalty``) resumes under the defaults, which keep its numbers; an option stated otherwise
    is a difference, against the default."""
    config = RunConfig(algo="neat", reg=11.0, generations=3)
    run = RunDir(tmp_path / "old")
    run.path.mkdir()
    run.write_config(config)
    written = json.loads(run.config.read_text())
    for name in ("lambda_2", "penalty"):
        del written["algo_options_resolved"][name]
    run.config.write_text(json.dumps(written))
    assert run.setting_differences(config.to_dict()) == []
    assert run.setting_differences({"regulariser": "wp", "algo_options": {"lambda_2": 0.5}}) == [
        "--regulariser 'wp' (stored: 'gd')", "--option lambda_2=0.5 (stored: 0.3)"]


@pytest.mark.parametrize("algo, table, key, recorded, default", [
    ("neat", "env", "sensor_range", 5.0, 4.0),
    ("sep-cmaes", "algo_options", "sigma", 2.0, 0.5),
])
def test_a_run_made_under_another_default_goes_on_with_it(tmp_path, algo, table, key, recorded, default):
    """A run whose config.json records an option it did not give at another value than today's
    default (the default changed since it was written) goes on with the recorded value: resumed
    without flags it is no difference (it was refused, naming a flag nobody gave), stating the
    recorded value is none either and keeps it (the run went on with today's default, silently),
    and stating today's default is the difference. A whole configuration (a sweep's trial) states
    its defaults: there the change is a difference."""
    run = RunDir(tmp_path / "old")
    run.path.mkdir()
    config = RunConfig(algo=algo, generations=3).validate(machine=False)
    run.write_config(config)
    written = json.loads(run.config.read_text())
    written[f"{table}_resolved"][key] = recorded
    run.config.write_text(json.dumps(written))
    flag = "--env" if table == "env" else "--option"

    def value(continued: RunConfig) -> float:
        return getattr(continued.env_config(), key) if table == "env" else continued.algo_options_resolved()[key]

    assert run.setting_differences({}) == []
    assert value(run.continuation({})) == recorded
    assert value(run.continuation({table: {key: recorded}})) == recorded
    assert run.setting_differences({table: {key: default}}) == [f"{flag} {key}={default} (stored: {recorded})"]
    assert run.setting_differences(config.to_dict()) == [f"{flag} {key}={default} (stored: {recorded})"]
    assert run.setting_differences(run.continuation({}).to_dict()) == []


def test_an_option_the_run_does_not_read_is_no_difference_when_its_default_changes(tmp_path):
    """A run under the genetic distance records weight protection's ``lambda_2``, which it never
    reads, at another value than today's default: it resumes, with nothing laid under its options
    (laying it under was refused as an option only ``wp`` reads, naming a flag nobody gave), and a
    whole configuration of it is no other configuration either."""
    run = RunDir(tmp_path / "gd")
    run.path.mkdir()
    config = RunConfig(algo="neat", reg=11.0, generations=3).validate(machine=False)
    run.write_config(config)
    written = json.loads(run.config.read_text())
    written["algo_options_resolved"]["lambda_2"] = 0.5
    run.config.write_text(json.dumps(written))
    assert run.setting_differences({}) == [] and run.setting_differences(config.to_dict()) == []
    continued = run.continuation({})
    assert continued.regulariser == "gd" and "lambda_2" not in continued.algo_options


def test_an_option_its_optimiser_normalises_is_resolved_as_written(tmp_path, monkeypatch):
    """config.json's resolved options hold what the optimiser's options made of the given ones: a
    custom optimiser whose options cap ``sigma`` writes 0.5 where 2.0 was given, and its run reads
    back (the check compared the given value with the resolved one and refused the run)."""
    from dataclasses import dataclass

    from algorithms import REGISTRY
    from algorithms.es import ESOptions

    @dataclass(frozen=True)
    class CappedOptions(ESOptions):
        def __post_init__(self):
            object.__setattr__(self, "sigma", min(self.sigma, 0.5))
            super().__post_init__()

    class Capped(REGISTRY["openai-es"]):
        name = "capped-es"
        Options = CappedOptions

    monkeypatch.setitem(REGISTRY, "capped-es", Capped)
    run = RunDir(tmp_path / "capped")
    run.path.mkdir()
    run.write_config(RunConfig(algo="capped-es", generations=3, algo_options={"sigma": 2.0}).validate(machine=False))
    assert json.loads(run.config.read_text())["algo_options_resolved"]["sigma"] == 0.5
    assert run.read_config().algo_options == {"sigma": 2.0}


def test_a_whole_configuration_leaves_out_only_defaults(tmp_path):
    """A whole configuration (every field: a sweep's trial, a run taking over a first task) states
    its options and environment whole: a key the run stored and it leaves out is at its default,
    a difference. Settings as a command states them (``--resume``) leave the stored ones be."""
    run = RunDir(tmp_path / "run")
    run.path.mkdir()
    run.write_config(RunConfig(algo="sep-cmaes", generations=3, env={"n_agents": 4},
                               algo_options={"sigma": 2.0}).validate(machine=False))
    whole = RunConfig(algo="sep-cmaes", generations=3).validate(machine=False).to_dict()
    assert run.setting_differences(whole) == ["--env n_agents=5 (stored: 4)", "--option sigma=0.5 (stored: 2.0)"]
    assert run.setting_differences({k: v for k, v in whole.items() if k not in ("env", "algo_options")}) == []
    assert run.setting_differences({"algo": "sep-cmaes", "generations": 3}) == []


@pytest.mark.parametrize("stored, stated, says", [
    # the stored wp's options were kept under the stated gd: the refusal named --option penalty=wp, never given
    (dict(regulariser="wp", algo_options={"lambda_2": 0.003}), {"regulariser": "gd"},
     ["--regulariser 'gd' (stored: 'wp')"]),
    (dict(regulariser="wp"), {"regulariser": "functional"}, ["--regulariser 'functional' (stored: 'wp')"]),
    (dict(algo="sep-cmaes", regulariser="ewc"), {"regulariser": "functional"},
     ["--regulariser 'functional' (stored: 'ewc')"]),
    (dict(algo_options={"references": 2}), {"regulariser": "functional"},
     ["--regulariser 'functional' (stored: 'gd')"]),
    # the stored regulariser stated, or default (the one the stored options choose): no difference
    (dict(regulariser="wp", algo_options={"lambda_2": 0.003}), {"regulariser": "wp"}, []),
    (dict(regulariser="wp", algo_options={"lambda_2": 0.003}), {"regulariser": "default"}, []),
    # an option stated beside it is named as stated
    (dict(regulariser="wp", algo_options={"lambda_2": 0.003}), {"regulariser": "wp", "algo_options": {"lambda_2": 1}},
     ["--option lambda_2=1.0 (stored: 0.003)"]),
])
def test_a_regulariser_stated_on_resume_is_named_as_its_difference(tmp_path, stored, stated, says):
    """``--resume --regulariser gd`` on a run stored with wp is one difference, the regulariser's, not
    an option nobody gave (the stored options that chose, or that only the stored regulariser
    reads, are the stored regulariser's)."""
    run = RunDir(tmp_path / "run")
    run.path.mkdir()
    run.write_config(RunConfig(**{"algo": "neat", "reg": 0.4, "generations": 3, **stored}).validate(machine=False))
    assert run.setting_differences(stated) == says


def test_resume_with_another_regulariser_names_it(tmp_path, capsys):
    from lifelong_evo.commands.cli import main

    argv = ["--algo", "neat", "--reg", "0.4", "--preset", "smoke", "--schedule", "red:1", "--env", "duration=20",
            "--held-out-episodes", "1", "--no-record", "--quiet", "--out", str(tmp_path), "--name", "wp"]
    assert main([*argv, "--regulariser", "wp", "--option", "lambda_2=0.003"]) == 0
    capsys.readouterr()
    before = {path: path.read_bytes() for path in (tmp_path / "wp").rglob("*") if path.is_file()}
    assert main([*argv, "--resume", "--regulariser", "gd"]) == 2
    assert capsys.readouterr().err == (
        f"error: {tmp_path / 'wp'} was run with other settings than these: --regulariser 'gd' (stored: 'wp'): "
        "continue it with its stored settings (drop those flags or give the stored values), or start a new run "
        "(another --name, or --overwrite to replace it)\n")
    assert {path: path.read_bytes() for path in (tmp_path / "wp").rglob("*") if path.is_file()} == before


@pytest.mark.parametrize("algo, options, own", [("neat", {}, "gd"), ("neat", {"penalty": "wp"}, "wp"),
                                                ("sep-cmaes", {}, "l2"), ("sep-cmaes", {"importance": "ewc"}, "ewc")])
def test_regulariser_default_is_the_one_a_run_without_it_applies(algo, options, own):
    """``--regulariser default`` (config.json's value before the setting existed) is documented: the
    family's own, or the one the options given choose, as without the flag; it is how a grid over
    families says "each its own" beside another (``--algo neat,sep-cmaes --regulariser default,functional``)."""
    from lifelong_evo.config import configure

    stated = configure({"algo": algo, "reg": 1.0, "regulariser": "default", "algo_options": options}, machine=False)
    assert stated == configure({"algo": algo, "reg": 1.0, "algo_options": options}, machine=False)
    assert stated.regulariser == own


def test_the_functional_regulariser_is_the_default_only_of_an_optimiser_with_no_other(monkeypatch):
    """A custom optimiser listing ``functional`` first beside its own regulariser got functional by
    default (the first entry won), built at lambda 0: its own regulariser silently off."""
    from algorithms import REGISTRY
    from algorithms.base import FUNCTIONAL
    from lifelong_evo.config import DEFAULT_REGULARISER, resolve_regulariser

    neat = REGISTRY["neat"]
    monkeypatch.setitem(REGISTRY, "functional-first", type("FunctionalFirst", (neat,), {
        "name": "functional-first",
        "regularisers": {FUNCTIONAL: {}, "mine": {"penalty": "gd"}, "wp": {"penalty": "wp"}},
        "options_used_by": {}}))
    monkeypatch.setitem(REGISTRY, "functional-only", type("FunctionalOnly", (neat,), {
        "name": "functional-only", "regularisers": {FUNCTIONAL: {}}, "options_used_by": {}}))
    assert resolve_regulariser("functional-first", DEFAULT_REGULARISER, {})[0] == "mine"
    assert resolve_regulariser("functional-first", DEFAULT_REGULARISER, {"penalty": "wp"})[0] == "wp"
    assert resolve_regulariser("functional-only", DEFAULT_REGULARISER, {})[0] == FUNCTIONAL
    names = [RunConfig(algo=algo, reg=1.0, regulariser=regulariser).validate(machine=False).default_name()
             for algo, regulariser in (("functional-first", "mine"), ("functional-first", "functional"),
                                       ("functional-only", "functional"))]
    assert names == ["functional-first-red-green-red-reg1-seed42",
                     "functional-first-red-green-red-functional-reg1-seed42",
                     "functional-only-red-green-red-reg1-seed42"]


# ------------------------------------------------------------------------ one spelling per schedule

@pytest.mark.parametrize("schedule, generations", [("red:2, green:2", 200), ("red:02,green:+2", 200),
                                                   ("red:2,green", 2), (" red:2 ,green: 2", 7)])
def test_a_schedule_is_stored_and_named_in_one_spelling(schedule, generations):
    config = RunConfig(schedule=schedule, generations=generations).validate(machine=False)
    assert config.schedule == "red:2,green:2" and config.default_name() == "neat-red-2-green-2-reg0-seed42"


def test_a_list_that_is_a_named_schedule_is_its_name():
    """config.json has always stored the named schedules by name: spelt out, they are the same run."""
    for spelt, generations, name in (("red:200,green:200,red:200", 200, "red-green-red"),
                                     ("red:3,red-nest-bottom,red:3", 3, "nest-relocation")):
        assert RunConfig(schedule=spelt, generations=generations).validate(machine=False).schedule == name
    assert RunConfig(schedule="red:5,green:5,red:5", generations=6).validate(machine=False).schedule == \
        "red:5,green:5,red:5"


def test_minus_zero_is_zero():
    config = RunConfig(reg="-0").validate(machine=False)
    assert math.copysign(1, config.reg) == 1 and config.default_name() == "neat-red-green-red-reg0-seed42"


def test_a_run_stored_with_another_spelling_of_its_schedule_resumes_and_groups(tmp_path, capsys):
    """A run directory written before schedules had one spelling (config.json and its checkpoints
    hold ``red:01, green:+1``) is continued by the command that names the schedule otherwise, and
    grouped with a run of the one spelling, as one configuration."""
    from lifelong_evo import checkpoint
    from lifelong_evo.commands.cli import main
    from lifelong_evo.runs import load_runs

    argv = ["--preset", "smoke", "--env", "duration=20", "--held-out-episodes", "1", "--no-record", "--quiet",
            "--out", str(tmp_path)]
    assert main([*argv, "--schedule", "red:1,green:1", "--name", "plain"]) == 0
    shutil.copytree(tmp_path / "plain", tmp_path / "odd")
    odd = RunDir(tmp_path / "odd")
    written = json.loads(odd.config.read_text())
    odd.config.write_text(json.dumps({**written, "schedule": "red:01, green:+1"}))
    for path in odd.checkpoint_files():
        payload = checkpoint.load(path)
        checkpoint.save(path, {**payload, "config": {**payload["config"], "schedule": "red:01, green:+1"}})
    assert main([*argv, "--schedule", "red:1,green:1", "--resume", "--name", "odd"]) == 0, capsys.readouterr().err
    first, second = load_runs([tmp_path])
    assert first.key == second.key  # one configuration: the key group_runs groups by
