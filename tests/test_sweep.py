"""``python -m lifelong_evo sweep`` on a local Ray with 2 CPUs (one Ray for the module): a smoke
grid completes and aggregates, a failing trial is recorded while the others finish, a second
invocation skips finished trials, Ctrl-C stops cleanly; and (no Ray) the grid parsing and the
model-specific lambda selection."""
from __future__ import annotations

import csv
import json
import os
import shutil
from pathlib import Path

import pytest

from envs import ForagingConfig
from lifelong_evo.commands.cli import build_parser, main
from lifelong_evo.commands.grid import build_grid
from lifelong_evo.analysis.model_specific import (
    model_specific_label,
    model_specific_report,
    select_model_specific,
    selection_score,
)
from lifelong_evo.commands.sweep import run_trial, trial_state
from lifelong_evo.config import RunConfig

ray = pytest.importorskip("ray")

CONTRACT = ("config.json", "metrics.csv", "summary.json", "controllers/final-top.json")
SMOKE = ["--preset", "smoke", "--no-record", "--env", "duration=60"]
"""With shorter episodes than the preset's: these tests check the sweep, not learning."""


def _trials(sweep_dir: Path) -> dict[str, dict[str, str]]:
    with open(sweep_dir / "trials.csv", newline="") as handle:
        return {row["trial"]: row for row in csv.DictReader(handle)}


@pytest.fixture(scope="module")
def local_ray():
    # Ray gives its raylet a fixed 30 s to register; on a loaded 2-core machine that can run out
    for attempt in range(3):
        try:
            ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
            break
        except Exception as error:  # Ray raises a bare Exception for the start-up time-out
            ray.shutdown()
            if "timed out during startup" not in str(error) or attempt == 2:
                raise
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def smoke_sweep(local_ray, tmp_path_factory):
    out = tmp_path_factory.mktemp("sweeps")
    argv = ["sweep", "--algo", "neat,openai-es", "--seed", "2,3", "--generations", "2", *SMOKE,
            "--out", str(out), "--name", "smoke"]
    assert main(argv) == 0
    return out / "smoke", argv


def test_smoke_sweep_completes_and_aggregates(smoke_sweep):
    sweep_dir, _ = smoke_sweep
    names = ["neat-seed2", "neat-seed3", "openai-es-seed2", "openai-es-seed3"]
    trials = _trials(sweep_dir)
    assert sorted(trials) == names
    assert all(row["status"] == "done" and row["error"] == "" and float(row["wall_time_s"]) > 0
               for row in trials.values())
    for name in names:
        for item in CONTRACT:
            assert (sweep_dir / name / item).is_file(), (name, item)
        assert sorted((sweep_dir / name / "checkpoints").glob("generation-*.pt"))
        config = json.loads((sweep_dir / name / "config.json").read_text())
        assert (config["algo"], config["seed"], config["generations"], config["threads"]) == \
            (name.rsplit("-seed", 1)[0], int(name[-1]), 2, 1)
    sweep = json.loads((sweep_dir / "sweep.json").read_text())
    assert sweep["grid"] == {"algo": ["neat", "openai-es"], "seed": [2, 3]}
    assert [t["trial"] for t in sweep["trials"]] == names
    assert (sweep_dir / "comparison.md").read_text().strip()
    # the compare table over the sweep: 2 configurations, 2 seeds each (printed, and in comparison.md/.csv)
    with open(sweep_dir / "comparison.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert {row["algo"] for row in rows} == {"neat", "openai-es"}
    assert {row["configuration"] for row in rows} == {"neat reg=0 red-green-red", "openai-es reg=0 red-green-red"}
    assert all(row["n"] == "2" for row in rows if row["metric"].startswith(("C phase", "ACC_")))
    assert "| neat reg=0 red-green-red | 2 |" in (sweep_dir / "comparison.md").read_text()


def test_second_invocation_skips_finished_trials(smoke_sweep, capsys):
    sweep_dir, argv = smoke_sweep
    before = {p: p.stat().st_mtime_ns for p in sweep_dir.glob("*/metrics.csv")}
    assert len(before) == 4
    capsys.readouterr()
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert printed.count("skipped") == 4 and "0 to run" in printed
    assert "| neat reg=0 red-green-red | 2 |" in printed  # the table is printed at the end
    assert {p: p.stat().st_mtime_ns for p in sweep_dir.glob("*/metrics.csv")} == before
    assert all(row["status"] == "done" for row in _trials(sweep_dir).values())
    # a default stated is the same setting as a default left out; another value is not
    stated = [*argv, "--env", f"n_agents={ForagingConfig().n_agents}"]
    assert main(stated) == 0 and capsys.readouterr().out.count("skipped") == 4
    trial = build_grid(build_parser().parse_args([*stated[:-1], "n_agents=4"])).trials[0]
    state, why = trial_state(sweep_dir / trial.name, trial.config)
    assert state == "failed" and "other settings than the sweep gives this trial: --env n_agents=4 (stored: 5)" in why
    assert "--overwrite" in why and "drop those flags" not in why


def test_an_unfinished_trial_resumes_with_the_settings_it_was_created_with(smoke_sweep, tmp_path, capsys):
    """A trial whose settings equal the directory's only once resolved (a default stated in one,
    left out in the other) resumes, as run --resume would, and keeps the stored settings."""
    sweep_dir, argv = smoke_sweep
    copy = tmp_path / "neat-seed2"
    shutil.copytree(sweep_dir / "neat-seed2", copy)
    stored = (copy / "config.json").read_text()
    (copy / "summary.json").unlink()
    trial = build_grid(build_parser().parse_args([*argv, "--env", f"n_agents={ForagingConfig().n_agents}"])).trials[0]
    assert trial.name == "neat-seed2" and trial.config.env == {"duration": 60, "n_agents": 5}
    assert trial_state(copy, trial.config) == ("resume", "")
    result = run_trial(trial.config.to_dict(), str(copy), overwrite=False)
    assert result["status"] == "done", result
    assert (copy / "config.json").read_text() == stored
    assert trial_state(copy, trial.config) == ("done", "")


def test_failed_trial_is_reported_and_the_others_finish(local_ray, tmp_path, capsys):
    # a file holds the neat trial's directory: its run fails when it starts (a bad option would be
    # refused before any trial runs); OpenAI-ES runs
    (tmp_path / "failing").mkdir()
    (tmp_path / "failing" / "neat").write_text("not a run directory")
    argv = ["sweep", "--algo", "neat,openai-es", "--seed", "2", "--generations", "1",
            *SMOKE, "--out", str(tmp_path), "--name", "failing"]
    assert main(argv) == 1
    printed = capsys.readouterr().out
    trials = _trials(tmp_path / "failing")
    assert trials["openai-es"]["status"] == "done"
    assert trials["neat"]["status"] == "failed"
    assert "is a file" in trials["neat"]["error"] and "\n" not in trials["neat"]["error"]
    assert "failed neat" in printed and "is a file" in printed
    assert (tmp_path / "failing" / "openai-es" / "summary.json").is_file()


def test_ctrl_c_cancels_and_keeps_trials_csv(local_ray, tmp_path, monkeypatch, capsys):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(ray, "wait", interrupted)
    argv = ["sweep", "--algo", "openai-es", "--seed", "5,6", *SMOKE, "--out", str(tmp_path), "--name", "stopped"]
    assert main(argv) == 130
    assert "run the same command again" in capsys.readouterr().err
    assert {row["status"] for row in _trials(tmp_path / "stopped").values()} == {"pending"}


def test_grid_from_flags_and_file(tmp_path, capsys):
    sweep_file = tmp_path / "grid.toml"
    sweep_file.write_text('preset = "smoke"\nschedule = "red:2,green:1"\n[grid]\nreg = [0, 5]\nseed = [1, 2]\n'
                          '[grid.algo_options]\nreferences = [1, 2]\n')
    assert main(["sweep", "--config", str(sweep_file), "--seed", "7", "--algo", "neat",
                 "--out", str(tmp_path), "--dry-run"]) == 0
    printed = capsys.readouterr().out
    assert "sweep grid: 4 trial(s)" in printed
    assert [line.split()[-1] for line in printed.splitlines() if line.startswith("would run")] == \
        ["reg0-references1", "reg0-references2", "reg5-references1", "reg5-references2"]
    assert main(["sweep", "--schedule", "red-green-red,four-tasks;red:2,green:1", "--reg", "0,1.5",
                 "--out", str(tmp_path), "--name", "s", "--dry-run"]) == 0
    names = [line.split()[-1] for line in capsys.readouterr().out.splitlines() if line.startswith("would run")]
    assert names[:2] == ["red-green-red-reg0", "red-green-red-reg1.5"] and names[-1] == "red-2-green-1-reg1.5"
    assert main(["sweep", "--seed", "1,x", "--dry-run"]) == 2
    assert "--seed: 'x' is not an integer" in capsys.readouterr().err
    assert main(["sweep", "--seed", "1,1", "--dry-run"]) == 2


def test_regulariser_default_gives_each_family_of_a_grid_its_own(tmp_path, capsys):
    """``--regulariser default`` (documented, not refused): in a grid over families it says "each its
    own" beside another regulariser, which no family's own name can (another family refuses it)."""
    argv = ["sweep", "--algo", "neat,sep-cmaes", "--reg", "1", "--preset", "smoke", "--out", str(tmp_path), "--dry-run"]
    assert main([*argv, "--regulariser", "default,functional"]) == 0
    assert [line.split()[-1] for line in capsys.readouterr().out.splitlines() if line.startswith("would run")] == \
        ["neat-gd", "neat-functional", "sep-cmaes-l2", "sep-cmaes-functional"]
    assert main([*argv, "--regulariser", "gd,functional"]) == 2
    assert "--regulariser 'gd': sep-cmaes applies l2, ewc, functional" in capsys.readouterr().err


def test_grid_values_are_typed_as_a_run_types_them(tmp_path, capsys):
    argv = ["sweep", "--algo", "openai-es", "--preset", "smoke", "--out", str(tmp_path), "--name", "t", "--dry-run"]
    assert main([*argv, "--option", "hidden=[8],[8,8]", "--env", "see_other_agents=no,YES"]) == 0
    assert [line.split()[-1] for line in capsys.readouterr().out.splitlines() if line.startswith("would run")] == \
        ["hidden8-see_other_agentsFalse", "hidden8-see_other_agentsTrue",
         "hidden8-8-see_other_agentsFalse", "hidden8-8-see_other_agentsTrue"]
    for bad, message in ((["--env", "see_other_agents=no,nah"], "--env see_other_agents: 'nah' is not a boolean"),
                         (["--option", "hidden=[8],[0]"], "--option hidden: '[0]' is not a list of at most 16 integers"),
                         (["--algo", "openai-es,neat", "--option", "sigma=0.05"],
                          "unknown neat option 'sigma'")):
        assert main([*argv, *bad]) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1
    assert not (tmp_path / "t").exists()


def _summary(c1: float, r_top: float, complete: bool = True) -> dict:
    # the population's best (C) is above the top individual's (C_top): selection scores the latter
    summary = {"phases": ["red", "green", "red"], "current": [5.0, c1 + 10, 6.0],
               "current_top": [5.0, c1, 6.0], "wall_time_s": 1.0,
               "forgetting": [{"at_end_of": 1, "task": "red", "C": 5.0, "R_pop": r_top + 1, "R_top": r_top,
                               "F_pop": 0.0, "F_top": 0.0}]}
    if complete:
        summary["R_top"] = [[5.0, 0.0, 0.0], [r_top, c1, 0.0], [6.0, 1.0, 6.0]]
    return summary


def test_model_specific_lambda_selection():
    base = {"algo": "neat", "schedule": "red-green-red", "population": 12, "record": False}
    runs = []
    # seed 1: lambda 5 wins on C1 + R_top (4 + 3 = 7 > 6 > 5); seed 2: lambda 0 and 11 tie at 8 -> smaller lambda
    for seed, reg, c1, r_top in [(1, 0, 5.0, 1.0), (1, 5, 4.0, 3.0), (1, 11, 2.0, 4.0),
                                 (2, 0, 6.0, 2.0), (2, 5, 3.0, 3.0), (2, 11, 7.0, 1.0)]:
        runs.append(({**base, "seed": seed, "reg": float(reg), "record": seed == 1}, _summary(c1, r_top),
                     f"neat-reg{reg}-seed{seed}"))
    # another configuration (population) with one lambda only: no m.s. row for it
    runs.append(({**base, "population": 30, "seed": 1, "reg": 0.0}, _summary(9.0, 9.0), "big"))
    (selection,) = select_model_specific(runs)
    assert selection["config"]["population"] == 12
    assert [(c["seed"], c["reg"], c["score"], c["tag"]) for c in selection["choices"]] == \
        [(1, 5.0, 7.0, "neat-reg5-seed1"), (2, 0.0, 8.0, "neat-reg0-seed2")]
    # one lambda for both seeds: means 0: 7.0, 5: 6.5, 11: 7.0 -> 0 (tie with 11: the smaller)
    assert selection["shared"] == {"reg": 0.0, "means": {0.0: 7.0, 5.0: 6.5, 11.0: 7.0}}
    # every seed chooses among the same lambdas: a seed that did not run one of them is left out,
    # of the choice per seed and of the one lambda for all seeds (seed 1 alone: 0: 6, 5: 7, 11: 6)
    (partial,) = select_model_specific([r for r in runs if r[2] != "neat-reg0-seed2"])
    assert [(c["seed"], c["reg"]) for c in partial["choices"]] == [(1, 5.0)]
    assert partial["shared"] == {"reg": 5.0, "means": {0.0: 6.0, 5.0: 7.0, 11.0: 6.0}}
    assert partial["left_out"] == {2: [5.0, 11.0]} and selection["left_out"] == {}
    assert list(partial["candidates"]) == [1]
    # so do the seeds of a second sweep that ran only some lambdas (the study's parts 1 and 2)
    extra = [({**base, "seed": 3, "reg": float(reg)}, _summary(c1, r_top), f"neat-reg{reg}-seed3")
             for reg, c1, r_top in [(0, 1.0, 1.0), (11, 9.0, 9.0)]]
    (mixed,) = select_model_specific(runs + extra)
    assert [c["tag"] for c in mixed["choices"]] == [c["tag"] for c in selection["choices"]]
    assert mixed["shared"] == selection["shared"] and mixed["left_out"] == {3: [0.0, 11.0]}
    _, report = model_specific_report([mixed], {tag: summary for _, summary, tag in runs + extra},
                                      [config for config, _, _ in runs + extra])
    assert ("lambda per seed: 1: 5, 2: 0. Left out, as they did not finish every lambda of 0, 5, 11: "
            "seeds 3 (finished 0 and 11)") in report
    # none finished every lambda: no row
    assert select_model_specific([r for r in runs if r[2] not in ("neat-reg0-seed2", "neat-reg5-seed1")]) == []
    # an unfinished run is scored from its forgetting rows; before the end of phase 1 it is not scored
    assert selection_score(_summary(4.0, 3.0, complete=False)) == 7.0
    assert selection_score({"phases": ["red"], "current": [5.0], "forgetting": []}) is None
    # the report: its own row with the lambda per seed, the mean of the chosen runs
    rows, markdown = model_specific_report([selection], {tag: summary for _, summary, tag in runs},
                                           [config for config, _, _ in runs])
    (line,) = [row for row in markdown.splitlines() if row.startswith("| neat reg=m.s.")]
    # the criterion's mean with its t-interval: 7.5 +- t_0.975(1) * |7 - 8| / 2, t_0.975(1) = 12.706
    assert "| 2 | 1: 5, 2: 0 | 0 (0: 7.00, 5: 6.50, 11: 7.00) | 7.50 [1.15, 13.85] |" in line
    c1 = next(row for row in rows if row["metric"] == "C_top phase 1 (green)")
    assert c1["values"] == [4.0, 6.0] and c1["reg"] == "m.s. 5 0" and c1["mean"] == 5.0
    assert next(row for row in rows if row["metric"] == "C phase 1 (green)")["values"] == [14.0, 16.0]


def test_model_specific_lambda_has_the_unregularised_run_as_candidate_of_its_own_regulariser():
    """The families sweep runs lambda 0 once, naming no importance (so the family's default, l2),
    and lambda 100 with either importance: L2 chooses between 100 and none; for EWC (here run at 10
    and 100 too) the run without one is the point of comparison, shown, never chosen, and an EWC run
    at lambda 0 would be its candidate. Each m.s. row is named by its regulariser."""
    base = {"algo": "sep-cmaes", "schedule": "red-green-red", "population": 12}
    runs = []
    for seed, variant, reg, c1, r_top in [(1, "none", 0, 5.0, 1.0), (1, "l2", 100, 4.0, 3.0), (1, "ewc", 100, 2.0, 1.0),
                                          (1, "ewc", 10, 1.0, 1.0), (2, "none", 0, 6.0, 2.0), (2, "l2", 100, 3.0, 3.0),
                                          (2, "ewc", 100, 7.0, 4.0), (2, "ewc", 10, 1.0, 1.0)]:
        options = {} if variant == "none" else {"importance": variant}
        config = RunConfig(**base, seed=seed, reg=float(reg), algo_options=options)
        written = {**config.validate(machine=False).to_dict(), "algo_options_resolved": config.algo_options_resolved()}
        runs.append((written, _summary(c1, r_top), f"{variant}{reg}-seed{seed}"))
    selections = select_model_specific(runs)
    chosen = {s["config"]["regulariser"]: [c["tag"] for c in s["choices"]] for s in selections}
    assert chosen == {"l2": ["l2100-seed1", "none0-seed2"], "ewc": ["ewc100-seed1", "ewc100-seed2"]}
    ewc = next(s for s in selections if s["config"]["regulariser"] == "ewc")
    assert ewc["lambdas"] == [10.0, 100.0] and ewc["shared"] == {"reg": 100.0, "means": {10.0: 2.0, 100.0: 7.0},
                                                                  "lambda_0": 7.0}
    configs = [config for config, _, _ in runs]
    assert sorted(model_specific_label(s["config"], configs) for s in selections) == [
        "sep-cmaes reg=m.s. red-green-red regulariser=ewc", "sep-cmaes reg=m.s. red-green-red regulariser=l2"]
    at_zero = RunConfig(**base, seed=1, reg=0.0, algo_options={"importance": "ewc"}).validate(machine=False)
    named = ({**at_zero.to_dict(), "algo_options_resolved": at_zero.algo_options_resolved()}, _summary(9.0, 9.0), "e0")
    (one_seed,) = [s for s in select_model_specific(runs + [named]) if s["config"]["regulariser"] == "ewc"]
    assert one_seed["lambdas"] == [0.0, 10.0, 100.0] and [c["tag"] for c in one_seed["choices"]] == ["e0"]


def test_the_study_chooses_among_its_grid_with_lambda_0_the_point_of_comparison():
    """docs/studies/regularisers-and-archive.md, step 1: lambda 0 (the fine-tune run every other run
    of its seed takes its first task from) is "the choice's point of comparison, not a candidate",
    and weight protection's (lambda_1, lambda_2) pairs are the swept values, one choice among them.
    Here lambda 0 scores best on both seeds, wp's second pair and functional's 10 best among theirs."""
    runs = []
    for seed in (1, 2):
        for regulariser, reg, options, c1, r_top in [
                ("default", 0, {}, 9.0, 9.0), ("wp", 0.4, {"lambda_2": 0.3}, 2.0, 1.0),
                ("wp", 4, {"lambda_2": 3.0}, 3.0, 2.0), ("functional", 1, {}, 1.0, 1.0), ("functional", 10, {}, 4.0, 1.0)]:
            config = RunConfig(algo="neat", schedule="red:100,green:100", population=12, seed=seed, reg=float(reg),
                               regulariser=regulariser, algo_options={"genetics": "0.92", **options})
            config = config.validate(machine=False)
            written = {**config.to_dict(), "algo_options_resolved": config.algo_options_resolved()}
            runs.append((written, _summary(c1 + seed, r_top), f"{regulariser}-{reg}-seed{seed}"))
    selections = {s["config"]["regulariser"]: s for s in select_model_specific(runs)}
    assert sorted(selections) == ["functional", "wp"]  # one wp configuration, not one per lambda_2
    wp, functional = selections["wp"], selections["functional"]
    assert wp["lambdas"] == [(0.4, 0.3), (4.0, 3.0)] and functional["lambdas"] == [1.0, 10.0]
    assert [c["reg"] for c in wp["choices"]] == [(4.0, 3.0)] * 2 and wp["shared"]["reg"] == (4.0, 3.0)
    assert [c["reg"] for c in functional["choices"]] == [10.0] * 2 and functional["shared"]["reg"] == 10.0
    assert wp["shared"]["lambda_0"] == functional["shared"]["lambda_0"] == 19.5
    configs = [config for config, _, _ in runs]
    _, markdown = model_specific_report(list(selections.values()), {tag: summary for _, summary, tag in runs}, configs)
    assert ("| neat reg=m.s. red:100,green:100 regulariser=wp | 2 | 1: (4, 3), 2: (4, 3) | (4, 3) ((0.4, 0.3): 4.50, "
            "(4, 3): 6.50; lambda 0, not a candidate: 19.50) |") in markdown
    assert "| neat reg=m.s. red:100,green:100 regulariser=functional | 2 | 1: 10, 2: 10 | 10 (1: 3.50, 10: 6.50; " \
        "lambda 0, not a candidate: 19.50) |" in markdown


def test_a_trial_name_keeps_an_option_ending_in_a_digit_apart_from_its_value(tmp_path):
    """wp's lambda_2 at 0.003 read as lambda_20.003 (lambda_20 = .003) in a trial's name."""
    sweep_file = tmp_path / "wp.toml"
    sweep_file.write_text('preset = "smoke"\n[grid]\nseed = [1, 2]\nvariants = [{ reg = 0 }, '
                          '{ regulariser = "wp", reg = 0.004, algo_options = { lambda_2 = 0.003 } }]\n')
    grid = build_grid(build_parser().parse_args(["sweep", "--config", str(sweep_file), "--out", str(tmp_path)]))
    assert [t.name for t in grid.trials] == ["reg0-seed1", "reg0-seed2", "wp-reg0.004-lambda_2=0.003-seed1",
                                            "wp-reg0.004-lambda_2=0.003-seed2"]


def test_variants_give_values_together(tmp_path, capsys):
    """``variants``: each a set of values given together, so an ES's lambda can go with its
    importance (and lambda = 0 run once) where a product of axes would run every pairing."""
    sweep_file = tmp_path / "families.toml"
    sweep_file.write_text(
        'preset = "smoke"\n[grid]\nalgo = ["neat", "openai-es"]\nseed = [1, 2]\n[grid.neat]\nreg = [0, 11]\n'
        '[grid.openai-es]\nvariants = [{ reg = 0 }, { reg = 10, algo_options = { importance = "l2" } },\n'
        '  { reg = 100, algo_options = { importance = "ewc", sigma = 0.05 } }]\n')
    grid = build_grid(build_parser().parse_args(["sweep", "--config", str(sweep_file), "--out", str(tmp_path)]))
    by_name = {t.name: t.config for t in grid.trials}
    assert list(by_name) == ["neat-reg0-seed1", "neat-reg11-seed1", "neat-reg0-seed2", "neat-reg11-seed2",
                             *(name for seed in (1, 2) for name in (
                                 f"openai-es-reg0-seed{seed}", f"openai-es-reg10-importancel2-seed{seed}",
                                 f"openai-es-reg100-importanceewc-sigma0.05-seed{seed}"))]
    assert by_name["openai-es-reg0-seed2"].algo_options == {} and by_name["openai-es-reg0-seed2"].reg == 0
    assert by_name["openai-es-reg10-importancel2-seed1"].algo_options == {"importance": "l2"}
    assert by_name["openai-es-reg100-importanceewc-sigma0.05-seed1"].algo_options == {"importance": "ewc", "sigma": 0.05}
    assert by_name["openai-es-reg100-importanceewc-sigma0.05-seed1"].reg == 100.0
    assert grid.columns == ["algo", "reg", "algo_options.importance", "algo_options.sigma", "seed"]
    # a flag wins over the variants too; variants it makes equal are one
    args = build_parser().parse_args(["sweep", "--config", str(sweep_file), "--algo", "openai-es",
                                      "--option", "importance=l2", "--option", "sigma=0.1", "--seed", "1"])
    assert [(t.name, t.config.reg) for t in build_grid(args).trials] == [("reg0", 0.0), ("reg10", 10.0), ("reg100", 100.0)]
    args = build_parser().parse_args(["sweep", "--config", str(sweep_file), "--algo", "openai-es", "--reg", "5",
                                      "--option", "importance=l2", "--option", "sigma=0.1", "--seed", "1"])
    assert [(t.name, t.config.reg) for t in build_grid(args).trials] == [("openai-es-red-green-red-reg5-seed1", 5.0)]
    for text, message in (
            ('[grid]\nvariants = [1, 2]\n', "variants in"),
            ('[grid]\nvariants = []\n', "must be a list of tables"),
            ('[grid]\nvariants = [{ algo = "snes" }]\n', "unknown key 'algo' in [grid] variants"),
            ('[grid]\nvariants = [{ reg = "ten" }]\n', "--reg"),
            ('[grid]\nreg = [0, 1]\nvariants = [{ reg = 2 }]\n', "reg in"),
            ('[grid]\nalgo = ["neat", "snes"]\nreg = [0, 1]\n[grid.snes]\nvariants = [{ reg = 2 }]\n',
             "reg is an axis of every trial and of [grid.snes] too")):
        sweep_file.write_text(text)
        assert main(["sweep", "--config", str(sweep_file), "--out", str(tmp_path), "--dry-run"]) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, err


@pytest.mark.parametrize("argv, message", [
    # two spellings of one schedule ran one experiment twice
    (["--schedule", "red:2;red:02"], "the trials of {'schedule': 'red:2'} and of {'schedule': 'red:02'} are one "
                                     "trial, {'schedule': 'red:2'}: give each value once"),
    (["--schedule", "red:2,green;red:2,green:2", "--generations", "2"], "are one trial"),
    (["--reg", "0,-0"], "reg lists a value twice ([0.0, 0.0]): give each value once"),
    # the last of them was kept
    (["--env", "duration=30", "--env", "duration=40,50"],
     "--env duration is given twice (duration=30 and duration=40,50): give it once"),
])
def test_a_value_given_twice_is_refused(argv, message, tmp_path, capsys):
    assert main(["sweep", "--preset", "smoke", *argv, "--out", str(tmp_path / "sweeps"), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err
    assert not (tmp_path / "sweeps").exists()


def test_one_grid_for_algorithms_whose_options_differ(tmp_path, capsys):
    """[grid.<algo>] gives axes and fixed values to one algorithm's trials only: NEAT's genetics
    and lambdas next to an ES's sigma and lambdas, in one sweep."""
    sweep_file = tmp_path / "families.toml"
    sweep_file.write_text('preset = "smoke"\n[grid]\nalgo = ["neat", "openai-es", "sep-cmaes"]\nseed = [1, 2]\n'
                          '[grid.neat]\nreg = [0, 11]\nalgo_options = { genetics = "2.0" }\n'
                          '[grid.openai-es]\nreg = [0, 0.5]\nalgo_options = { sigma = [0.05, 0.1] }\n')
    args = build_parser().parse_args(["sweep", "--config", str(sweep_file), "--out", str(tmp_path)])
    grid = build_grid(args)
    by_name = {t.name: t.config for t in grid.trials}
    assert list(by_name) == ["neat-reg0-seed1", "neat-reg11-seed1", "neat-reg0-seed2", "neat-reg11-seed2",
                             *(f"openai-es-reg{r}-sigma{s}-seed{seed}" for seed in (1, 2) for r in ("0", "0.5")
                               for s in ("0.05", "0.1")),
                             "sep-cmaes-seed1", "sep-cmaes-seed2"]
    assert by_name["neat-reg11-seed2"].algo_options == {"genetics": "2.0"} and by_name["neat-reg11-seed2"].reg == 11
    assert by_name["openai-es-reg0.5-sigma0.1-seed1"].algo_options == {"sigma": 0.1}
    assert by_name["sep-cmaes-seed1"].algo_options == {} and by_name["sep-cmaes-seed1"].reg == 0
    assert grid.columns == ["algo", "reg", "algo_options.sigma", "seed"]
    # a flag wins over the file everywhere, the algorithms' own tables included
    args = build_parser().parse_args(["sweep", "--config", str(sweep_file), "--reg", "1", "--algo", "neat,openai-es"])
    assert sorted({t.config.reg for t in build_grid(args).trials}) == [1.0]
    for text, message in (('[grid]\nalgo = ["neat"]\n[grid.openai-es]\nreg = [0, 1]\n', "no trial runs openai-es"),
                          ('[grid]\nalgo = ["neat", "snes"]\nreg = [0, 1]\n[grid.neat]\nreg = [0, 11]\n',
                           "reg is an axis of every trial and of [grid.neat] too"),
                          ('[grid]\nalgo = ["neat", "snes"]\n[grid.neat]\nalgo = ["snes"]\n',
                           "unknown [grid.neat] key 'algo'")):
        sweep_file.write_text(text)
        assert main(["sweep", "--config", str(sweep_file), "--out", str(tmp_path), "--dry-run"]) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, err


def test_rays_driver_messages_go_to_the_sweeps_log(tmp_path, capsys):
    """The error messages Ray's driver prints from its own thread (a dead node's state dump among
    them) are looked up by name in Ray's worker module on every message: inside a sweep they land
    in ray.log, and nothing reaches the sweep's output."""
    from ray._private import worker

    from lifelong_evo.commands.ray_cluster import RAY_LOG, _ray_messages_to

    original = worker.print_to_stdstream
    with _ray_messages_to(tmp_path / RAY_LOG):
        worker.print_to_stdstream({"lines": ["[state-dump] NodeManager:", "[state-dump] Node ID: x"],
                                   "pid": "raylet", "is_err": False}, ignore_prefix=False)
    assert worker.print_to_stdstream is original
    logged = (tmp_path / RAY_LOG).read_text().splitlines()
    assert [line.split(" ", 2)[2] for line in logged] == \
        ["(raylet) [state-dump] NodeManager:", "(raylet) [state-dump] Node ID: x"]
    printed = capsys.readouterr()
    assert "state-dump" not in printed.out + printed.err


def test_a_trial_sharing_the_machine_repeats_a_run_alone(smoke_sweep, tmp_path):
    """Trials run side by side (here four on two cores; on a GPU machine, several on one device
    with --gpus-per-trial) and each gives the numbers it gives alone with the same settings."""
    sweep_dir, _argv = smoke_sweep
    assert main(["--algo", "neat", "--seed", "2", "--generations", "2", *SMOKE, "--threads", "1",
                 "--out", str(tmp_path), "--name", "alone", "--quiet"]) == 0
    assert (tmp_path / "alone/metrics.csv").read_bytes() == (sweep_dir / "neat-seed2/metrics.csv").read_bytes()


def test_trials_run_together_repeat_the_trials_run_apart(smoke_sweep, tmp_path, monkeypatch, capsys):
    """--together plays the four trials' evaluations in one batch per generation, in this process;
    each trial writes the numbers it wrote as a Ray trial of its own."""
    import lifelong_evo.commands.sweep as sweep

    sweep_dir, argv = smoke_sweep
    together = [*argv[:argv.index("--out")], "--out", str(tmp_path), "--name", "smoke", "--together"]
    monkeypatch.setattr(sweep, "STATUS_EVERY_S", 0.0)
    assert main(together) == 0
    printed = capsys.readouterr().out
    assert "[0/4] 4 running together;" in printed and "[4/4] done" in printed
    trials = _trials(tmp_path / "smoke")
    assert {row["status"] for row in trials.values()} == {"done"}
    for name in trials:
        for file in ("metrics.csv", "controllers/final-top.json"):
            assert (tmp_path / "smoke" / name / file).read_bytes() == (sweep_dir / name / file).read_bytes(), (name, file)


@pytest.mark.parametrize("extra, message", [
    (["--eval-threads", "2"], "has --eval-threads 2: pass --eval-threads 1"),
    (["--workers", "2"], "--together runs every trial in this process, without Ray: drop --address"),
])
def test_together_refuses_what_it_cannot_do_before_writing(extra, message, tmp_path, capsys):
    argv = ["sweep", "--algo", "neat", "--seed", "2", *SMOKE, "--out", str(tmp_path), "--name", "t", "--together",
            *extra]
    assert main(argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "t").exists()


def test_together_stopped_by_ctrl_c_resumes_to_the_same_numbers(smoke_sweep, tmp_path, monkeypatch, capsys):
    """Ctrl-C in the middle of a --together sweep keeps every trial's checkpoints; the same command
    again resumes them all and writes what the uninterrupted Ray sweep wrote."""
    import lifelong_evo.loop as loop

    sweep_dir, argv = smoke_sweep
    together = [*argv[:argv.index("--out")], "--out", str(tmp_path), "--name", "smoke", "--together"]
    real, calls = loop.evaluate_together, []

    def stopped_after_three(evaluations):
        calls.append(1)
        if len(calls) > 3:
            raise KeyboardInterrupt
        return real(evaluations)

    monkeypatch.setattr(loop, "evaluate_together", stopped_after_three)
    assert main(together) == 130
    assert "run the same command again" in capsys.readouterr().err
    assert {row["status"] for row in _trials(tmp_path / "smoke").values()} == {"pending"}
    monkeypatch.setattr(loop, "evaluate_together", real)
    assert main(together) == 0
    for name in _trials(tmp_path / "smoke"):
        assert (tmp_path / "smoke" / name / "metrics.csv").read_bytes() == (sweep_dir / name / "metrics.csv").read_bytes()


def test_share_first_task_runs_each_pair_in_turn_with_the_numbers_of_separate_runs(local_ray, tmp_path, capsys):
    """--share-first-task: each lambda > 0 trial runs right after its lambda = 0 sibling and takes
    over its first task; every trial's files hold the numbers of the sweep without it."""
    grid = ["sweep", "--algo", "neat", "--reg", "0,2", "--seed", "4,5", "--schedule", "red:2,green:2", *SMOKE,
            "--out", str(tmp_path), "--workers", "1"]  # one at a time: a source has ended its first task
    assert main([*grid, "--name", "shared", "--share-first-task", "--dry-run"]) == 0
    planned = [line.split()[-1] for line in capsys.readouterr().out.splitlines() if line.startswith("would run")]
    assert planned == ["reg0-seed4", "reg2-seed4", "reg0-seed5", "reg2-seed5"]
    assert main([*grid, "--name", "shared", "--share-first-task"]) == 0
    assert main([*grid, "--name", "plain"]) == 0
    trials = _trials(tmp_path / "shared")
    for name in trials:
        source = tmp_path / "shared" / name.replace("reg2", "reg0")
        assert trials[name]["first_task_from"] == ("" if name.startswith("reg0") else str(source.resolve()))
        for file in ("metrics.csv", "species.csv", "controllers/task1-green-top.json"):
            assert (tmp_path / "shared" / name / file).read_bytes() == (tmp_path / "plain" / name / file).read_bytes()
        held_out = [json.loads((tmp_path / sweep / name / "summary.json").read_text())["held_out"]
                    for sweep in ("shared", "plain")]
        assert held_out[0] == held_out[1]
    # run again: finished trials are skipped, and trials.csv still says where each first task came from
    assert main([*grid, "--name", "shared", "--share-first-task"]) == 0
    assert _trials(tmp_path / "shared") == trials
    # a trial stopped after taking over its first task resumes and still says where it came from
    resumed = tmp_path / "shared" / "reg2-seed5"
    (resumed / "summary.json").unlink()
    for later in sorted(resumed.glob("checkpoints/generation-*.pt"))[1:]:
        later.unlink()
    assert main([*grid, "--name", "shared", "--share-first-task"]) == 0
    assert "resume  reg2-seed5" in "".join(capsys.readouterr())
    assert _trials(tmp_path / "shared")["reg2-seed5"]["first_task_from"] == trials["reg2-seed5"]["first_task_from"]


@pytest.mark.parametrize("order", ["sources-last", "sources-first"])
def test_an_overwriting_sweep_never_starts_a_trial_from_a_first_task_it_deletes(tmp_path, monkeypatch, order, capsys):
    """``--overwrite --share-first-task``: a lambda > 0 trial that starts before its restarted
    lambda = 0 sibling has deleted its old files (workers at once; here Ray is played in this
    process, in the order given) took over that old first task, which the sibling then deleted
    while it was read. It runs its first task itself; once the sibling has written its first
    task again, that is taken over."""
    from lifelong_evo.commands import ray_cluster

    def in_turn(jobs, function, *, on_result, **settings):
        order_ = range(len(jobs)) if order == "sources-first" else reversed(range(len(jobs)))
        for index in order_:
            on_result(index, function(*jobs[index].args), "")

    grid = ["sweep", "--algo", "neat", "--reg", "0,2", "--schedule", "red:2,green:2", *SMOKE, "--eval-threads", "1",
            "--out", str(tmp_path), "--name", "shared"]
    assert main([*grid, "--together"]) == 0
    first = {name: (tmp_path / "shared" / name / "metrics.csv").read_bytes() for name in ("reg0", "reg2")}
    # a second link keeps the old file's inode allocated, so the rewritten file cannot reuse its number
    old_first_task = tmp_path / "old-first-task-end.pt"
    os.link(tmp_path / "shared/reg0/checkpoints/first-task-end.pt", old_first_task)
    monkeypatch.setattr(ray_cluster, "run_jobs", in_turn)
    assert main([*grid, "--overwrite", "--share-first-task"]) == 0
    trials = _trials(tmp_path / "shared")
    assert trials["reg0"]["status"] == trials["reg2"]["status"] == "done", trials
    source = str(tmp_path.resolve() / "shared" / "reg0") if order == "sources-first" else ""
    assert trials["reg2"]["first_task_from"] == source, trials
    assert (tmp_path / "shared/reg0/checkpoints/first-task-end.pt").stat().st_ino != old_first_task.stat().st_ino
    for name, metrics in first.items():
        assert (tmp_path / "shared" / name / "metrics.csv").read_bytes() == metrics, name


def test_share_first_task_takes_a_first_task_over_from_another_regulariser(tmp_path, monkeypatch, capsys):
    """A grid over NEAT's regularisers at one lambda: nothing they add acts before the first task's
    end, so the wp trial takes over the gd trial's first task (it played it again) and has the numbers
    it has alone. (Ray played in this process, one trial after the other.)"""
    from lifelong_evo.commands import ray_cluster

    def in_turn(jobs, function, *, on_result, **settings):
        for index in range(len(jobs)):
            on_result(index, function(*jobs[index].args), "")

    monkeypatch.setattr(ray_cluster, "run_jobs", in_turn)
    grid = ["sweep", "--algo", "neat", "--regulariser", "gd,wp", "--reg", "2", "--schedule", "red:2,green:2", *SMOKE,
            "--held-out-episodes", "1", "--out", str(tmp_path)]
    # with lambda 0 among them, the fine-tuning trials first, whatever their regulariser
    assert main([*grid[:6], "2,0", *grid[7:], "--name", "order", "--share-first-task", "--dry-run"]) == 0
    assert [line.split()[-1] for line in capsys.readouterr().out.splitlines() if line.startswith("would run")] == \
        ["gd-reg0", "wp-reg0", "gd-reg2", "wp-reg2"]
    assert main([*grid, "--name", "shared", "--share-first-task"]) == 0
    trials = _trials(tmp_path / "shared")
    assert [trials[name]["first_task_from"] for name in ("gd", "wp")] == ["", str((tmp_path / "shared/gd").resolve())]
    assert main(["--algo", "neat", "--regulariser", "wp", "--reg", "2", "--schedule", "red:2,green:2", *SMOKE,
                 "--held-out-episodes", "1", "--out", str(tmp_path), "--name", "alone", "--quiet"]) == 0
    for file in ("metrics.csv", "species.csv", "controllers/task1-green-top.json"):
        assert (tmp_path / "shared/wp" / file).read_bytes() == (tmp_path / "alone" / file).read_bytes()


def test_first_task_from_needs_share_first_task(tmp_path, capsys):
    assert main(["sweep", "--algo", "neat", *SMOKE, "--out", str(tmp_path), "--first-task-from", str(tmp_path)]) == 2
    assert "add --share-first-task" in capsys.readouterr().err
    assert main(["sweep", "--algo", "neat", *SMOKE, "--out", str(tmp_path), "--share-first-task", "--together",
                 "--eval-threads", "1"]) == 2
    assert "drop one of them" in capsys.readouterr().err


def test_only_runs_the_picked_trials_and_leaves_the_others_as_they_are(tmp_path, capsys):
    """--only: the trials whose names match a pattern run, the others are neither run nor resumed
    nor, with --overwrite, restarted; a later sweep without it runs the rest and skips the picked."""
    grid = ["sweep", "--algo", "neat", "--reg", "0,2", "--seed", "4,5", "--schedule", "red:2,green:2", *SMOKE,
            "--eval-threads", "1", "--together", "--out", str(tmp_path), "--name", "part"]
    assert main([*grid, "--only", "reg0-*", "--only", "reg2-seed5", "--dry-run"]) == 0
    printed = capsys.readouterr().out
    assert [line.split()[-1] for line in printed.splitlines() if line.startswith("would run")] == [
        "reg0-seed4", "reg0-seed5", "reg2-seed5"]
    assert "left    reg2-seed4 (not picked by --only)" in printed
    assert main([*grid, "--only", "*-seed4"]) == 0
    assert sorted(p.name for p in (tmp_path / "part").iterdir() if p.is_dir()) == ["reg0-seed4", "reg2-seed4"]
    assert {name: row["status"] for name, row in _trials(tmp_path / "part").items()} == {
        "reg0-seed4": "done", "reg2-seed4": "done", "reg0-seed5": "pending", "reg2-seed5": "pending"}
    kept = (tmp_path / "part/reg0-seed4/metrics.csv").stat().st_mtime_ns
    assert main([*grid, "--only", "reg0-seed5,reg2-seed5", "--overwrite"]) == 0
    assert (tmp_path / "part/reg0-seed4/metrics.csv").stat().st_mtime_ns == kept
    assert {row["status"] for row in _trials(tmp_path / "part").values()} == {"done"}
    capsys.readouterr()
    assert main(grid) == 0
    assert "skipped reg2-seed5 (done)" in capsys.readouterr().out


@pytest.mark.parametrize("patterns, says", [
    (["neat-*-seed9"], "--only 'neat-*-seed9' matches none of the grid's 2 trials"),
    (["seed4,"], "--only has an empty pattern"),
])
def test_only_refuses_a_pattern_that_picks_nothing_before_writing(patterns, says, tmp_path, capsys):
    argv = ["sweep", "--algo", "neat", "--seed", "4,5", *SMOKE, "--out", str(tmp_path), "--name", "t"]
    assert main([*argv, *(item for p in patterns for item in ("--only", p))]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and says in err
    assert not (tmp_path / "t").exists()
