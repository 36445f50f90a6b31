"""The analysis from Python, as in a notebook: the tables ``compare`` prints, then one number
worked out by hand from the same runs.

    python examples/analysis.py                      # the runs kept in docs/data/paper-genetics
    python examples/analysis.py runs/my-sweep        # any run directories, or folders holding them

``comparison`` gives exactly the markdown ``python -m lifelong_evo compare PATH`` prints (its
``rows`` are comparison.csv's); nothing is written. ``load_runs``/``group_runs`` read the runs
back, and ``paired_difference`` is the statistic the tables use.
"""
from __future__ import annotations

import sys
from pathlib import Path

from lifelong_evo.analysis.comparison import comparison
from lifelong_evo.analysis.statistics import paired_difference
from lifelong_evo.runs import describe_config, group_runs, load_runs
from lifelong_evo.summary_json import SummaryLayout

DATA = Path(__file__).resolve().parents[1] / "docs/data/paper-genetics"


def red_retention_at_green_end(summary: dict) -> float | None:
    """The top individual's red retention at the end of green (selection-time), from summary.json."""
    for row in summary.get(SummaryLayout.FORGETTING, []):
        if row["at_end_of"] == 1 and row["task"] == "red":
            return row["R_top"]
    return None


def main(paths: list[str]) -> None:
    report = comparison(paths)  # compare's options are keywords: episodes, baseline, family, lambda_per_seed
    print(report.markdown)

    groups = group_runs(load_runs(paths, with_metrics=False))
    by_seed = [{run.seed: red_retention_at_green_end(run.summary) for run in group} for group in groups]
    if len(groups) == 2:
        first, second = (describe_config(group[0].config) for group in groups)
        d = paired_difference(by_seed[1], by_seed[0])
        print(f"\nred R_top at the end of green, {second} minus {first}, paired over {d.n} seeds: "
              f"{d.mean:+.2f} [{d.low:+.2f}, {d.high:+.2f}], sign-flip p = {d.p:.3g}")


if __name__ == "__main__":
    main(sys.argv[1:] or [str(DATA)])
