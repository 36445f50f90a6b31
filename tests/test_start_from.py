"""``--start-from``: a run that differs from another only in lambda takes over that run's first
task (no optimiser uses lambda before the reference it takes at the first task end) and gives
the numbers it gets from scratch."""
from __future__ import annotations

import json

import pytest

from algorithms import REGISTRY
from lifelong_evo.commands.cli import main
from lifelong_evo.rundir import RunDir
from tests.test_nothing_lost import snapshot

COMMON = ["--preset", "smoke", "--schedule", "red:3,green:3,red:2", "--env", "duration=60", "--checkpoint-every", "2",
          "--no-record", "--quiet"]


def _files(run) -> dict[str, bytes]:
    """Every file a run wrote that holds its numbers (summary.json without the wall time)."""
    files = {path.relative_to(run).as_posix(): path.read_bytes() for path in sorted(run.rglob("*"))
             if path.is_file() and path.suffix in (".csv", ".json") and path.name != "summary.json"}
    summary = json.loads((run / "summary.json").read_text())
    summary.pop("first_task_from", None)  # the run it started from, if any
    files["summary.json"] = json.dumps({**summary, "wall_time_s": None}).encode()
    return files


VARIANTS = [[name] for name, cls in REGISTRY.items() if cls.has_regularizer] + [
    ["sep-cmaes", "--option", "importance=ewc"], ["openai-es", "--option", "importance=ewc", "--option", "reference=best"],
    ["neat", "--option", "genetics=2.0", "--option", "references=2"]]
"""Every optimiser with a regulariser, and the regularisers' options that keep state of their own."""


@pytest.mark.parametrize("algo", VARIANTS, ids=" ".join)
def test_a_run_started_from_another_lambda_gives_its_own_numbers(tmp_path, algo):
    def run(*argv):
        assert main(["--algo", *algo, *COMMON, "--out", str(tmp_path), *argv]) == 0

    run("--reg", "0", "--name", "source")
    run("--reg", "3", "--name", "alone")
    run("--reg", "3", "--name", "started", "--start-from", str(tmp_path / "source"))
    assert json.loads((tmp_path / "started/summary.json").read_text())["first_task_from"] == \
        str((tmp_path / "source").resolve())
    alone, started = _files(tmp_path / "alone"), _files(tmp_path / "started")
    assert json.loads(alone.pop("config.json")) == json.loads(started.pop("config.json"))
    assert alone == started
    # the regulariser acted after the first task: the runs differ from the source there
    metrics = [(tmp_path / name / "metrics.csv").read_text().splitlines() for name in ("source", "started")]
    assert metrics[0][:4] == metrics[1][:4] and metrics[0][4:] != metrics[1][4:]


@pytest.mark.parametrize("algo, regulariser", [("sep-cmaes", ["--regulariser", "functional"]),
                                               ("neat", ["--regulariser", "wp", "--option", "lambda_2=1"])])
def test_a_run_started_from_another_regulariser_gives_its_own_numbers(tmp_path, algo, regulariser):
    """The regulariser and the options that act only from the first task's end
    (``Optimizer.after_first_task_options``) take their reference there like lambda: a run of another
    takes over a fine-tuning run's first task (it was refused) and gives the numbers it gets alone."""
    def run(*argv):
        assert main(["--algo", algo, *COMMON, "--out", str(tmp_path), *argv]) == 0

    run("--name", "source")
    run(*regulariser, "--reg", "3", "--name", "alone")
    run(*regulariser, "--reg", "3", "--name", "started", "--start-from", str(tmp_path / "source"))
    alone, started = _files(tmp_path / "alone"), _files(tmp_path / "started")
    assert json.loads(alone.pop("config.json")) == json.loads(started.pop("config.json"))
    assert alone == started
    # the regulariser acted after the first task: the runs differ from the source there
    metrics = [(tmp_path / name / "metrics.csv").read_text().splitlines() for name in ("source", "started")]
    assert metrics[0][:4] == metrics[1][:4] and metrics[0][4:] != metrics[1][4:]


@pytest.mark.parametrize("algo", ["neat", "sep-cmaes"])
@pytest.mark.parametrize("source, baseline", [([], ["--rehearsal", "0.5", "--reg", "2"]), ([], ["--from-scratch"]),
                                              (["--from-scratch"], ["--reg", "2"]), ([], ["--archive"]),
                                              (["--archive"], ["--from-scratch"])])
def test_a_baseline_run_started_from_another_gives_its_own_numbers(tmp_path, algo, source, baseline):
    """Rehearsal has nothing to rehearse before the first task's end, from scratch starts afresh
    at it and the archive puts a controller back only when a task returns: such a run takes over
    another's first task (a from-scratch source keeps that end as it was reached, before starting
    afresh; an archive holds that task's top controller whether the source kept one or not) and
    repeats its numbers from scratch, resumed included."""
    def run(*argv):
        assert main(["--algo", algo, *COMMON, "--out", str(tmp_path), *argv]) == 0

    run(*source, "--name", "source")
    run(*baseline, "--name", "alone")
    run(*baseline, "--name", "started", "--start-from", str(tmp_path / "source"))
    alone, started = _files(tmp_path / "alone"), _files(tmp_path / "started")
    assert json.loads(alone.pop("config.json")) == json.loads(started.pop("config.json"))
    assert alone == started


def test_start_from_refuses_a_run_that_differs_in_more_than_lambda(tmp_path, capsys):
    assert main(["--algo", "neat", *COMMON, "--out", str(tmp_path), "--name", "source"]) == 0
    capsys.readouterr()
    for argv, message in ((["--seed", "7"], "seed"), (["--resume"], "drop --start-from"),
                          (["--start-from", str(tmp_path / "nothing")], "does not exist")):
        start = [] if "--start-from" in argv else ["--start-from", str(tmp_path / "source")]
        assert main(["--algo", "neat", "--reg", "2", *COMMON, "--out", str(tmp_path), "--name", "new", *start,
                     *argv]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err
        assert not (tmp_path / "new").exists()
    (tmp_path / "source/checkpoints/first-task-end.pt").unlink()
    assert main(["--algo", "neat", "--reg", "2", *COMMON, "--out", str(tmp_path), "--name", "new", "--start-from",
                 str(tmp_path / "source")]) == 2
    assert "keeps no checkpoint of its first task" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize("algo, setting, says", [
    ("neat", ["--option", "genetics=2.0"], "--option genetics='0.92' (stored: '2.0')"),
    ("sep-cmaes", ["--option", "sigma=2"], "--option sigma=0.5 (stored: 2.0)"),
    ("openai-es", ["--option", "reference=best"], "--option reference='centre' (stored: 'best')"),
    ("sep-cmaes", ["--env", "n_boxes=10"], "--env n_boxes=20 (stored: 10)")])
def test_start_from_refuses_a_source_with_a_setting_the_new_run_leaves_at_its_default(tmp_path, capsys, algo,
                                                                                     setting, says):
    """The source's options and environment were laid under the new run's, so a setting only the
    source gave was never compared: a NEAT source under 2.0's genetics crashed the new run after
    its directory was made, an ES source with another sigma gave other numbers without a word."""
    assert main(["--algo", algo, *COMMON, *setting, "--out", str(tmp_path), "--name", "source"]) == 0
    capsys.readouterr()
    before = snapshot(tmp_path)
    assert main(["--algo", algo, *COMMON, "--reg", "2", "--out", str(tmp_path), "--name", "new",
                 "--start-from", str(tmp_path / "source")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and says in err, err
    assert snapshot(tmp_path) == before


def test_start_from_a_run_of_another_algo_names_only_the_algo(tmp_path, capsys):
    """The refusal listed the options of both optimisers, which nobody typed, beside --algo."""
    assert main(["--algo", "neat", *COMMON, "--out", str(tmp_path), "--name", "source"]) == 0
    capsys.readouterr()
    before = snapshot(tmp_path)
    assert main(["--algo", "openai-es", "--reg", "2", *COMMON, "--out", str(tmp_path), "--name", "new",
                 "--start-from", str(tmp_path / "source")]) == 2
    captured = capsys.readouterr()
    assert captured.err == (f"error: --start-from {tmp_path / 'source'}: that run differs from this one in settings "
                            "that act before its first task's end (--algo 'openai-es' (stored: 'neat')), so its first "
                            "task is not this run's: start this run without --start-from\n")
    assert captured.out == "" and snapshot(tmp_path) == before


@pytest.mark.parametrize("algo", ["neat", "sep-cmaes"])
def test_a_from_scratch_run_stopped_right_after_taking_over_a_first_task_resumes_to_its_numbers(tmp_path, algo):
    """The checkpoint written when a from-scratch run takes over another's first task holds the
    fresh optimiser it goes on with: resumed from it, the run repeats its numbers from scratch."""
    from lifelong_evo import loop
    from lifelong_evo.commands.flags import resolve_run_config
    from lifelong_evo.commands.cli import build_parser
    from lifelong_evo.rundir import RunDir

    def run(*argv):
        assert main(["--algo", algo, *COMMON, "--out", str(tmp_path), *argv]) == 0

    run("--name", "source")
    run("--from-scratch", "--name", "alone")
    config = resolve_run_config(build_parser().parse_args(["run", "--algo", algo, *COMMON, "--from-scratch"]))
    steps = loop.lifelong(config, RunDir(tmp_path / "stopped"), progress="off", start_from=RunDir(tmp_path / "source"))
    next(steps)  # the first task taken over, the next one's first evaluation asked for: stop here
    steps.close()
    assert [p.name for p in sorted((tmp_path / "stopped/checkpoints").glob("generation-*"))] == ["generation-000003.pt"]
    run("--from-scratch", "--name", "stopped", "--resume")
    alone, resumed = _files(tmp_path / "alone"), _files(tmp_path / "stopped")
    assert json.loads(alone.pop("config.json")) == json.loads(resumed.pop("config.json"))
    assert alone == resumed


@pytest.mark.parametrize("damage, names", [
    ("damaged", "task0-red-top.json"), ("missing", "task0-red-top.json"),
    ("another-run's-first-task-end", "first-task-end.pt belongs to another configuration"),
    ("metrics-cut", "metrics.csv has no rows for generation(s) 2"),
])
def test_a_damaged_source_is_refused_before_the_new_run_is_made(tmp_path, capsys, damage, names):
    """What a run takes over is read, and refused, before its run directory exists: the first
    task's controllers (read after it was made, leaving it half-made), a first-task-end.pt of
    another run (another seed's: taken over silently, with this source's rows and controllers) and
    a metrics.csv without rows of the first task (a run with a gap in its generations)."""
    assert main(["--algo", "neat", *COMMON, "--out", str(tmp_path), "--name", "source"]) == 0
    source = tmp_path / "source"
    top = source / "controllers" / "task0-red-top.json"
    if damage == "missing":
        top.unlink()
    elif damage == "damaged":
        top.write_text(json.dumps({"format": "neat-python-genome", "genome": "x"}))
    elif damage == "metrics-cut":
        (source / "metrics.csv").write_text("".join((source / "metrics.csv").read_text().splitlines(True)[:3]))
    else:
        assert main(["--algo", "neat", *COMMON, "--seed", "7", "--out", str(tmp_path), "--name", "other"]) == 0
        (source / "checkpoints" / "first-task-end.pt").write_bytes(
            (tmp_path / "other" / "checkpoints" / "first-task-end.pt").read_bytes())
    capsys.readouterr()
    before = snapshot(tmp_path)
    assert main(["--algo", "neat", "--reg", "1", *COMMON, "--out", str(tmp_path), "--name", "new",
                 "--start-from", str(source)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and names in err
    assert snapshot(tmp_path) == before and not (tmp_path / "new").exists()


@pytest.mark.parametrize("numerics", ["portable", "native"])
def test_other_speed_settings_take_over_a_first_task_and_resume_only_under_the_portable_arithmetic(
        tmp_path, capsys, numerics):
    """Under the portable arithmetic the thread counts and compiled code change no byte
    (tests/test_same_numbers_anywhere.py): a run under other ones takes over a first task, and a
    run is resumed under other ones, each giving the numbers it gives alone. Under the native one
    they round otherwise: both are refused, naming the setting, and nothing is written."""
    import shutil

    def run(*argv):
        return main(["--algo", "sep-cmaes", *COMMON, "--numerics", numerics, "--out", str(tmp_path), *argv])

    assert run("--reg", "3", "--name", "source", "--eval-threads", "1", "--no-compile") == 0
    copy = tmp_path / "copy"
    shutil.copytree(tmp_path / "source", copy)
    newest = sorted(copy.glob("checkpoints/generation-*.pt"))[-1]
    newest.unlink()  # back to the run's middle: --resume plays its last generations again
    faster = ["--eval-threads", "2", "--compile"]
    started = ["--reg", "3", "--name", "started", *faster, "--start-from", str(tmp_path / "source")]
    if numerics == "native":
        capsys.readouterr()
        assert run(*started) == 2
        assert "--eval-threads 2 (stored: 1)" in capsys.readouterr().err and not (tmp_path / "started").exists()
        before = _files(copy)
        assert run("--name", "copy", "--resume", *faster) == 2
        assert "--eval-threads 2 (stored: 1)" in capsys.readouterr().err and _files(copy) == before
        return
    assert run(*started) == 0
    continued = RunDir(copy).continuation({"eval_threads": 2, "compile": True})
    assert (continued.eval_threads, continued.compile) == (2, True)  # the resumed run computes as told
    assert run("--name", "copy", "--resume", *faster) == 0
    source, taken_over, resumed = (_files(tmp_path / name) for name in ("source", "started", "copy"))
    assert resumed == source  # config.json too: it keeps the settings the run was created with
    for files in (source, taken_over):
        config = json.loads(files.pop("config.json"))
        config.pop("eval_threads"), config.pop("compile")
        files["config.json"] = config
    assert taken_over == source
