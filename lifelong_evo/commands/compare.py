"""``python -m lifelong_evo compare RUN_OR_DIR... [--out DIR] [--baseline KEY=VALUE,...] [--holm ...]
[--per-seed-lambda SEED=LAMBDA,...] [--choose-lambda-on ...] [--episodes ...]``: configurations
side by side over seeds, and each against its baseline.

The verb parses and calls: ``analysis.comparison`` computes the tables (its docstring says what
each file holds and how baselines, episodes and the model-specific lambda are chosen),
``analysis.figures.overlay_figures`` draws the figures. It writes comparison.md, comparison.csv,
the figures and, where a configuration ran several lambdas, model_specific_lambda.md/.json to
``--out`` (default: the one folder given, else ``comparison/``), and prints the markdown.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from ..analysis.comparison import (EPISODES_CHOICES, Comparison, comparison, parse_baseline, parse_holm,
                                   write_report)
from ..analysis.figures import overlay_figures
from ..analysis.model_specific import CHOOSE_ON, parse_per_seed_lambda
from ..runs import is_run_dir


def default_out(paths) -> Path:
    if len(paths) == 1 and Path(paths[0]).is_dir() and not is_run_dir(Path(paths[0])):
        return Path(paths[0])
    return Path("comparison")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("paths", nargs="+", metavar="RUN_OR_DIR", help="run directories or folders holding them")
    parser.add_argument("--out", default=None, metavar="DIR",
                        help="where to write comparison.md/.csv and the figure (default: the one folder given, "
                             "else comparison/)")
    parser.add_argument("--baseline", action="append", default=None, metavar="KEY=VALUE[,KEY=VALUE...]",
                        help="the configuration the others are compared with, named by its settings (algo, reg, "
                             "schedule, an option such as genetics, env.NAME): one per schedule, e.g. "
                             "algo=neat,reg=0 (default: for each configuration with a regulariser or a baseline setting, "
                             "fine-tuning: lambda 0 without rehearsal, joint or from scratch, of the same algorithm "
                             "and otherwise the same settings)")
    parser.add_argument("--holm", action="append", default=None, metavar="KIND:OUTCOME",
                        help="an outcome of a family tested together (a study's secondary outcomes), as the "
                             "differences tables name it with its episodes, e.g. 'held-out:green C_top'; repeated, "
                             "one per outcome: the tables add its Holm-Bonferroni p over the family")
    parser.add_argument("--per-seed-lambda", default=None, metavar="SEED=LAMBDA[,SEED=LAMBDA...]",
                        help="beside the model-specific lambda, a lambda given per seed (e.g. a paper's own "
                             "per-seed table: 13=5,17=5,24=5,31=11,42=11), reported as the configuration "
                             "reg=given with the same tables, for each configuration that ran those runs")
    parser.add_argument("--choose-lambda-on", choices=CHOOSE_ON, default=CHOOSE_ON[0],
                        help="the figures the model-specific lambda and the one lambda for all seeds are chosen on: "
                             "selection-time (the default, the paper's rule: the top individual on the training "
                             "episodes it was selected on) or held-out (a plan that chooses on held-out figures; "
                             "every run chosen among needs summary.json's held_out block)")
    parser.add_argument("--episodes", choices=EPISODES_CHOICES, default="held-out",
                        help="the deployed controllers' figures in the tables: held-out (the default: where the "
                             "runs have summary.json's held_out block, else the selection-time ones), training "
                             "(the selection-time ones) or both; the population's are training figures always")


def requested_comparison(args: argparse.Namespace) -> Comparison:
    """The ``comparison`` that ``compare``'s parsed command line ``args`` asks for, written nowhere
    (UserError for a bad --baseline, --holm or --per-seed-lambda)."""
    return comparison(args.paths, args.episodes, parse_baseline(args.baseline), parse_holm(args.holm),
                      parse_per_seed_lambda(args.per_seed_lambda), args.choose_lambda_on)


def main(args: argparse.Namespace) -> int:
    out = Path(args.out) if args.out else default_out(args.paths)
    report = requested_comparison(args)  # a bad option writes nothing
    figures = overlay_figures(args.paths, out)  # reads every metrics.csv before it writes: a bad one writes nothing
    markdown = write_report(report, out)
    print(markdown)
    print(f"wrote {out / 'comparison.md'}, {out / 'comparison.csv'}" + "".join(f", {f}" for f in figures))
    return 0
