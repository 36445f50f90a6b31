"""The statistics of ``compare`` (``lifelong_evo.analysis.statistics``) against hand-computed values, and
``compare``'s use of them on small made-up run directories: pairing by seed, Welch, the baseline,
held-out against training figures, the order of the seeds."""
from __future__ import annotations

import csv
import json
import math
import shutil
from pathlib import Path

import pytest
import numpy as np
from scipy import stats

from lifelong_evo.commands.cli import main as cli_main
from lifelong_evo.analysis.statistics import (
    paired_difference,
    paired_seeds_for_power,
    position,
    sign_flip_p,
    t_interval,
    unpaired_seeds_for_power,
    welch_difference,
)
from lifelong_evo.metrics import held_out_summary

T_975_4 = 2.7764451
"""Student's t, 97.5% quantile, 4 degrees of freedom (any t table: 2.776)."""
T_975_1 = 12.7062047
"""The same with 1 degree of freedom (12.706)."""
REPO = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------- the statistics

def test_t_interval_against_the_t_table():
    # [1, 2, 3, 4, 10]: mean 4, squared deviations 9 + 4 + 1 + 0 + 36 = 50, SD^2 = 50/4, SE = sqrt(12.5/5)
    interval = t_interval([1.0, 2.0, 3.0, 4.0, 10.0])
    assert interval.mean == 4.0 and interval.n == 5
    assert interval.low == pytest.approx(4 - T_975_4 * math.sqrt(2.5), abs=1e-6)  # -0.389945
    assert interval.high == pytest.approx(4 + T_975_4 * math.sqrt(2.5), abs=1e-6)  # 8.389945
    # two values: mean +- t(1) * |a - b| / 2 (a percentile bootstrap gives [min, max] here)
    two = t_interval([7.0, 8.0])
    assert (two.low, two.high) == pytest.approx((7.5 - T_975_1 * 0.5, 7.5 + T_975_1 * 0.5), abs=1e-6)
    one = t_interval([2.5])
    assert one.mean == 2.5 and math.isnan(one.low) and math.isnan(one.high)  # one seed: no interval
    assert (t_interval([3.0, 3.0, 3.0]).low, t_interval([3.0, 3.0, 3.0]).high) == (3.0, 3.0)


def test_sign_flip_p_is_exact_and_two_sided():
    """p = (sign vectors e with |mean(e d)| >= |mean(d)|) / 2^n, counted by hand."""
    # [1, 2, 3, 4, 10], sum 20: flipping values that sum to s gives 20 - 2s; |20 - 2s| >= 20 only
    # for s = 0 (none flipped) and s = 20 (all): 2 of 32 (one-sided: 1 of 32)
    assert sign_flip_p([1.0, 2.0, 3.0, 4.0, 10.0]) == (2 / 32, True)
    # [-1, 2, 3, 4, 10], sum 18: |18 - 2s| >= 18 for s <= 0 ({}, {-1}) or s >= 18
    # ({2, 3, 4, 10}: 19; all five: 18): 4 of 32
    assert sign_flip_p([-1.0, 2.0, 3.0, 4.0, 10.0]) == (4 / 32, True)
    # [0, 0, 1, 2, 2], sum 5: of {1, 2, 2}'s 8 subsets, s = 0 and s = 5 qualify; the zeros' signs
    # change nothing (x 4): 8 of 32
    assert sign_flip_p([0.0, 0.0, 1.0, 2.0, 2.0]) == (8 / 32, True)
    assert sign_flip_p([-10.0, -4.0, -3.0, -2.0, -1.0]) == (2 / 32, True)  # symmetric in the sign


def test_paired_difference_pairs_by_seed_and_leaves_unshared_seeds_out():
    # seed 0 only in the first, seed 7 only in the second; inserted in different orders, so
    # pairing by position would pair other values
    values = {0: 40.0, 5: 16.0, 1: 10.0, 4: 15.0, 2: 11.0, 3: 13.0}
    baseline = {1: 10.0, 2: 11.0, 3: 12.0, 4: 13.0, 5: 14.0, 7: 50.0}
    d = paired_difference(values, baseline)
    assert d.test == "paired" and d.seeds == (1, 2, 3, 4, 5) and d.n == 5
    assert d.differences == (0.0, 0.0, 1.0, 2.0, 2.0)
    # differences [0, 0, 1, 2, 2]: mean 1, SD 1 (squared deviations 1 + 1 + 0 + 1 + 1 = 4, / 4)
    assert d.mean == 1.0 and d.effect == pytest.approx(1.0)
    assert (d.low, d.high) == pytest.approx((1 - T_975_4 / math.sqrt(5), 1 + T_975_4 / math.sqrt(5)), abs=1e-6)
    assert (d.p, d.p_exact) == (8 / 32, True)
    assert d.seeds_for_power == 10  # d_z = 1: 10 pairs (G*Power, paired t-test, two-sided, 80%)
    with pytest.raises(ValueError):
        paired_difference({1: 1.0}, {2: 1.0})


def test_welch_against_the_formula():
    a, b = [1.0, 2.0, 3.0, 4.0, 10.0], [0.0, 1.0, 2.0]
    # means 4 and 1, variances 12.5 and 1; SE^2 = 12.5/5 + 1/3; Welch-Satterthwaite df
    se2 = 2.5 + 1 / 3
    df = se2 ** 2 / (2.5 ** 2 / 4 + (1 / 3) ** 2 / 2)
    assert df == pytest.approx(4.961373, abs=1e-6)
    half = stats.t.ppf(0.975, df) * math.sqrt(se2)
    d = welch_difference(a, b)
    assert d.test == "Welch" and (d.n, d.n_baseline) == (5, 3) and d.mean == 3.0
    assert (d.low, d.high) == pytest.approx((3 - half, 3 + half), abs=1e-9)
    assert d.p == pytest.approx(2 * stats.t.sf(3 / math.sqrt(se2), df), abs=1e-12)
    assert d.effect == pytest.approx(3 / math.sqrt((12.5 + 1) / 2))  # Cohen's d over the average variance
    assert welch_difference([1.0], [2.0, 3.0]).p is None  # one value: no test


def test_seeds_for_power_match_cohens_tables():
    """Two-sided, alpha 0.05, power 80%: paired (G*Power) d_z 0.5 -> 34, 0.8 -> 15, 1 -> 10,
    0.2 -> 199; two samples (Cohen 1988, table 2.4.1) d 0.5 -> 64, 0.8 -> 26 per group."""
    assert [paired_seeds_for_power(dz) for dz in (0.5, 0.8, 1.0, 0.2, -0.5)] == [34, 15, 10, 199, 34]
    assert [unpaired_seeds_for_power(d) for d in (0.5, 0.8)] == [64, 26]
    assert paired_seeds_for_power(0.0) == math.inf and paired_seeds_for_power(None) is None


def test_no_statistic_depends_on_the_order_of_the_seeds():
    # 0.1 + 0.2 + 0.3 and 0.3 + 0.2 + 0.1 differ in the last bit
    for order in ([0.1, 0.2, 0.3], [0.3, 0.2, 0.1], [0.2, 0.3, 0.1]):
        assert t_interval(order) == t_interval([0.1, 0.2, 0.3])
    values = {1: 0.1, 2: 0.2, 3: 0.3, 4: 0.7}
    baseline = {1: 0.0, 2: 0.0, 3: 0.0, 4: 0.05}
    reordered = paired_difference(dict(reversed(values.items())), dict(reversed(baseline.items())))
    assert reordered == paired_difference(values, baseline)
    assert welch_difference([0.3, 0.2, 0.1], [0.6, 0.3]) == welch_difference([0.1, 0.2, 0.3], [0.3, 0.6])


def test_a_position_is_the_ratio_of_the_mean_differences_on_the_seeds_both_have():
    fine_tuning = {1: 1.0, 2: 1.0, 3: 1.0, 9: 0.0}
    row = paired_difference({1: 3.0, 2: 5.0, 3: 1.0, 9: 100.0}, fine_tuning)  # 2, 4, 0 and seed 9's 100
    scale = paired_difference({1: 5.0, 2: 9.0, 3: 2.0}, fine_tuning)  # 4, 8, 1: mean 13/3
    assert position(row, scale) == (pytest.approx(2 / (13 / 3)), (1, 2, 3))
    assert position(scale, scale) == (1.0, (1, 2, 3))
    flat = paired_difference({1: 1.0, 2: 1.0, 3: 1.0}, fine_tuning)
    assert position(row, flat) == (None, (1, 2, 3))  # rehearsal no different from fine-tuning: no scale
    assert position(row, paired_difference({1: 4.0}, fine_tuning)) == (None, (1,))
    assert position(welch_difference([3.0, 5.0], [1.0, 1.0]), scale) == (None, ())


# ------------------------------------------------------------------------ compare on made-up runs

PHASES = ["red", "green", "red"]


def summary(green_top: float, red_top: float, held: tuple[float, float] | None = None, es: bool = False) -> dict:
    """A finished red -> green -> red summary.json: the top individual's green C_top and red R_top
    at green's end on the training episodes as given (the rest fixed), and with ``held`` the
    held-out block with those two as (green C_top, red R_top); ``es``: a centre and a best sample
    too, at +1 and +2 of the top individual's held-out scores."""
    result = {"phases": PHASES, "wall_time_s": 60.0, "current": [20.0, green_top + 1, 21.0],
              "current_top": [20.0, green_top, 19.0],
              "forgetting": [{"at_end_of": 1, "task": "red", "C": 20.0, "C_top": 20.0, "R_pop": red_top + 2,
                              "R_top": red_top, "F_pop": 18.0 - red_top, "F_top": 20.0 - red_top},
                             {"at_end_of": 2, "task": "green", "C": green_top + 1, "C_top": green_top, "R_pop": 2.0,
                              "R_top": 1.0, "F_pop": green_top - 1, "F_top": green_top - 1}],
              "ACC_pop": 11.0, "BWT_pop": -1.0, "FWT_pop": 1.0, "ACC_top": 10.0, "BWT_top": -1.5, "FWT_top": 0.5}
    if held is not None:
        green, red = held
        top = [{"red": 18.0, "green": 1.0}, {"red": red, "green": green}, {"red": 17.0, "green": 3.0}]
        kinds = {"top": 0.0, **({"centre": 1.0, "best-sample": 2.0} if es else {})}
        scores = {f"task{i}-{name}-{kind}": {t: v + shift for t, v in top[i].items()}
                  for kind, shift in kinds.items() for i, name in enumerate(PHASES)}
        scores["initial-top"] = {"red": 0.5, "green": 0.5}
        result["held_out"] = held_out_summary(PHASES, scores, 100)
    return result


def write_run(root: Path, name: str, seed, summary_json: dict, algo: str = "neat", reg: float = 0.0,
              **settings) -> Path:
    run = root / name
    run.mkdir(parents=True)
    config = {"algo": algo, "reg": reg, "schedule": "red-green-red", "generations": 2, "seed": seed, **settings}
    (run / "config.json").write_text(json.dumps(config))
    (run / "summary.json").write_text(json.dumps(summary_json))
    return run


BASE_RED = {1: 10.0, 2: 11.0, 3: 12.0, 4: 13.0, 5: 14.0, 7: 50.0}
"""Held-out red R_top of lambda 0 per seed; lambda 11 adds [0, 0, 1, 2, 2] on seeds 1-5."""
RED_GAIN = {1: 0.0, 2: 0.0, 3: 1.0, 4: 2.0, 5: 2.0}
GREEN_GAIN = {1: 10.0, 2: 3.0, 3: 1.0, 4: 4.0, 5: 2.0}
"""Held-out green C_top of lambda 11 minus lambda 0 (20 at every seed): [1, 2, 3, 4, 10] in another order."""


@pytest.fixture
def lambdas(tmp_path) -> Path:
    """neat lambda 0 (seeds 1-5 and 7) and lambda 11 (seeds 0-5), with the held-out block; the
    training figures: lambda 11's selection-time red R_top is 3 above lambda 0's at every seed."""
    root = tmp_path / "runs"
    for seed, red in BASE_RED.items():
        write_run(root, f"reg0-seed{seed}", seed, summary(25.0, 5.0 + seed, held=(20.0 if seed != 7 else 0.0, red)))
    for seed in (0, 1, 2, 3, 4, 5):
        held = (5.0, 40.0) if seed == 0 else (20.0 + GREEN_GAIN[seed], BASE_RED[seed] + RED_GAIN[seed])
        write_run(root, f"reg11-seed{seed}", seed, summary(20.0, 8.0 + seed, held=held), reg=11.0)
    return root


def read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_compare_pairs_lambda_11_with_lambda_0_by_seed(lambdas, tmp_path, capsys):
    out = tmp_path / "cmp"
    assert cli_main(["compare", str(lambdas), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    markdown = (out / "comparison.md").read_text()
    assert "### neat reg=11 red-green-red against neat reg=0 red-green-red" in printed
    # differences [0, 0, 1, 2, 2]: mean 1, SD 1, t-interval 1 +- 2.776/sqrt(5), p 8/32, d_z 1, 10 seeds
    assert "| red R_top | held-out | +1.00 [-0.24, +2.24] | 0.25 | +1.00 | 5 | 10 |" in markdown
    # differences [1, 2, 3, 4, 10]: mean 4, 4 +- 2.776 sqrt(2.5), p 2/32, d_z 4 / sqrt(12.5)
    assert "| green C_top | held-out | +4.00 [-0.39, +8.39] | 0.0625 | +1.13 | 5 |" in markdown
    # training figures, labelled: lambda 11's selection-time R_top is 3 above at every seed
    assert "| red R_pop | training | +3.00 [+3.00, +3.00] | 0.0625 | - | 5 | - |" in markdown
    assert "| red R_top | selection-time |" not in markdown  # held-out shown where the runs have it
    assert "Left out of the pairs (run by one of the two only): seed(s) 0 (neat reg=11 red-green-red), " \
           "7 (neat reg=0 red-green-red)." in markdown
    rows = read_csv(out / "comparison.csv")
    (row,) = [r for r in rows if r["statistic"] == "paired difference" and r["episodes"] == "held-out"
              and r["metric"] == "R_top red at end of phase 1"]
    assert (row["configuration"], row["baseline"], row["n"]) == ("neat reg=11 red-green-red",
                                                                 "neat reg=0 red-green-red", "5")
    assert (row["seeds"], row["values"]) == ("1 2 3 4 5", "0.0 0.0 1.0 2.0 2.0")
    assert float(row["mean"]) == 1.0 and float(row["p"]) == 0.25 and row["p_method"] == "exact sign-flip"
    assert float(row["ci_low"]) == pytest.approx(1 - T_975_4 / math.sqrt(5), abs=1e-6)
    assert float(row["ci_high"]) == pytest.approx(1 + T_975_4 / math.sqrt(5), abs=1e-6)
    assert float(row["effect_size"]) == pytest.approx(1.0) and row["seeds_for_80_power"] == "10"
    # the selection-time difference is in the csv too, though the tables show the held-out one
    assert any(r["statistic"] == "paired difference" and r["episodes"] == "selection-time"
               and r["metric"] == "R_top red at end of phase 1" for r in rows)
    (mean,) = [r for r in rows if r["statistic"] == "mean" and r["episodes"] == "held-out"
               and r["metric"] == "R_top red at end of phase 1" and r["configuration"] == "neat reg=0 red-green-red"]
    assert (mean["n"], mean["seeds"], mean["values"]) == ("6", "1 2 3 4 5 7", "10.0 11.0 12.0 13.0 14.0 50.0")
    assert float(mean["mean"]) == pytest.approx(110 / 6)


def test_the_seed_order_changes_no_figure(lambdas, tmp_path):
    """The same runs under names that list the seeds in another order, and two runs of one seed
    (they come in the order of their paths): the same comparison.md and comparison.csv, byte
    for byte."""
    shuffled = tmp_path / "shuffled"
    runs = sorted(lambdas.iterdir())
    for i, run in enumerate(runs):
        shutil.copytree(run, shuffled / f"{len(runs) - i:02d}-{run.name}")
    for root, first, second in ((lambdas, "a-extra", "z-extra"), (shuffled, "z-extra", "a-extra")):
        write_run(root, first, 3, summary(20.0, 5.1, held=(21.0, 0.1)), reg=11.0)
        write_run(root, second, 3, summary(20.0, 5.3, held=(21.0, 0.3)), reg=11.0)
    assert cli_main(["compare", str(lambdas), "--out", str(tmp_path / "a")]) == 0
    assert cli_main(["compare", str(shuffled), "--out", str(tmp_path / "b")]) == 0
    for name in ("comparison.md", "comparison.csv"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    rows = read_csv(tmp_path / "a" / "comparison.csv")
    (row,) = [r for r in rows if r["statistic"] == "mean" and r["episodes"] == "held-out"
              and r["metric"] == "R_top red at end of phase 1" and r["configuration"] == "neat reg=11 red-green-red"]
    assert row["seeds"] == "0 1 2 3 3 3 4 5" and row["values"] == "40.0 10.0 11.0 0.1 0.3 13.0 15.0 16.0"


def test_welch_where_the_configurations_share_no_seed(tmp_path):
    """An ES against NEAT, on seeds of the same numbers: two algorithms share no sample path, so
    unpaired, labelled Welch, the hand-computed numbers."""
    root = tmp_path / "runs"
    for seed, red in zip((1, 2, 3), (0.0, 1.0, 2.0)):
        write_run(root, f"neat-{seed}", seed, summary(25.0, 5.0, held=(20.0, red)))
    for seed, red in zip((1, 2, 3, 4, 5), (1.0, 2.0, 3.0, 4.0, 10.0)):
        write_run(root, f"es-{seed}", seed, summary(25.0, 5.0, held=(20.0, red), es=True), algo="openai-es")
    out = tmp_path / "cmp"
    assert cli_main(["compare", str(root), "--out", str(out), "--baseline", "algo=neat"]) == 0
    markdown = (out / "comparison.md").read_text()
    assert "### openai-es reg=0 red-green-red against neat reg=0 red-green-red" in markdown
    assert "Welch (two algorithms: a seed's runs share no sample path, so unpaired)" in markdown
    se2 = 12.5 / 5 + 1 / 3
    df = se2 ** 2 / ((12.5 / 5) ** 2 / 4 + (1 / 3) ** 2 / 2)
    half = stats.t.ppf(0.975, df) * math.sqrt(se2)
    p = 2 * stats.t.sf(3 / math.sqrt(se2), df)
    assert f"| red R_top | held-out | +3.00 [{3 - half:+.2f}, {3 + half:+.2f}] | {p:.3g} | +1.15 | 5 + 3 (Welch) |" \
        in markdown
    (row,) = [r for r in read_csv(out / "comparison.csv") if r["statistic"] == "Welch difference"
              and r["episodes"] == "held-out" and r["metric"] == "R_top red at end of phase 1"]
    assert (row["n"], row["n_baseline"], row["p_method"]) == ("5", "3", "Welch t-test")
    assert float(row["ci_low"]) == pytest.approx(3 - half) and float(row["p"]) == pytest.approx(p)


@pytest.fixture
def three(lambdas, tmp_path) -> Path:
    """neat lambda 0 and 11 (``lambdas``) and an OpenAI-ES at lambda 0, seeds 1-3, one schedule."""
    for seed in (1, 2, 3):
        write_run(lambdas, f"es-seed{seed}", seed, summary(25.0, 5.0, held=(20.0, 10.0 + seed), es=True),
                  algo="openai-es")
    return lambdas


def test_the_baseline_by_default_and_named(three, tmp_path):
    _, markdown = _compare(three)
    # default: lambda 0 of the same algorithm and settings; the ES at lambda 0 has none
    assert [line for line in markdown.splitlines() if " against " in line and line.startswith("### ")] == [
        "### neat reg=11 red-green-red against neat reg=0 red-green-red"]
    for given in (["--baseline", "algo=neat,reg=0"], ["--baseline", "algo=neat", "--baseline", "reg=0"]):
        _, markdown = _compare(three, *given)
        assert "### neat reg=11 red-green-red against neat reg=0 red-green-red" in markdown
        assert "### openai-es reg=0 red-green-red against neat reg=0 red-green-red" in markdown
        assert "### neat reg=0 red-green-red against" not in markdown
    # named by the ES: NEAT's runs share its seeds 1-3, but two algorithms share no sample path,
    # so they are compared unpaired
    _, markdown = _compare(three, "--baseline", "algo=openai-es")
    assert "### neat reg=11 red-green-red against openai-es reg=0 red-green-red" in markdown
    # neat lambda 0's held-out red R_top (BASE_RED, six seeds) against the ES's 11, 12, 13: Welch over all of each
    difference = sum(BASE_RED.values()) / len(BASE_RED) - 12.0
    section = markdown.split("### neat reg=0 red-green-red against openai-es reg=0 red-green-red")[1].split("###")[0]
    assert f"| red R_top | held-out | {difference:+.2f} [" in section and "| 6 + 3 (Welch) |" in section


def _compare(root: Path, *flags: str) -> tuple[Path, str]:
    out = root.parent / "cmp"
    shutil.rmtree(out, ignore_errors=True)
    assert cli_main(["compare", str(root), "--out", str(out), *flags]) == 0
    return out, (out / "comparison.md").read_text()


@pytest.mark.parametrize("given, message", [
    ("reg=0", "--baseline reg=0 matches 2 configurations of schedule red -> green -> red "
              "(neat reg=0 red-green-red; openai-es reg=0 red-green-red): add an item that tells them apart"),
    ("algo=cmaes", "--baseline algo=cmaes matches none of the 3 configurations compared"),
    ("algo=neat,reg=5", "--baseline algo=neat,reg=5 matches none"),
    ("colour=red", "--baseline colour=red: no configuration compared has a setting colour; the settings are "),
    ("reg=zero", "--baseline reg=zero: reg is a number, e.g. reg=0"),
    ("reg", "--baseline 'reg' is not KEY=VALUE"),
])
def test_a_baseline_that_names_no_single_configuration_is_refused_in_one_line(three, tmp_path, capsys, given,
                                                                                message):
    out = tmp_path / "refused"
    assert cli_main(["compare", str(three), "--out", str(out), "--baseline", given]) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith("error: ") and message in captured.err and captured.err.count("\n") == 1
    assert captured.out == "" and not out.exists()  # nothing written, not even the figures


def test_held_out_figures_by_default_training_ones_labelled(lambdas, tmp_path):
    """Runs with the held-out block show held-out figures for the top individual; runs without
    (made before it existed) their selection-time ones, labelled; --episodes picks."""
    for run in lambdas.glob("reg0-*"):  # lambda 0 from before the held-out block
        path = run / "summary.json"
        path.write_text(json.dumps({k: v for k, v in json.loads(path.read_text()).items() if k != "held_out"}))
    _, markdown = _compare(lambdas)
    # lambda 11's green C_top: held-out 30, 23, 21, 24, 22 and 5 (seed 0); training 20 at every seed
    held = t_interval([30.0, 23.0, 21.0, 24.0, 22.0, 5.0])
    top_line = f"| neat reg=11 red-green-red | 6 | held-out | 18.00 [18.00, 18.00] | {held.mean:.2f} [{held.low:.2f}, "
    assert top_line in markdown
    assert "| neat reg=0 red-green-red | 6 | selection-time | 20.00 [20.00, 20.00] | 25.00 [25.00, 25.00] |" \
        in markdown
    assert "| phase | C (training) | C_top (held-out) |" in markdown
    assert "| phase | C (training) | C_top (selection-time) |" in markdown  # lambda 0's own table
    # the population's figures are training ones in every mode
    assert "| configuration | n seeds | red C | green C | red R_pop | red F_pop | red C (returns) | ACC_pop |" \
        in markdown
    # compared with a baseline without the block: the selection-time figures of both
    assert "| red R_top | selection-time | +3.00 [+3.00, +3.00] | 0.0625 | - | 5 | - |" in markdown
    assert "| red R_top | held-out |" not in markdown
    _, markdown = _compare(lambdas, "--episodes", "training")
    assert "| neat reg=11 red-green-red | 6 | selection-time | 20.00 [20.00, 20.00] | 20.00 [20.00, 20.00] |" \
        in markdown and "held-out |" not in markdown
    _, markdown = _compare(lambdas, "--episodes", "both")
    assert top_line in markdown and "| neat reg=11 red-green-red | 6 | selection-time |" in markdown
    assert "| phase | C (training) | C_top (held-out) | C_top (selection-time) |" in markdown


def test_an_es_centre_and_best_sample_are_reported_apart(three, tmp_path):
    _, markdown = _compare(three)
    # held-out red R_top 11, 12, 13 at seeds 1-3; the centre +1, the best sample +2
    assert "the centre (ES)" in markdown and "the best sample (ES)" in markdown
    for level, shift in (("top", 0), ("centre", 1), ("best_sample", 2)):
        interval = t_interval([11.0 + shift, 12.0 + shift, 13.0 + shift])
        header = f"| configuration | n seeds | episodes | red C_{level} | green C_{level} | red R_{level} |"
        assert header in markdown
        line = (f"| openai-es reg=0 red-green-red | 3 | held-out | {18 + shift:.2f} [{18 + shift:.2f}, "
                f"{18 + shift:.2f}] | {20 + shift:.2f} [{20 + shift:.2f}, {20 + shift:.2f}] | "
                f"{interval.mean:.2f} [{interval.low:.2f}, {interval.high:.2f}] |")
        assert line in markdown, level
    assert "| phase | C (training) | C_top (held-out) | C_centre (held-out) | C_best_sample (held-out) |" in markdown


def test_the_model_specific_lambda_is_chosen_on_training_figures_and_reported_held_out(lambdas, tmp_path):
    """The criterion C_top(green) + R_top(red at green's end) on the training episodes: lambda 0
    scores 25 + 5 + s, lambda 11 20 + 8 + s, so lambda 0 wins at every seed that ran both (seeds
    0 and 7 ran one lambda each: left out); the m.s. tables show the chosen runs' held-out
    figures, not their selection-time ones."""
    out, markdown = _compare(lambdas)
    selection = json.loads((out / "model_specific_lambda.json").read_text())[0]
    assert [(c["seed"], c["reg"]) for c in selection["choices"]] == [(1, 0.0), (2, 0.0), (3, 0.0), (4, 0.0),
                                                                     (5, 0.0)]
    assert selection["left_out"] == [{"seed": 0, "lambdas": [11.0]}, {"seed": 7, "lambdas": [0.0]}]
    part = markdown[markdown.index("## Model-specific lambda"):]
    assert "Left out, as they did not finish every lambda of 0, 11: seeds 0 (finished 11), 7 (finished 0)" in part
    assert "chosen on the training episodes (selection-time figures)" in part
    assert "reported below with held-out figures where they have them" in part
    assert "| task at end of phase | R_pop (training) | F_pop (training) | R_top (held-out) | F_top (held-out) |" in part
    chosen = t_interval([10.0, 11.0, 12.0, 13.0, 14.0])  # the chosen runs' held-out red R_top
    line = next(line for line in part.splitlines() if line.startswith("| red at end of phase 1 |"))
    assert line.split(" | ")[3] == f"{chosen.mean:.2f} [{chosen.low:.2f}, {chosen.high:.2f}]"


def test_the_lambda_is_chosen_on_held_out_figures_where_asked(lambdas):
    """--choose-lambda-on held-out: the same criterion on the held-out block, where lambda 11
    scores 20 + GREEN_GAIN + BASE_RED + RED_GAIN against lambda 0's 20 + BASE_RED, so lambda 11
    wins at every seed and as the one lambda for all seeds (means 32 + 5 against 32), where the
    training figures choose lambda 0 (the test above)."""
    out, markdown = _compare(lambdas, "--choose-lambda-on", "held-out")
    (selection,) = json.loads((out / "model_specific_lambda.json").read_text())
    assert selection["chosen_on"] == "held-out"
    assert [(c["seed"], c["reg"]) for c in selection["choices"]] == [(seed, 11.0) for seed in (1, 2, 3, 4, 5)]
    shared = selection["one_lambda_for_all_seeds"]
    assert shared["reg"] == 11.0 and shared["mean_per_lambda"] == [{"reg": 0.0, "mean": 32.0},
                                                                   {"reg": 11.0, "mean": 37.0}]
    part = markdown[markdown.index("## Model-specific lambda"):]
    assert "chosen on the held-out episodes (--choose-lambda-on held-out)" in part
    assert "at end of phase 1) (held-out) |" in part and "(selection-time) |" not in part
    chosen = t_interval([BASE_RED[s] + RED_GAIN[s] for s in (1, 2, 3, 4, 5)])  # lambda 11's held-out red R_top
    line = next(line for line in part.splitlines() if line.startswith("| red at end of phase 1 |"))
    assert line.split(" | ")[3] == f"{chosen.mean:.2f} [{chosen.low:.2f}, {chosen.high:.2f}]"
    # the optimism table still holds both figures of the chosen runs: training 28 + s, held-out 32 + 5 on average
    optimism = next(line for line in part.splitlines() if line.startswith("| chosen per seed |"))
    assert optimism.split(" | ")[2].startswith("31.00 ") and optimism.split(" | ")[3].startswith("37.00 ")


def test_a_held_out_choice_refuses_a_run_without_held_out_scores(lambdas, capsys):
    summary_file = lambdas / "reg11-seed3" / "summary.json"
    summary_json = json.loads(summary_file.read_text())
    del summary_json["held_out"]
    summary_file.write_text(json.dumps(summary_json))
    out = lambdas.parent / "cmp"
    assert cli_main(["compare", str(lambdas), "--out", str(out), "--choose-lambda-on", "held-out"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --choose-lambda-on held-out: reg11-seed3 has no held-out score") and \
        err.count("\n") == 1
    assert not out.exists()
    _compare(lambdas)  # the training figures still choose


def test_a_lambda_given_per_seed_is_reported_beside_the_chosen_one(lambdas):
    """--per-seed-lambda (the paper's own per-seed table): the named runs form the configuration
    reg=given, with the same tables as the model-specific choice, held-out where the runs have it."""
    given = {1: 11.0, 2: 11.0, 3: 0.0, 4: 0.0, 5: 11.0}
    out, markdown = _compare(lambdas, "--per-seed-lambda", " 1=11, 2=11,3=0,4=0,5=11.0")
    (selection,) = json.loads((out / "model_specific_lambda.json").read_text())
    assert [(c["seed"], c["reg"], c["tag"]) for c in selection["given"]] == [
        (seed, reg, f"reg{reg:g}-seed{seed}") for seed, reg in given.items()]
    assert [c["reg"] for c in selection["choices"]] == [0.0] * 5  # the rule's own choice is unchanged
    part = markdown[markdown.index("### neat reg=given red-green-red"):]
    assert part.splitlines()[2] == "lambda per seed, as given (--per-seed-lambda): 1: 11, 2: 11, 3: 0, 4: 0, 5: 11"
    expected = t_interval([BASE_RED[s] + (RED_GAIN[s] if reg else 0.0) for s, reg in given.items()])
    line = next(line for line in part.splitlines() if line.startswith("| red at end of phase 1 |"))
    assert line.split(" | ")[3] == f"{expected.mean:.2f} [{expected.low:.2f}, {expected.high:.2f}]"
    (row,) = [r for r in read_csv(out / "comparison.csv") if r["configuration"] == "neat reg=given red-green-red"
              and r["episodes"] == "held-out" and r["metric"] == "R_top red at end of phase 1"]
    assert row["reg"] == "given 11 11 0 0 11" and row["seeds"] == "1 2 3 4 5"


@pytest.mark.parametrize("given, says", [
    ("1=11,7=11", "no finished run of seed 7 lambda 11 among the seeds that finished every lambda of 0, 11 "
                  "(1, 2, 3, 4, 5)"),
    ("1=5", "no finished run of seed 1 lambda 5"),
    ("1=11,1=0", "'1=0' is not SEED=LAMBDA, or names its seed twice"),
    ("1:11", "'1:11' is not SEED=LAMBDA"),
    ("one=11", "'one=11' is not SEED=LAMBDA"),
    ("1=nan", "'1=nan' is not SEED=LAMBDA")])
def test_a_bad_per_seed_lambda_is_refused_before_anything_is_written(lambdas, tmp_path, capsys, given, says):
    assert cli_main(["compare", str(lambdas), "--out", str(tmp_path / "cmp"), "--per-seed-lambda", given]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --per-seed-lambda") and says in err and err.count("\n") == 1
    assert not (tmp_path / "cmp").exists()


def test_the_paper_genetics_study(capsys):
    """docs/data/paper-genetics: lambda 11 against lambda 0, paired over seeds 13, 17, 24, 31, 42,
    selection-time (the runs have no held-out block): the issue's t-intervals, R_top +6.8
    [-4.1, 17.8] and green C_top -10.4 [-23.4, 2.7]; the exact sign-flip p-values are 4/32 and
    2/32 (every difference has the same sign but one zero, and green's are all negative)."""
    from lifelong_evo.analysis.comparison import compare_table

    _, markdown = compare_table([REPO / "docs" / "data" / "paper-genetics"])
    assert "| red R_top | selection-time | +6.84 [-4.15, +17.83] | 0.125 | +0.77 | 5 | 16 |" in markdown
    assert "| green C_top | selection-time | -10.36 [-23.39, +2.67] | 0.0625 | -0.99 | 5 | 11 |" in markdown


def test_holm_against_its_definition_worked_by_hand():
    from lifelong_evo.analysis.statistics import holm

    # sorted 0.005, 0.01, 0.03, 0.04 -> 4 x 0.005, 3 x 0.01, max(that, 2 x 0.03), max(that, 1 x 0.04)
    assert holm([0.01, 0.04, 0.03, 0.005]) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert holm([0.5, 0.6]) == [1.0, 1.0]  # capped at 1
    assert holm([0.02]) == [0.02] and holm([]) == []


def test_compare_adds_the_holm_p_of_a_named_family(tmp_path, capsys):
    """The paper-genetics runs in docs/data: four secondary outcomes, p 0.0625, 0.125, 0.125, 0.125
    (exact sign-flip, five seeds), whose Holm p are 0.25 and three times 0.375; the CSV has them too."""
    data = Path(__file__).resolve().parents[1] / "docs/data/paper-genetics"
    family = ["selection-time:green C_top", "selection-time:red F_top", "training:red R_pop",
              "selection-time:red C_top (returns)"]
    assert cli_main(["compare", str(data), "--out", str(tmp_path / "cmp"),
                     *(flag for item in family for flag in ("--holm", item))]) == 0
    rows = list(csv.DictReader(open(tmp_path / "cmp/comparison.csv")))
    adjusted = {(r["episodes"], r["metric"]): r["p_holm"] for r in rows if r["statistic"] == "paired difference"}
    named = {value for value in adjusted.values() if value}
    assert sorted(float(v) for v in named) == [0.25, 0.375] and sum(bool(v) for v in adjusted.values()) == 4
    markdown = (tmp_path / "cmp/comparison.md").read_text()
    assert "| green C_top | selection-time | -10.36 [-23.39, +2.67] | 0.0625 | -0.99 | 5 | 11 | 0.25 |" in markdown
    assert "| red R_pop | training | +7.58 [+0.18, +14.98] | 0.125 | +1.27 | 5 | 8 | 0.375 |" in markdown
    assert "| red R_top | selection-time | +6.84 [-4.15, +17.83] | 0.125 | +0.77 | 5 | 16 | - |" in markdown


@pytest.mark.parametrize("given, says", [("greenC", "is not KIND:OUTCOME"),
                                         ("held-out:green C", "no difference table has that outcome")])
def test_a_bad_holm_family_is_refused_before_anything_is_written(tmp_path, capsys, given, says):
    data = Path(__file__).resolve().parents[1] / "docs/data/paper-genetics"
    assert cli_main(["compare", str(data), "--out", str(tmp_path / "cmp"), "--holm", given]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --holm") and says in err and err.count("\n") == 1
    assert not (tmp_path / "cmp").exists()


def test_the_optimism_of_a_lambda_chosen_per_seed_worked_by_hand():
    """Criterion (C_top green + R_top red) on training / held-out episodes: seed 1, lambda 0 30 / 26
    and lambda 11 28 / 27; seed 2, lambda 0 25 / 24 and lambda 11 29 / 22. Chosen: lambda 0 at seed
    1, 11 at seed 2: 29.5 selection-time, 24.0 held-out, differences 4 and 7; lambda 0 on every
    seed: 4 and 1; lambda 11: 1 and 7."""
    from lifelong_evo.analysis.model_specific import optimism_rows, select_model_specific
    from lifelong_evo.analysis.tables import Estimate

    def summary(train: float, held: float) -> dict:
        part = lambda score: {"phases": ["red", "green", "red"], "current_top": [0.0, score - 5.0, 0.0],  # noqa: E731
                              "forgetting": [{"at_end_of": 1, "task": "red", "R_top": 5.0}]}
        return {**part(train), "held_out": part(held)}

    figures = {(1, 0.0): (30.0, 26.0), (1, 11.0): (28.0, 27.0), (2, 0.0): (25.0, 24.0), (2, 11.0): (29.0, 22.0)}
    summaries = {f"s{seed}-l{reg:g}": summary(*values) for (seed, reg), values in figures.items()}
    runs = [({"algo": "neat", "reg": reg, "seed": seed}, summaries[f"s{seed}-l{reg:g}"], f"s{seed}-l{reg:g}")
            for seed, reg in figures]
    (selection,) = select_model_specific(runs)
    assert [(c["seed"], c["reg"]) for c in selection["choices"]] == [(1, 0.0), (2, 11.0)]
    rows = optimism_rows(selection, summaries)

    def est(values):
        return str(Estimate.of(values, [1, 2]))

    assert rows == [["chosen per seed", "2", est([30.0, 29.0]), est([26.0, 22.0]), est([4.0, 7.0])],
                    ["lambda 0, every seed", "2", est([30.0, 25.0]), est([26.0, 24.0]), est([4.0, 1.0])],
                    ["lambda 11, every seed", "2", est([28.0, 29.0]), est([27.0, 22.0]), est([1.0, 7.0])]]
    del summaries["s2-l11"]["held_out"]  # a run without held-out scores: nothing to measure
    assert optimism_rows(selection, summaries) == []


@pytest.mark.parametrize("n", [2, 5, 9, 12])
def test_sign_flip_p_is_scipys_exact_test(n):
    """The exact p-value is scipy's ``permutation_test`` (one sample, ``samples``, two-sided),
    computed as one array: the same on spread values, on whole numbers with ties and zeros, on a
    zero mean and where a flip gives the observed mean but for its rounding (the tolerance for
    ties decides)."""
    rng = np.random.default_rng(n)
    cases = [rng.normal(0.3, 1.0, n), rng.integers(-3, 4, n).astype(float), np.zeros(n),
             np.concatenate([[1.0], -np.ones(n - 1)]),
             rng.normal(0, 1, n) * 1e-9 + 0.1,
             # flipping -1.5, 1.0 and 0.5 keeps the mean in exact arithmetic, not in its rounding
             np.concatenate([[-1.5, -1.3, -0.4, 0.5, 1.0, 2.7][:n], rng.normal(0.5, 1.0, max(0, n - 6))]),
             # a mean of 0 in exact arithmetic, about 1e-16 in floats: the order of each sum decides
             np.concatenate([[1.0, -2.7, -1.9, -0.2, -0.4, 0.2, 0.2, 3.8][:n], [0.5, -0.5] * max(0, (n - 8) // 2),
                             [0.0] * ((n - 8) % 2 if n > 8 else 0)])]
    for differences in cases:
        scipys = stats.permutation_test((np.sort(differences),), lambda x, axis: np.mean(x, axis=axis),
                                        permutation_type="samples", vectorized=True, n_resamples=np.inf,
                                        alternative="two-sided")
        assert sign_flip_p(differences) == (float(scipys.pvalue), True), differences


REHEARSAL_RED = {1: 2.0, 2: 3.0, 3: 4.0, 4: 5.0, 5: 6.0}
"""Held-out red R_top of rehearsal minus lambda 0 per seed: mean 4, its interval above 0."""


def test_compare_places_each_configuration_between_fine_tuning_and_rehearsal(lambdas, tmp_path):
    """On red R_top held-out, lambda 11 gains [0, 0, 1, 2, 2] and rehearsal [2, 3, 4, 5, 6] over
    lambda 0 on seeds 1-5: position 1 / 4; on the population's training R_pop, 3 and 4 at every
    seed: 0.75. Rehearsal itself is the scale, not a row; a named baseline that is not fine-tuning
    has no scale."""
    for seed, gain in REHEARSAL_RED.items():
        write_run(lambdas, f"rehearsal-seed{seed}", seed,
                  summary(20.0, 9.0 + seed, held=(20.0, BASE_RED[seed] + gain)), rehearsal=0.3)
    out, markdown = _compare(lambdas)
    fine, reg11, rehearsal = "neat reg=0 red-green-red", "neat reg=11 red-green-red", \
        "neat reg=0 red-green-red rehearsal=0.3"
    lines = markdown.split("## Between fine-tuning and rehearsal")[1].split("\n## ")[0].splitlines()
    rows = [line for line in lines if line.startswith(f"| {fine}") or line.startswith(f"| {reg11}")]
    assert rows == [f"| {reg11} | {rehearsal} | red R_top | held-out | +1.00 [-0.24, +2.24] | "
                    "+4.00 [+2.04, +5.96] | yes | 0.25 | 5 |",
                    f"| {reg11} | {rehearsal} | red R_pop | training | +3.00 [+3.00, +3.00] | "
                    "+4.00 [+4.00, +4.00] | yes | 0.75 | 5 |"]
    placed = [r for r in read_csv(out / "comparison.csv") if r["statistic"] == "position"]
    assert [(r["configuration"], r["baseline"], r["episodes"], r["metric"], float(r["mean"]), r["seeds"])
            for r in placed if r["metric"] in ("R_top red at end of phase 1", "R_pop red at end of phase 1")] == [
        (reg11, rehearsal, "held-out", "R_top red at end of phase 1", 0.25, "1 2 3 4 5"),
        (reg11, rehearsal, "selection-time", "R_top red at end of phase 1", 0.75, "1 2 3 4 5"),  # not shown
        (reg11, rehearsal, "training", "R_pop red at end of phase 1", 0.75, "1 2 3 4 5")]
    _, against_reg11 = _compare(lambdas, "--baseline", "reg=11")
    assert "## Between fine-tuning and rehearsal" not in against_reg11
