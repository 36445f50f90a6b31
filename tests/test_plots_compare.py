"""``plot`` and ``compare`` on real smoke runs: 2 seeds of NEAT and 1 of OpenAI-ES."""
from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from lifelong_evo.analysis import figures as plots
from lifelong_evo.commands.cli import main as cli_main

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def sweep(tmp_path_factory) -> Path:
    """A sweep-like folder: runs two levels down, named without their seed."""
    root = tmp_path_factory.mktemp("sweep")
    for algo, seed, reg, name in (("neat", 1, "1", "a"), ("neat", 2, "1", "b"), ("openai-es", 1, "0", "c")):
        assert cli_main(["--algo", algo, "--reg", reg, "--seed", str(seed), "--preset", "smoke", "--no-record",
                         "--generations", "3", "--env", "duration=60",
                         "--quiet", "--out", str(root / algo), "--name", name]) == 0
    return root


def summaries(sweep: Path, algo: str) -> list[dict]:
    return [json.loads((run / "summary.json").read_text()) for run in sorted((sweep / algo).iterdir())]


ENDS = ("task0-red", "task1-green", "task2-red")
"""The task ends of the paper's schedule, each with a network figure."""


def test_plot_writes_every_figure_kind(sweep, tmp_path, capsys):
    out = tmp_path / "figures"
    assert cli_main(["plot", str(sweep), "--out", str(out)]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted([
        "neat-red-green-red-reg1-retention-pop.png", "neat-red-green-red-reg1-retention-top.png",
        "neat-red-green-red-reg1-species.png", "neat-red-green-red-reg1-lifespans-seed1.png",
        "neat-red-green-red-reg1-lifespans-seed2.png",
        *(f"neat-red-green-red-reg1-network-{end}-seed{seed}.png" for end in ENDS for seed in (1, 2)),
        "openai-es-red-green-red-reg0-retention-pop.png", "openai-es-red-green-red-reg0-retention-top.png",
        *(f"openai-es-red-green-red-reg0-network-{end}.png" for end in ENDS)])
    for path in out.iterdir():
        data = path.read_bytes()
        assert data.startswith(PNG) and len(data) > 10_000, path.name
    assert capsys.readouterr().out.count(".png") == len(names)


def test_plot_single_run_defaults_to_its_directory(sweep):
    run = sweep / "openai-es" / "c"
    assert cli_main(["plot", str(run)]) == 0
    assert (run / "openai-es-red-green-red-reg0-retention-pop.png").is_file()


def test_plot_of_several_runs_writes_next_to_them(sweep, tmp_path, monkeypatch):
    """Not into the working directory: into the folder holding the runs, as a sweep's directory."""
    runs = tmp_path / "my-sweep"
    shutil.copytree(sweep / "neat", runs)
    monkeypatch.chdir(tmp_path)
    assert cli_main(["plot", str(runs)]) == 0
    assert (runs / "neat-red-green-red-reg1-retention-pop.png").is_file()
    assert (runs / "neat-red-green-red-reg1-lifespans-seed2.png").is_file()
    assert not (tmp_path / "plots").exists()
    written = sorted(p.name for p in runs.glob("*.png"))
    for png in runs.glob("*.png"):
        png.unlink()
    assert cli_main(["plot", str(runs / "a"), str(runs / "b")]) == 0  # runs given one by one
    assert sorted(p.name for p in runs.glob("*.png")) == written
    assert not (tmp_path / "plots").exists()


def test_configurations_apart_only_in_an_option_get_their_own_figures_and_labels(sweep, tmp_path, capsys):
    """Two configurations of one algorithm and lambda that differ in an option (here sigma) are
    named and titled by it, in plot and compare, with no hand editing."""
    runs = tmp_path / "sigmas"
    shutil.copytree(sweep / "openai-es" / "c", runs / "wide")
    shutil.copytree(sweep / "openai-es" / "c", runs / "narrow")
    config_file = runs / "narrow" / "config.json"
    config = json.loads(config_file.read_text())
    config["algo_options"] = {"sigma": 0.05}
    config["algo_options_resolved"]["sigma"] = 0.05
    config_file.write_text(json.dumps(config))
    assert cli_main(["plot", str(runs), "--out", str(tmp_path / "figures")]) == 0
    names = sorted(p.name for p in (tmp_path / "figures").glob("*-retention-pop.png"))
    assert names == ["openai-es-red-green-red-reg0-sigma-0.05-retention-pop.png",
                     "openai-es-red-green-red-reg0-sigma-0.1-retention-pop.png"]
    assert cli_main(["compare", str(runs), "--out", str(tmp_path / "cmp")]) == 0
    table = (tmp_path / "cmp" / "comparison.md").read_text()
    assert "| openai-es reg=0 red-green-red sigma=0.05 | 1 |" in table
    assert "| openai-es reg=0 red-green-red sigma=0.1 | 1 |" in table


def test_compare_adds_the_model_specific_lambda_where_lambda_varies(sweep, tmp_path):
    runs = tmp_path / "lambdas"
    shutil.copytree(sweep / "neat", runs / "reg1")
    shutil.copytree(sweep / "neat", runs / "reg5")
    for config_file in (runs / "reg5").glob("*/config.json"):
        config_file.write_text(json.dumps({**json.loads(config_file.read_text()), "reg": 5.0}))
    assert cli_main(["compare", str(runs), "--out", str(tmp_path / "cmp")]) == 0
    (selection,) = json.loads((tmp_path / "cmp" / "model_specific_lambda.json").read_text())
    # equal scores at both lambdas (the same runs): the smaller lambda, for each seed and for all
    assert [c["reg"] for c in selection["choices"]] == [1.0, 1.0]
    assert selection["one_lambda_for_all_seeds"]["reg"] == 1.0
    assert [m["reg"] for m in selection["one_lambda_for_all_seeds"]["mean_per_lambda"]] == [1.0, 5.0]
    assert "## Model-specific lambda" in (tmp_path / "cmp" / "comparison.md").read_text()


def test_plot_series_follow_metrics(sweep):
    """The curves drawn are metrics.csv's: the current task's best (NaN elsewhere), the retention
    where measured, stacked over the two seeds."""
    from lifelong_evo.analysis.figures import current_by_task, retention_by_task
    from lifelong_evo.metrics_csv import read_metrics
    from lifelong_evo.runs import group_runs, load_run

    runs = [load_run(p) for p in sorted((sweep / "neat").iterdir())]
    groups = group_runs(runs)
    assert len(groups) == 1 and [r.seed for r in groups[0]] == [1, 2]
    metrics = [read_metrics(p / "metrics.csv") for p in sorted((sweep / "neat").iterdir())]
    generations, values = current_by_task(groups[0])["green"]
    assert values.shape == (2, 9)
    for seed, rows in enumerate(metrics):
        expected = [float(r["best"]) if r["task"] == "green" else np.nan for r in rows]
        np.testing.assert_array_equal(values[seed], expected)
    generations, values = retention_by_task(groups[0], "top")["red"]
    measured = [int(r["generation"]) for r in metrics[0] if r["retention_top_red"]]
    drawn = ~np.isnan(values).all(axis=0)
    assert list(generations[drawn]) == measured and measured
    np.testing.assert_array_equal(values[1][drawn], [float(r["retention_top_red"]) for r in metrics[1]
                                                     if r["retention_top_red"]])
    # NaN (a break in the dashed line) exactly where red is the current task
    assert [int(r["generation"]) for r in metrics[0] if r["task"] == "red"] == list(generations[~drawn])


def test_compare_groups_configurations_and_matches_hand_computation(sweep, tmp_path, capsys):
    from lifelong_evo.analysis.comparison import compare_table

    rows, markdown = compare_table([sweep])
    means = [r for r in rows if r["statistic"] == "mean"]
    configurations = {r["configuration"]: r["n"] for r in means if r["metric"] == "C phase 0 (red)"}
    assert configurations == {"neat reg=1 red-green-red": 2, "openai-es reg=0 red-green-red": 1}
    by = {(r["algo"], r["episodes"], r["metric"]): r for r in means}
    neat = summaries(sweep, "neat")
    # current performance of phase 1, both seeds: the mean; with two values the 95% t-interval is
    # mean +- t_0.975(1) * |a - b| / 2, t_0.975(1) = 12.706 (a t table)
    values = [s["current"][1] for s in neat]
    row = by[("neat", "training", "C phase 1 (green)")]
    assert row["values"] == values and row["seeds"] == [1, 2]
    assert row["mean"] == pytest.approx(np.mean(values))
    half = 12.7062047 * abs(values[0] - values[1]) / 2
    assert (row["ci_low"], row["ci_high"]) == pytest.approx((np.mean(values) - half, np.mean(values) + half))
    # forgetting of red at the end of phase 1, population (training) and top individual (selection-time)
    for key, kind in (("R_pop", "training"), ("F_pop", "training"), ("R_top", "selection-time"),
                      ("F_top", "selection-time")):
        values = [next(f[key] for f in s["forgetting"] if f["task"] == "red" and f["at_end_of"] == 1) for s in neat]
        assert by[("neat", kind, f"{key} red at end of phase 1")]["mean"] == pytest.approx(np.mean(values))
    for key in ("ACC_pop", "BWT_pop", "FWT_pop", "ACC_top", "BWT_top", "FWT_top"):
        kind = "training" if key.endswith("pop") else "selection-time"
        assert by[("neat", kind, key)]["mean"] == pytest.approx(np.mean([s[key] for s in neat]))
    # the held-out block's figures, as held-out
    for key in ("R_top", "F_top"):
        values = [next(f[key] for f in s["held_out"]["forgetting"] if f["task"] == "red" and f["at_end_of"] == 1)
                  for s in neat]
        assert by[("neat", "held-out", f"{key} red at end of phase 1")]["mean"] == pytest.approx(np.mean(values))
    assert by[("neat", "held-out", "C_top phase 1 (green)")]["values"] == [s["held_out"]["current_top"][1]
                                                                          for s in neat]
    # a single seed: the value itself, no interval
    es = summaries(sweep, "openai-es")[0]
    row = by[("openai-es", "selection-time", "F_top green at end of phase 2")]
    expected = next(f["F_top"] for f in es["forgetting"] if f["task"] == "green")
    assert (row["n"], row["mean"]) == (1, expected) and np.isnan(row["ci_low"]) and np.isnan(row["ci_high"])
    assert "| neat reg=1 red-green-red | 2 |" in markdown and "| openai-es reg=0 red-green-red | 1 |" in markdown
    assert f"| phase 0 (red) | {es['current'][0]:.2f} |" in markdown

    out = tmp_path / "cmp"
    assert cli_main(["compare", str(sweep / "neat"), str(sweep / "openai-es" / "c"), "--out", str(out)]) == 0
    assert (out / "comparison.md").read_text().strip() == markdown.strip()
    with open(out / "comparison.csv", newline="") as handle:
        written = list(csv.DictReader(handle))
    assert len(written) == len(rows)
    assert float(written[0]["mean"]) == pytest.approx(rows[0]["mean"])
    assert written[0]["seeds"] == " ".join(map(str, rows[0]["seeds"]))
    assert [float(v) for v in written[0]["values"].split()] == rows[0]["values"]
    assert all(r["ci_low"] == r["ci_high"] == "" for r in written if r["configuration"].startswith("openai-es"))
    assert (out / "comparison-current.png").read_bytes().startswith(PNG)
    assert (out / "comparison-diagnostics.png").read_bytes().startswith(PNG)
    assert (out / "comparison-retention.png").read_bytes().startswith(PNG)  # red's, measured during green
    assert "neat reg=1 red-green-red" in capsys.readouterr().out
    es_only = tmp_path / "cmp-es"
    assert cli_main(["compare", str(sweep / "openai-es"), "--out", str(es_only)]) == 0
    assert (es_only / "comparison-diagnostics.png").read_bytes().startswith(PNG)  # the ES log their distance too


def test_the_retention_figure_draws_every_task_kept_while_another_is_current(sweep, tmp_path, monkeypatch):
    """Red through green (solid) and green through red's return (dotted): the seeds' mean of
    metrics.csv's retention columns, for the population and the top individual."""
    from lifelong_evo.metrics_csv import read_metrics

    figures = {}
    monkeypatch.setattr(plots, "save", lambda fig, path: figures.setdefault(path.name, fig) and path)
    plots.overlay_figures([sweep / "neat"], tmp_path)
    metrics = [read_metrics(p / "metrics.csv") for p in sorted((sweep / "neat").iterdir())]
    for ax, level in zip(figures["comparison-retention.png"].axes, ("pop", "top")):
        (labelled,) = [line for line in ax.get_lines() if "(n=2)" in line.get_label()]
        drawn = {line.get_linestyle(): line for line in ax.get_lines() if line.get_color() == labelled.get_color()}
        for task, style, phase in (("red", "-", 1), ("green", ":", 2)):
            rows = [[r for r in seed if int(r["task_index"]) == phase and r[f"retention_{level}_{task}"]]
                    for seed in metrics]
            expected = np.mean([[float(r[f"retention_{level}_{task}"]) for r in seed] for seed in rows], axis=0)
            line = drawn[style]
            x, y = np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float)
            shown = ~np.isnan(y)
            assert list(x[shown]) == [int(r["generation"]) for r in rows[0]]
            np.testing.assert_allclose(y[shown], expected)
        legend = {t.get_text(): line for t, line in zip(ax.get_legend().get_texts(), ax.get_legend().get_lines())}
        assert {"retention of red", "retention of green", "drift"} <= set(legend)
        # every legend entry names one kind of line: the drifts' dashes are no task's
        styles = [legend[name].get_linestyle() for name in ("retention of red", "retention of green", "drift")]
        assert len(set(styles)) == 3


def test_the_retention_figure_tells_every_task_of_a_long_schedule_apart(tmp_path, monkeypatch):
    """Past four tasks the line styles come round again, each time with a marker of their own: no
    two tasks' retention looks alike, in the legend or on the curves."""
    schedule = "red:2,green:2,purple:2,cyan:2,red-nest-bottom:2,red-two-failed:2"
    assert cli_main(["--algo", "neat", "--preset", "smoke", "--schedule", schedule, "--env", "duration=20",
                     "--out", str(tmp_path / "runs"), "--name", "long", "--no-record", "--quiet"]) == 0
    figures = {}
    monkeypatch.setattr(plots, "save", lambda fig, path: figures.setdefault(path.name, fig) and path)
    plots.overlay_figures([tmp_path / "runs"], tmp_path)
    for ax in figures["comparison-retention.png"].axes:
        legend = {t.get_text(): line for t, line in zip(ax.get_legend().get_texts(), ax.get_legend().get_lines())}
        tasks = [name for name in legend if name.startswith("retention of ")]
        assert len(tasks) == 6
        looks = {(legend[name].get_linestyle(), legend[name].get_marker()) for name in tasks}
        assert len(looks) == 6
        (labelled,) = [line for line in ax.get_lines() if "(n=1)" in line.get_label()]
        curves = [(line.get_linestyle(), line.get_marker()) for line in ax.get_lines()
                  if line.get_color() == labelled.get_color()]
        assert len(curves) == len(set(curves)) == 5  # every task but the last is kept while another is current


def test_the_papers_table_has_a_line_per_configuration(sweep):
    """One line per configuration in the paper's shape, each cell the estimate of its metric
    over the seeds: per deployed controller (held-out, as these runs have the block) red learnt,
    green learnt, red's retention and forgetting at green's end, red when it returns, transfer;
    for the population (training episodes) the same and the wall time per run."""
    from lifelong_evo.analysis.comparison import compare_table
    from lifelong_evo.analysis.tables import Estimate

    _, markdown = compare_table([sweep])
    assert ("| configuration | n seeds | episodes | red C_top | green C_top | red R_top | red F_top | "
            "red C_top (returns) | ACC_top | BWT_top | FWT_top |") in markdown
    assert ("| configuration | n seeds | red C | green C | red R_pop | red F_pop | red C (returns) | ACC_pop | "
            "BWT_pop | FWT_pop | wall time per run (min) |") in markdown
    for algo, label in (("neat", "neat reg=1 red-green-red"), ("openai-es", "openai-es reg=0 red-green-red")):
        runs = summaries(sweep, algo)
        red = [next(f for f in s["forgetting"] if f["task"] == "red" and f["at_end_of"] == 1) for s in runs]
        cells = [Estimate.of([s["current"][0] for s in runs]), Estimate.of([s["current"][1] for s in runs]),
                 *(Estimate.of([r[key] for r in red]) for key in ("R_pop", "F_pop")),
                 Estimate.of([s["current"][2] for s in runs]),
                 *(Estimate.of([s[key] for s in runs]) for key in ("ACC_pop", "BWT_pop", "FWT_pop")),
                 Estimate.of([s["wall_time_s"] / 60 for s in runs])]
        assert f"| {label} | {len(runs)} | " + " | ".join(map(str, cells)) + " |" in markdown
        levels = ("top", "centre", "best_sample") if algo == "openai-es" else ("top",)
        for level in levels:
            held = [s["held_out"] for s in runs]
            red = [next(f for f in h["forgetting"] if f["task"] == "red" and f["at_end_of"] == 1) for h in held]
            cells = [*(Estimate.of([h[f"current_{level}"][i] for h in held]) for i in (0, 1)),
                     *(Estimate.of([r[f"{key}_{level}"] for r in red]) for key in ("R", "F")),
                     Estimate.of([h[f"current_{level}"][2] for h in held]),
                     *(Estimate.of([h[f"{key}_{level}"] for h in held]) for key in ("ACC", "BWT", "FWT"))]
            assert f"| {label} | {len(runs)} | held-out | " + " | ".join(map(str, cells)) + " |" in markdown, level


def test_unfinished_runs_are_counted_as_such(sweep, tmp_path):
    """A sweep read while it runs: a run that has not ended every task is named unfinished
    beside its configuration's seed count, since its later metrics are missing from the means."""
    from lifelong_evo.analysis.comparison import compare_table

    copy = tmp_path / "sweep"
    shutil.copytree(sweep, copy)
    summary_path = copy / "neat" / "b" / "summary.json"
    summary = json.loads(summary_path.read_text())
    summary["phases"] = summary["phases"][:2]  # as written at the end of green
    summary_path.write_text(json.dumps(summary))
    _, markdown = compare_table([copy])
    assert "| neat reg=1 red-green-red | 2 (1 unfinished) |" in markdown
    assert "| openai-es reg=0 red-green-red | 1 |" in markdown
    assert "2 seed(s): 1, 2 (unfinished)" in markdown


def test_runs_from_before_the_diagnostics_columns(sweep, tmp_path):
    """Runs written before metrics.csv had the optimisers' diagnostics columns still plot and
    compare as before, without a diagnostics figure."""
    old = tmp_path / "old"
    shutil.copytree(sweep / "neat", old / "neat")
    shutil.copytree(sweep / "openai-es", old / "openai-es")
    diagnostics = {"distance_mean", "distance_std", "disabled_fraction"}
    for metrics in old.glob("**/metrics.csv"):
        with open(metrics, newline="") as handle:
            rows = list(csv.DictReader(handle))
        columns = [c for c in rows[0] if c not in diagnostics]
        assert len(columns) == len(rows[0]) - len(diagnostics & set(rows[0])) < len(rows[0])
        with open(metrics, "w", newline="") as handle:
            writer = csv.DictWriter(handle, columns, extrasaction="ignore", lineterminator="\n")
            writer.writeheader()
            writer.writerows(rows)
    assert cli_main(["plot", str(old / "neat"), "--out", str(tmp_path / "figures")]) == 0
    assert len(list((tmp_path / "figures").glob("*.png"))) == 5 + 2 * len(ENDS)
    assert cli_main(["compare", str(old), "--out", str(tmp_path / "cmp")]) == 0
    assert (tmp_path / "cmp" / "comparison.md").is_file()
    assert not (tmp_path / "cmp" / "comparison-diagnostics.png").exists()


def test_compare_and_plot_errors_are_one_line(tmp_path, capsys):
    for verb in ("compare", "plot"):
        assert cli_main([verb, str(tmp_path)]) == 2
        err = capsys.readouterr().err
        assert "no run directory" in err and err.count("\n") == 1
        assert cli_main([verb, str(tmp_path / "missing")]) == 2
        assert "does not exist" in capsys.readouterr().err


def test_one_run_counts_once(sweep, tmp_path, capsys):
    """A copy of a run beside it (or the run again under other speed settings: the same figures)
    counted twice in every mean: n seeds 3 for two seeds, a narrower interval. compare and plot
    refuse it in one line naming both; one run reached by two paths is one run. (Two repetitions of
    one seed with other figures are counted each: test_statistics.)"""
    shutil.copytree(sweep, tmp_path / "runs")
    shutil.copytree(sweep / "neat" / "a", tmp_path / "runs" / "backup")
    for verb in ("compare", "plot"):
        assert cli_main([verb, str(tmp_path / "runs"), "--out", str(tmp_path / verb)]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1 and "one run twice" in err, err
        assert str(tmp_path / "runs" / "backup") in err and str(tmp_path / "runs" / "neat" / "a") in err
        assert not (tmp_path / verb).exists()
    run = sweep / "neat" / "a"
    assert cli_main(["compare", str(run), str(run / ".." / "a"), "--out", str(tmp_path / "once")]) == 0
    assert "Comparison of 1 run(s)" in (tmp_path / "once" / "comparison.md").read_text()


def test_a_broken_metrics_csv_is_named_by_file_line_and_column(tmp_path, capsys):
    """Without its header plot and compare died with a KeyError; a bad cell silently made a curve NaN."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"algo": "neat", "reg": 0, "schedule": "red:2", "generations": 2}))
    (run / "summary.json").write_text(json.dumps({"phases": ["red"], "current": [1.5]}))
    header = "task,task_index,generation,generation_in_task,best\n"
    cases = [("red,0,0,0,1.5\n", "metrics.csv line 1 is not a metrics.csv header: it lacks the column(s) task, "),
             (header + "red,0,0,0,1.5\nred,0,1,1,abc\n", "metrics.csv line 3, column best: 'abc' is not a finite number"),
             (header + "red,0,x,0,1.5\n", "metrics.csv line 2, column generation: 'x' is not an integer"),
             (header + "red,0,0,0\n", "metrics.csv line 2 has 4 cells for the header's 5 columns")]
    for verb in ("plot", "compare"):
        for text, message in cases:
            (run / "metrics.csv").write_text(text)
            assert cli_main([verb, str(run), "--out", str(tmp_path / "out")]) == 2
            err = capsys.readouterr().err
            assert err.startswith("error: ") and message in err and err.count("\n") == 1, err
            assert not (tmp_path / "out").exists(), "nothing is written"
    (run / "metrics.csv").write_text(header + "red,0,0,0,\nred,0,1,1,2.5\nred,0,2,2,3")  # a blank, a half line
    from lifelong_evo.runs import load_run

    assert load_run(run).column("best")[1:].tolist() == [2.5] and len(load_run(run).metrics) == 2


def test_a_broken_species_csv_is_named_too(tmp_path, capsys):
    """species.csv lines that were not numbers were skipped without a word, and a lifespan bar
    was silently lost."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"algo": "neat", "reg": 0, "schedule": "red:2", "generations": 2}))
    (run / "summary.json").write_text(json.dumps({"phases": ["red"], "current": [1.5]}))
    (run / "metrics.csv").write_text("task,task_index,generation,generation_in_task,best,species\n"
                                     "red,0,0,0,1.5,1\nred,0,1,1,2.5,1\n")
    (run / "species.csv").write_text("generation,species_id,size\n0,1,20\n1,one,20\n")
    assert cli_main(["plot", str(run), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "species.csv line 3, column species_id: 'one' is not an integer" in err and err.count("\n") == 1
    (run / "summary.json").write_text(json.dumps({"phases": []}))  # a run still in its first task
    (run / "species.csv").write_text("generation,species_id,size\n0,1,20\n1,1,2")  # a half-written last line
    from lifelong_evo.runs import load_run

    assert load_run(run).species_rows() == [(0, 1, 20)]


def test_plot_checks_every_input_before_it_draws(tmp_path, capsys):
    """A malformed species.csv was found after three PNGs had been written; an --out that is a file
    was a traceback."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"algo": "neat", "reg": 0, "schedule": "red:2", "generations": 2}))
    (run / "summary.json").write_text(json.dumps({"phases": ["red"], "current": [1.5]}))
    (run / "metrics.csv").write_text("task,task_index,generation,generation_in_task,best,top,species\n"
                                     "red,0,0,0,1.5,1.5,1\nred,0,1,1,2.5,2.5,1\n")
    (run / "species.csv").write_text("generation,species_id,size\n0,1,20\n1,one,20\n")
    out = tmp_path / "out"
    assert cli_main(["plot", str(run), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "species.csv line 3, column species_id: 'one' is not an integer" in err and err.count("\n") == 1
    assert not out.exists(), "nothing is drawn before every input is read"
    (run / "species.csv").write_text("generation,species_id,size\n0,1,20\n1,1,20\n")
    (tmp_path / "file").write_text("not a folder")
    for target in (tmp_path / "file", tmp_path / "file" / "below"):
        assert cli_main(["plot", str(run), "--out", str(target)]) == 2
        err = capsys.readouterr().err
        assert err == f"error: --out {target}: {tmp_path / 'file'} is a file, not a folder: give a folder for the figures\n"
    assert cli_main(["plot", str(run), "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["neat-red-2-reg0-lifespans.png", "neat-red-2-reg0-retention-pop.png",
                                                     "neat-red-2-reg0-retention-top.png", "neat-red-2-reg0-species.png"]
