"""``python -m lifelong_evo plot RUN... [--out DIR]``: the paper's figures as PNG for the runs at
or under RUN (``analysis.figures.plot_runs``, which says which files and how they are drawn)."""
from __future__ import annotations

import argparse

from ..analysis.figures import plot_runs


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("runs", nargs="+", metavar="RUN", help="run directories or folders holding them")
    parser.add_argument("--out", default=None, metavar="DIR",
                        help="where to write the PNGs (default: the folder that holds the runs: "
                             "a single run's directory, a sweep's directory)")


def main(args: argparse.Namespace) -> int:
    for path in plot_runs(args.runs, args.out):
        print(path)
    return 0
