"""Command line: ``python -m lifelong_evo [run] --algo neat --reg 11`` and the other verbs.

``run`` (the default verb) runs the lifelong experiment; ``replay``, ``view``, ``plot``,
``compare`` and ``sweep`` work on run directories; ``options`` lists the environment's and the
optimisers' options. A mistake in what was given (an unknown verb or option, a value its option
cannot take, a missing file) is one line, ``error: ...``, and exit status 2, before anything is written.
"""
from __future__ import annotations

import argparse
import difflib
import shlex
import sys

from algorithms import UnknownAlgorithmError
from envs import ConfigError

from .. import loop, memory
from ..analysis.report import summary_table
from ..config import configure
from ..errors import Parser, UserError, interrupted_status, terminating_as_interrupt
from ..options import plain
from ..progress import MODES
from ..rundir import RunDir
from . import compare, option_list, plot, replay, score, sweep, view
from .flags import add_run_options, stated_settings
from .rerun_recorder import RerunRecorder

VERBS = {
    "replay": (replay, "Run a stored controller on fresh episodes and record them."),
    "view": (view, "Open a run's recording in the Rerun viewer."),
    "plot": (plot, "Write the paper's figures for runs as PNG."),
    "compare": (compare, "Tables of configurations over seeds, each against its baseline, and overlay figures."),
    "score": (score, "Score runs' exported controllers on the held-out episodes (summary.json's held_out block)."),
    "sweep": (sweep, "Grid of runs (algorithms x lambda x seeds x ...) on Ray."),
    "options": (option_list, "List the environment's and each optimiser's options, with defaults."),
}
"""Every verb but ``run`` (this module's): its module, with ``add_arguments`` and ``main``, and its help."""
RUN_HELP = "Run the lifelong experiment (the default verb)."


def _run_parser(parser: argparse.ArgumentParser) -> None:
    add_run_options(parser)
    parser.add_argument("--out", default="runs", help="parent folder of run directories (default: runs)")
    parser.add_argument("--name", default=None,
                        help="run directory name, one folder name inside --out "
                             "(default: from algo, schedule, reg, seed)")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run from its last checkpoint: give its --name, or the flags of "
                             "the command that started it (flags that differ from its stored settings are refused)")
    parser.add_argument("--overwrite", action="store_true",
                        help="delete an existing run directory first (only one that lifelong-evo wrote)")
    parser.add_argument("--start-from", default=None, metavar="RUN_DIR",
                        help="take over the first task of this run, which differs from this one only in --reg "
                             "(the same numbers, a third of a run's time saved on the paper's schedule), and go on")
    parser.add_argument("--progress", choices=MODES, default=None,
                        help="bar (the default on a terminal), lines (a line at every task end and at least "
                             "every 30 s: the default where stderr is a file) or off")
    parser.add_argument("--quiet", dest="progress", action="store_const", const="off", help="same as --progress off")


def resume_command(args: argparse.Namespace, name: str) -> str:
    """The command line that continues run ``name`` under ``args.out``."""
    words = ["python", "-m", "lifelong_evo", "--resume", "--name", name]
    if args.out != "runs":
        words += ["--out", args.out]
    return shlex.join(words)


def _run(args: argparse.Namespace) -> int:
    if args.resume and args.overwrite:
        raise UserError("--resume continues a run directory and --overwrite deletes it: give one of them")
    if args.resume and args.start_from:
        raise UserError("--resume continues a run from its own checkpoint: drop --start-from")
    stated = stated_settings(args)
    # a new run's configuration; without --name it also names the run (the command that started a
    # run, plus --resume, names the same directory)
    config = None if args.resume and args.name is not None else configure(stated)
    run_dir = RunDir.inside(args.out, args.name) if args.name is not None else RunDir.inside(
        args.out, config.default_name(), "the run name from --algo, --schedule, --reg and --seed", fix="give --name")
    if args.resume:
        run_dir.check_not_a_sweep()
        config = run_dir.continuation(stated)
        run_dir.check_free()  # the loop takes the lock
    else:
        if args.start_from:  # first: with --overwrite, the source may be the very directory it would empty
            loop.check_start_from(config, run_dir, RunDir(args.start_from))
        run_dir.check_create(args.overwrite)  # the loop checks again, locked
    if args.memory_check:
        memory.check([config])
    print(f"run directory: {run_dir.path}", flush=True)
    recorder = RerunRecorder.for_run(run_dir, config, resume=args.resume) if config.record else None
    try:
        summary = loop.run(config, run_dir, resume=args.resume, overwrite=args.overwrite, recorder=recorder,
                           progress=args.progress, start_from=RunDir(args.start_from) if args.start_from else None)
    except KeyboardInterrupt as interruption:  # Ctrl-C, or SIGTERM (errors.Terminated)
        if not run_dir.config.exists():
            print(f"\ninterrupted before {run_dir.path} was written: nothing to resume", file=sys.stderr)
        else:
            print(f"\ninterrupted: {run_dir.path} keeps everything up to its last checkpoint; continue with\n"
                  f"  {resume_command(args, run_dir.path.name)}", file=sys.stderr)
        return interrupted_status(interruption)
    print(summary_table(summary))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="python -m lifelong_evo", description=plain(__doc__),
                    formatter_class=argparse.RawDescriptionHelpFormatter)
    verbs = parser.add_subparsers(dest="verb", metavar="VERB")
    run = verbs.add_parser("run", help=RUN_HELP, description=RUN_HELP, epilog=option_list.listing(),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    _run_parser(run)
    run.set_defaults(handler=_run)
    parser.epilog = "The default verb, run:\n\n" + run.format_help()
    for verb, (module, help_text) in VERBS.items():
        sub = verbs.add_parser(verb, help=help_text, description=help_text)
        module.add_arguments(sub)
        sub.set_defaults(handler=module.main)
    return parser


def unknown_verb(word: str) -> str:
    """The error for a first word that is no verb (``run`` takes no words, only options): the verbs,
    and the closest one or the benchmark's own module where the word looks like it."""
    verbs = ["run", *VERBS]
    if word == "bench":
        fix = "the benchmark is a module of its own: python -m lifelong_evo.bench"
    elif close := difflib.get_close_matches(word, verbs, n=1):
        fix = f"did you mean {close[0]}?"
    else:
        fix = "see python -m lifelong_evo --help"
    return f"unknown verb {word!r}: the verbs are {', '.join(verbs)}; {fix}"


def main(argv: list[str] | None = None) -> int:
    """The command line with ``argv`` (default: ``sys.argv[1:]``); returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and not argv[0].startswith("-") and argv[0] not in ("run", *VERBS):
        print(f"error: {unknown_verb(argv[0])}", file=sys.stderr)
        return 2
    if not argv or argv[0] not in ("run", *VERBS, "-h", "--help"):
        argv = ["run", *argv]
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exit_:  # --help, or argparse's one-line error: main returns the status either way
        return exit_.code
    try:
        with terminating_as_interrupt():
            return args.handler(args) or 0
    except (UserError, ConfigError, UnknownAlgorithmError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except OSError as error:
        if error.filename is None:  # not about a path that was given: a fault, with its traceback
            raise
        # a path the file system refuses (a name too long, a file where a folder should be, no access)
        path = str(error.filename)
        shown = path if len(path) <= 80 else f"{path[:77]}..."
        print(f"error: cannot use {shown}: {error.strerror}: give another path", file=sys.stderr)
        return 2
    except KeyboardInterrupt as interruption:
        print("\ninterrupted", file=sys.stderr)
        return interrupted_status(interruption)


if __name__ == "__main__":
    sys.exit(main())
