"""The reading verbs against damaged or mismatched run directories (issue #59).

Four finished smoke runs are copied afresh for each check and one file of the copy is damaged:
NEAT and OpenAI-ES as the paper runs them, and two made with the newer run features (a task file's
task with every drift field, the skill archive, NEAT's ``wp`` regulariser with ``lambda_2``,
sep-CMA-ES with the functional regulariser), whose config.json holds ``tasks`` and
``task_definitions`` and whose summary.json's held-out block scores the archive. Every reading verb (``plot``, ``compare``, ``replay``, ``view``, ``score``,
and ``--resume`` and ``--start-from`` where a run reads another) must then exit 0 or 2, print no
traceback, give exactly one ``error:`` line on a refusal, and leave every file it does not own
byte for byte (a verb that only reads, on a refusal: every file). One test per case the issue
names (a traceback, or a damage accepted silently, before), then a property test whose damages
hypothesis draws: truncation, a file removed, JSON values of the wrong type, numbers out of range,
unknown task names, duplicated or dropped rows and controllers of the wrong shape."""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path
from types import SimpleNamespace

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from lifelong_evo import checkpoint
from lifelong_evo.commands import view
from lifelong_evo.commands.cli import main
from lifelong_evo.commands.sweep import trial_state
from lifelong_evo.rundir import RunDir
from tests.test_command_line_fuzz import SIZE, snapshot

TASK_FILE = Path(__file__).parent / "data" / "damaged-runs-tasks.toml"
"""Defines ``red-south``: the nest at the bottom, a costlier wrong pick, one robot failed, worn motors."""
FEATURES = ["--schedule", "red:2,red-south:2,red:2", "--tasks", str(TASK_FILE), "--archive", "--reg", "2"]
"""A task file's task between two red phases, and the skill archive (lambda 2: ``--start-from``'s
``--reg 1`` differs from it only after the first task)."""
KINDS = {"neat": [], "es": ["--algo", "openai-es"],
         "wp": [*FEATURES, "--regulariser", "wp", "--option", "lambda_2=0.5"],
         "sep": [*FEATURES, "--algo", "sep-cmaes", "--regulariser", "functional"]}
"""The finished runs, by name, and the flags that made them beside ``SIZE``."""


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A folder holding the finished runs of ``KINDS``, by name, never changed: copy them."""
    out = tmp_path_factory.mktemp("finished")
    for name, flags in KINDS.items():
        assert main([*SIZE, *flags, "--out", str(out), "--name", name, "--quiet"]) == 0
    return out


@pytest.fixture
def work(finished, tmp_path) -> Path:
    """A fresh copy of the finished runs under ``runs/``, in a folder of its own."""
    shutil.copytree(finished, tmp_path / "runs")
    return tmp_path


# ---------------------------------------------------------------------------------------------
# Damages: each changes one file of a run directory


def edit_json(name: str, change):
    """A damage: ``change(value)`` applied to the JSON file ``name`` (relative to the run), in place."""
    def damage(run: Path) -> None:
        path = run / name
        value = json.loads(path.read_text())
        changed = change(value)
        path.write_text(json.dumps(value if changed is None else changed))
    return damage


def setting(key: str, value):
    return edit_json("config.json", lambda config: config.update({key: value}))


def option(table: str, key: str, value):
    """A damage: config.json's ``table`` (env, algo_options) with ``key`` set to ``value``."""
    return edit_json("config.json", lambda config: config[table].update({key: value}))


def write(name: str, text: str):
    def damage(run: Path) -> None:
        (run / name).write_text(text)
    return damage


def truncate(name: str, keep: float = 0.5):
    def damage(run: Path) -> None:
        data = (run / name).read_bytes()
        (run / name).write_bytes(data[:int(len(data) * keep)])
    return damage


def remove(name: str):
    def damage(run: Path) -> None:
        (run / name).unlink()
    return damage


def edit_lines(name: str, change):
    """A damage: ``change(lines)`` on the lines of the CSV file ``name`` (header first)."""
    def damage(run: Path) -> None:
        path = run / name
        path.write_text("\n".join(change(path.read_text().splitlines())) + "\n")
    return damage


def edit_metrics(change):
    return edit_lines("metrics.csv", change)


def edit_species(change):
    return edit_lines("species.csv", change)


def set_cell(line: int, column: str, value: str):
    def change(lines: list[str]) -> list[str]:
        header = lines[0].split(",")
        cells = lines[line].split(",")
        cells[header.index(column)] = value
        return [*lines[:line], ",".join(cells), *lines[line + 1:]]
    return change


def wrong_layer_sizes(controller: dict) -> None:
    """Layer sizes that agree with the parameters' count, for 10 inputs where the arena has 41."""
    controller["layer_sizes"] = [10, 16, 3]
    controller["parameters"] = [0.1] * (10 * 16 + 16 + 16 * 3 + 3)


def other_hidden_sizes(controller: dict) -> None:
    """A whole MLP that plays in the arena (41 inputs), of other hidden sizes than the run's (16)."""
    controller["layer_sizes"] = [41, 8, 3]
    controller["parameters"] = [0.1] * (41 * 8 + 8 + 8 * 3 + 3)


def every_controller(change):
    def damage(run: Path) -> None:
        for path in sorted((run / "controllers").glob("*.json")):
            edit_json(path.relative_to(run), change)(run)
    return damage


FINAL = "controllers/final-top.json"

VERBS = {
    "plot": lambda run, work: ["plot", str(run)],
    "compare": lambda run, work: ["compare", str(run), "--out", str(work / "comparison")],
    "replay": lambda run, work: ["replay", str(run), "--no-record", "--episodes", "1"],
    "score": lambda run, work: ["score", str(run)],
    "view": lambda run, work: ["view", str(run)],
}
"""Each reading verb's command line on ``run`` (what it writes goes into ``work``)."""

CASES = [
    # tracebacks before: sixteen (run, damage, verb)
    ("summary.json []", "neat", write("summary.json", "[]"), ["plot", "compare"]),
    ("summary.json phases out of range", "neat",
     edit_json("summary.json", lambda s: s.update(phases=[*s["phases"], "green", "red"])), ["compare"]),
    ("config.json []", "neat", write("config.json", "[]"), ["replay", "plot", "compare", "score"]),
    ("config.json schedule with an unknown task", "neat", setting("schedule", "red:2,blue:2"),
     ["replay", "compare", "score"]),
    ("config.json population 'abc'", "neat", setting("population", "abc"), ["compare"]),
    ("config.json regulariser no name", "neat", setting("regulariser", "l3"), ["replay", "compare", "score"]),
    ("config.json regulariser another family's", "es", setting("regulariser", "wp"), ["replay", "compare"]),
    ("ES controller with wrong layer sizes", "es", every_controller(wrong_layer_sizes), ["replay", "score"]),
    ("ES controller parameters a string", "es", edit_json(FINAL, lambda c: c.update(parameters="abc")), ["replay"]),
    ("NEAT controller nodes a string", "neat", edit_json(FINAL, lambda c: c["genome"].update(nodes="abc")),
     ["replay"]),
    ("NEAT controller num_inputs not the run's", "neat", edit_json(FINAL, lambda c: c.update(num_inputs=10)),
     ["replay"]),
    # rewritten or accepted silently before
    ("summary.json truncated", "neat", truncate("summary.json"), ["score"]),
    ("summary.json []", "neat", write("summary.json", "[]"), ["score"]),
    ("metrics.csv task not the schedule's", "neat", edit_metrics(set_cell(1, "task", "purple")), ["plot", "compare"]),
    ("metrics.csv task_index beyond the schedule", "neat", edit_metrics(set_cell(1, "task_index", "7")),
     ["plot", "compare"]),
    ("metrics.csv generation written twice", "neat", edit_metrics(lambda lines: [*lines[:2], *lines[1:]]),
     ["plot", "compare"]),
    ("summary.json phases disagree with config.json", "neat",
     edit_json("summary.json", lambda s: s.update(phases=["green", *s["phases"][1:]])), ["plot", "compare"]),
    ("ES reference not of its top controller's size", "es",
     edit_json("controllers/task1-green-reference.json", other_hidden_sizes), ["plot"]),
    # config.json's env and algo_options used as written before: a truthy "no", a TypeError or ValueError later
    ("config.json env see_other_agents 'no'", "neat", option("env", "see_other_agents", "no"),
     ["replay", "score", "compare", "--resume", "--start-from"]),
    ("config.json env duration '200'", "neat", option("env", "duration", "200"), ["replay", "plot"]),
    ("config.json algo_options references '1'", "neat", option("algo_options", "references", "1"), ["--resume"]),
    ("config.json algo_options sigma out of range", "es", option("algo_options", "sigma", -1), ["replay"]),
    # a NaN or an infinity (Python's json reads them) crashed the forward pass
    ("NEAT controller weight NaN", "neat",
     every_controller(lambda c: c["genome"]["connections"][0].update(weight=float("nan"))), ["replay", "score"]),
    ("ES controller parameter infinite", "es", edit_json(FINAL, lambda c: c["parameters"].__setitem__(3, float("inf"))),
     ["replay"]),
    # the runs with the newer features: config.json's keys written beside the settings were read
    # unchecked (a traceback in --resume, --start-from and compare, or a damage read as it stood),
    # and summary.json's archive was never checked
    ("config.json task_definitions a task's not an object", "wp",
     edit_json("config.json", lambda c: c["task_definitions"].update({"red-south": "x"})),
     ["--resume", "--start-from", "plot", "replay", "score"]),
    ("config.json task_definitions motor_gain 'x'", "sep",
     edit_json("config.json", lambda c: c["task_definitions"]["red-south"].update(motor_gain="x")), ["compare", "score"]),
    ("config.json task_definitions not the schedule's tasks", "sep", setting("task_definitions", {}), ["replay"]),
    # a valid definition the tables do not give: --resume compared one task, replay and score played another
    ("config.json task_definitions motor_gain not the table's", "wp",
     edit_json("config.json", lambda c: c["task_definitions"]["red-south"].update(motor_gain=0.5)), ["replay", "score"]),
    ("config.json env_resolved a string", "wp", setting("env_resolved", "x"), ["--resume", "--start-from", "compare"]),
    ("config.json algo_options_resolved lambda_2 'x'", "wp", option("algo_options_resolved", "lambda_2", "x"),
     ["compare", "--resume"]),
    ("config.json algo_options_resolved another family's option", "sep",
     option("algo_options_resolved", "lambda_2", 0.5), ["plot"]),
    # the resolved options disagreeing with the given ones: compare read one, --resume the other
    ("config.json env_resolved not the env it gives", "neat", option("env_resolved", "duration", 40),
     ["--resume", "compare", "replay"]),
    ("config.json algo_options_resolved not the option it gives", "wp", option("algo_options_resolved", "lambda_2", 0.25),
     ["--resume", "compare", "--start-from"]),
    # Python's json reads NaN and Infinity, which no writer of a run writes: compare averaged a NaN
    ("summary.json a figure NaN", "neat",
     edit_json("summary.json", lambda s: s.update(current=[float("nan")] * len(s["current"]))),
     ["compare", "plot", "score"]),
    ("metrics.csv best nan", "neat", edit_metrics(set_cell(2, "best", "nan")), ["plot", "compare"]),
    ("metrics.csv mean inf", "es", edit_metrics(set_cell(1, "mean", "inf")), ["compare"]),
    ("summary.json held-out score infinite", "sep",
     edit_json("summary.json", lambda s: next(iter(s["held_out"]["scores"].values())).update(red=float("inf"))), ["compare"]),
    ("summary.json archive a string", "sep", edit_json("summary.json", lambda s: s["held_out"].update(archive="x")),
     ["plot", "compare", "score"]),
    ("summary.json archive of a task not played", "wp",
     edit_json("summary.json", lambda s: s["held_out"]["archive"].update(blue={"controller": "task0-red-top", "score": 1})),
     ["compare"]),
    ("summary.json archive controller a list", "wp",
     edit_json("summary.json", lambda s: s["held_out"]["archive"]["red"].update(controller=[])), ["plot"]),
    ("summary.json archive score a string", "sep",
     edit_json("summary.json", lambda s: s["held_out"]["archive"]["red"].update(score="x")), ["compare"]),
    ("summary.json archive_mean a list", "wp", edit_json("summary.json", lambda s: s["held_out"].update(archive_mean=[])),
     ["score"]),
    # metrics.csv rows read as they stood: a curve with a hole, another phase's row, a phase start missing
    ("metrics.csv a generation missing", "neat", edit_metrics(lambda lines: [*lines[:2], *lines[3:]]),
     ["plot", "compare"]),
    ("metrics.csv generation_in_task not the schedule's", "es", edit_metrics(set_cell(2, "generation_in_task", "0")),
     ["compare"]),
    ("metrics.csv cut short of summary.json's ended phases", "sep", edit_metrics(lambda lines: lines[:3]),
     ["plot", "compare"]),
    ("species.csv cut short of summary.json's ended phases", "wp", truncate("species.csv", 0.3), ["plot"]),
    ("species.csv rows out of order", "neat", edit_species(lambda lines: [lines[0], lines[2], lines[1], *lines[3:]]),
     ["plot"]),
    # a controller summary.json names missing: score wrote the held-out block anew without its
    # scores (no phases, no figures), compare and plot left its figures out
    ("controllers/ lacks a task end's top controller", "neat", remove("controllers/task0-red-top.json"),
     ["score", "compare", "plot"]),
    ("controllers/ lacks a controller the held-out block scored", "es", remove("controllers/initial-centre.json"),
     ["score", "compare"]),
]
REFUSALS = [pytest.param(kind, damage, verb, id=f"{name}-{verb}") for name, kind, damage, verbs in CASES
            for verb in verbs]


def assert_refused(argv: list[str], work: Path, capsys) -> str:
    """``argv`` exits 2 with exactly one line on stderr, ``error: ...``, and changes no file under ``work``."""
    before = snapshot(work)
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, (argv, code, err)
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    assert snapshot(work) == before, sorted(p for p in before.keys() | snapshot(work).keys()
                                             if before.get(p) != snapshot(work).get(p))
    return err


@pytest.mark.parametrize(("kind", "damage", "verb"), REFUSALS)
def test_a_damaged_run_is_refused_in_one_line_and_left_as_it_was(kind, damage, verb, work, capsys):
    run = work / "runs" / kind
    damage(run)
    err = assert_refused(command(kind, verb, work), work, capsys)
    assert str(run) in err, "the line names the file"


@pytest.mark.parametrize("name", ["config.json", "summary.json"])
def test_a_file_that_is_not_json_is_refused_with_the_way_out(name, work, capsys):
    truncate(name)(work / "runs" / "neat")
    err = assert_refused(command("neat", "compare", work), work, capsys)
    assert "is not valid JSON" in err and err.endswith(": restore it from a copy of the run, or run the run again\n")


@pytest.mark.parametrize(("kind", "damage", "key", "named"), [
    ("neat", option("env", "see_other_agents", "no"), "env", "see_other_agents"),
    ("wp", edit_json("config.json", lambda c: c["task_definitions"].update({"red-south": []})), "task_definitions",
     "red-south"),
    ("sep", setting("algo_options_resolved", ["x"]), "algo_options_resolved", "['x']"),
])
def test_a_sweep_does_not_resume_a_trial_whose_config_json_is_damaged(kind, damage, key, named, work):
    """A sweep's trial is resumed from its config.json as ``--resume`` is: one whose environment
    option, task definition or resolved options are damaged is failed, naming the key, not
    continued with the value as it stands (nor a traceback)."""
    run = work / "runs" / kind
    config = RunDir(run).read_config()
    damage(run)
    state, why = trial_state(run, config)
    assert state == "failed" and f"key {key!r}" in why and named in why, (state, why)


@pytest.mark.parametrize("archive", ["x", {"red": "x"}, {"red": {"genome": 5}}, {"blue": {}}])
def test_resume_refuses_a_checkpoint_whose_archive_is_damaged(archive, work, capsys):
    """A checkpoint's skill archive is put back into the population when its task returns: one
    that is no object of the run's controllers by task (its checksum made to match) is refused in
    one line naming the checkpoint, not a traceback when the task returns."""
    run = work / "runs" / "wp"
    newest, *_ = sorted((run / "checkpoints").glob("generation-*.pt"), reverse=True)
    newest.unlink()  # the run ends its second task at the checkpoint before: red returns
    path = sorted((run / "checkpoints").glob("generation-*.pt"))[-1]
    payload = checkpoint.load(path)
    payload["loop"]["archive"] = archive
    checkpoint.save(path, payload)
    err = assert_refused(command("wp", "--resume", work), work, capsys)
    assert str(path) in err and "archive" in err, err


def test_resume_goes_on_with_an_option_the_run_resolved_before_its_default_changed(work, capsys):
    """A run whose config.json records an option it did not give at another value than today's
    default (here ``sensor_range``, as if the default had changed since) resumes without flags, its
    checkpoints (which hold the options as given) accepted as its own, and goes on with the
    recorded value: the checkpoints it writes from there say so."""
    run = work / "runs" / "neat"
    newest, *_ = sorted((run / "checkpoints").glob("generation-*.pt"), reverse=True)
    newest.unlink()
    edit_json("config.json", lambda c: c["env_resolved"].update(sensor_range=5.0))(run)
    assert "sensor_range" not in checkpoint.load(sorted((run / "checkpoints").glob("generation-*.pt"))[-1])[
        "config"]["env"]
    assert main(command("neat", "--resume", work)) == 0, capsys.readouterr().err
    newest, *_ = sorted((run / "checkpoints").glob("generation-*.pt"), reverse=True)
    assert checkpoint.load(newest)["config"]["env"]["sensor_range"] == 5.0


def test_start_from_takes_a_first_task_written_after_a_default_changed(work, capsys):
    """A source run resumed before its first task's end after a default changed wrote its
    first-task-end.pt with the value config.json records it resolved: a run stating that value
    starts from it (it was refused as a checkpoint of another configuration than its config.json)."""
    source = work / "runs" / "wp"
    edit_json("config.json", lambda c: c["env_resolved"].update(sensor_range=5.0))(source)
    path = source / "checkpoints" / "first-task-end.pt"
    payload = checkpoint.load(path)
    payload["config"]["env"]["sensor_range"] = 5.0
    checkpoint.save(path, payload)
    argv = command("wp", "--start-from", work)
    assert main([*argv, "--env", "sensor_range=5.0"]) == 0, capsys.readouterr().err
    err = assert_refused(argv, work, capsys)
    assert "--env sensor_range=4.0 (stored: 5.0)" in err, err


def test_the_undamaged_runs_pass_every_verb(work, capsys):
    """The checks refuse only damage: each verb that reads a run's files reads each finished run as
    it was written."""
    for kind in KINDS:
        for verb in ("plot", "compare", "replay", "score"):
            assert main(VERBS[verb](work / "runs" / kind, work)) == 0, (kind, verb, capsys.readouterr().err)


def test_score_keeps_the_summary_it_rewrites(work):
    """``score`` rewrites only summary.json's held-out block: every other key is kept as it was."""
    path = work / "runs" / "es" / "summary.json"
    before = json.loads(path.read_text())
    assert main(["score", str(path.parent)]) == 0
    after = json.loads(path.read_text())
    assert {k: v for k, v in after.items() if k != "held_out"} == {k: v for k, v in before.items() if k != "held_out"}


# ---------------------------------------------------------------------------------------------
# Generated damages, every reading verb


class NoViewer:
    """Stands in for the Rerun viewer process that ``view`` starts: it has closed at once."""

    def __init__(self, *args, **kwargs):
        pass

    def wait(self) -> int:
        return 0

    def poll(self) -> int:
        return 0


NO_VIEWER = SimpleNamespace(Popen=NoViewer, DEVNULL=subprocess.DEVNULL)
"""``view``'s ``subprocess`` module, as the tests give it (only ``view``'s: git and the rest run as ever)."""


WRONG_VALUES = st.sampled_from([[], {}, "abc", "", None, True, -1, 0, 10 ** 30, 1.5, ["red"], [[]], {"a": 1}])
"""JSON values of the wrong type or out of range for most keys."""
FILES = ["config.json", "summary.json", "metrics.csv", FINAL, "controllers/task0-red-top.json"]


@st.composite
def damages(draw):
    """(a description, a damage) to one file of a run."""
    name = draw(st.sampled_from(FILES))
    how = draw(st.sampled_from(["truncate", "remove", "wrong value", "out of range", "unknown task", "duplicate row",
                                "drop row", "controller shape", "held-out block", "task field"]))
    if how == "remove":
        return f"{name} removed", remove(name)
    if how == "truncate":
        keep = draw(st.floats(0, 0.99))
        return f"{name} cut to {keep:.2f}", truncate(name, keep)
    if name == "metrics.csv" or how in ("duplicate row", "drop row"):
        line = draw(st.integers(1, 6))
        column = draw(st.sampled_from(["task", "task_index", "generation", "generation_in_task", "best"]))
        value = draw(st.sampled_from(["purple", "blue", "7", "-1", "", "1e400", "0"]))
        if how == "duplicate row":
            return f"metrics.csv line {line} twice", edit_metrics(lambda lines: [*lines[:line + 1], *lines[line:]])
        if how == "drop row":
            return f"metrics.csv line {line} dropped", edit_metrics(lambda lines: [*lines[:line], *lines[line + 1:]])
        return f"metrics.csv line {line} {column}={value!r}", edit_metrics(set_cell(line, column, value))
    if name.startswith("controllers/"):
        key = draw(st.sampled_from(["layer_sizes", "parameters", "num_inputs", "num_outputs", "genome", "format",
                                    "unconnected_outputs", "nodes", "connections"]))
        value = draw(st.one_of(WRONG_VALUES, st.just([41, 8, 3]), st.just([1, 3])))
        if how == "controller shape" and key in ("nodes", "connections"):
            return f"{name} genome.{key}={value!r}", edit_json(name, lambda c: c.get("genome", {}).update({key: value}))
        return f"{name} {key}={value!r}", edit_json(name, lambda c: c.update({key: value}))
    if how == "held-out block" and name == "summary.json":
        key = draw(st.sampled_from(["archive", "archive_mean", "scores", "phases", "episodes", "current_top", "R_top",
                                    "forgetting"]))
        value = draw(st.one_of(WRONG_VALUES, st.just({"red": {"controller": "task0-red-top", "score": "x"}}),
                               st.just({"blue": {"controller": "task0-red-top", "score": 1.0}})))
        return (f"summary.json held_out.{key}={value!r}",
                edit_json(name, lambda s: s.update(held_out={**(s.get("held_out") or {}), key: value})))
    if how == "task field" and name == "config.json":
        table = draw(st.sampled_from(["tasks", "task_definitions"]))
        key = draw(st.sampled_from(["target", "season", "drop_zone", "rewards", "failed_robots", "motor_gain", "colour"]))
        value = draw(st.one_of(WRONG_VALUES, st.sampled_from(["blue", ["blue", "red"], 10 ** 9, -1e9, float("nan")])))

        def damage_tasks(config: dict) -> None:
            for task in (config.get(table) or {}).values():
                if isinstance(task, dict):
                    task[key] = value
        return f"config.json {table}.*.{key}={value!r}", edit_json(name, damage_tasks)
    keys = {"config.json": ["schedule", "population", "generations", "seed", "env", "algo_options", "algo", "reg",
                            "held_out_episodes", "rehearsal", "evals", "tasks", "task_definitions", "archive",
                            "regulariser", "env_resolved", "algo_options_resolved"],
            "summary.json": ["phases", "current", "current_top", "forgetting", "R_pop", "ACC_top", "held_out",
                             "stability_gap", "wall_time_s", "centre_current"]}[name]
    key = draw(st.sampled_from(keys))
    if how == "unknown task":
        value = {"config.json": "red:2,blue:2", "summary.json": ["red", "blue"]}[name]
    elif how == "out of range":
        value = draw(st.sampled_from([10 ** 9, -5, ["red", "green", "red", "green", "red"], "red:0"]))
    else:
        value = draw(WRONG_VALUES)
    return f"{name} {key}={value!r}", edit_json(name, lambda d: d.update({key: value}))


def command(kind: str, verb: str, work: Path) -> list[str]:
    """The command line of ``verb`` on run ``kind`` in ``work``."""
    run = work / "runs" / kind
    if verb == "--resume":
        return [*SIZE, *KINDS[kind], "--out", str(work / "runs"), "--name", kind, "--resume", "--quiet"]
    if verb == "--start-from":
        return [*SIZE, *KINDS[kind], "--reg", "1", "--out", str(work / "runs"), "--name", "taker", "--start-from",
                str(run), "--quiet"]
    return VERBS[verb](run, work)


def owns(kind: str, verb: str, path: str) -> bool:
    """Whether ``verb`` on run ``kind`` may write ``path`` (relative to its work folder) when it
    does not refuse: the run it continues, the run it starts, the files it is there to write."""
    path = Path(path)
    run = Path("runs", kind)
    owned = {"--resume": run, "--start-from": Path("runs", "taker"), "compare": Path("comparison"),
             "score": run / "summary.json"}.get(verb)
    if verb == "plot":
        return path.parent == run and path.suffix == ".png"
    return owned is not None and (path == owned or owned in path.parents)


@settings(max_examples=60, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(kind=st.sampled_from(list(KINDS)), verb=st.sampled_from([*VERBS, "--resume", "--start-from"]),
       damage=damages())
def test_every_reading_verb_refuses_damage_in_one_line_or_reads_it(kind, verb, damage, finished, tmp_path_factory,
                                                                   capsys, monkeypatch):
    described, apply = damage
    work = tmp_path_factory.mktemp("damaged")
    shutil.copytree(finished, work / "runs")
    apply(work / "runs" / kind)
    monkeypatch.setattr(view, "subprocess", NO_VIEWER)  # view reads, and starts no viewer
    argv = command(kind, verb, work)
    before = snapshot(work)
    try:
        code = main(argv)
    finally:
        monkeypatch.undo()
    err = capsys.readouterr().err
    after = snapshot(work)
    shutil.rmtree(work)
    event(f"{verb}: exit {code}")
    event(f"run {kind}")
    assert code in (0, 2), (described, argv, code, err)
    assert "Traceback" not in err, (described, argv, err)
    changed = [p for p in before.keys() | after.keys() if before.get(p) != after.get(p)]
    if code == 2:
        assert err.startswith("error: ") and err.count("\n") == 1, (described, argv, err)
        # a verb that only reads writes nothing when it refuses; a run may have begun its own directory
        assert all(verb in ("--resume", "--start-from") and owns(kind, verb, p) for p in changed), (described, argv)
    else:
        assert all(owns(kind, verb, p) for p in changed), (described, argv, changed)
