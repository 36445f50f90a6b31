"""Command line: ``python -m lifelong_evo [run] --algo neat --reg 11`` and the other verbs.

``run`` (the default verb) runs the lifelong experiment; ``replay``, ``view``, ``plot``,
``compare`` and ``sweep`` work on run directories; ``options`` lists the environment's and the
optimisers' options. A mistake in what was given (an unknown option, a value its option cannot
take, a missing file) is one line, ``error: ...``, and exit status 2, before anything is written.
"""
from __future__ import annotations

import argparse
import importlib
import json
import re
import shlex
import sys
from dataclasses import asdict, fields, replace
from pathlib import Path

from envs import ConfigError

from .config import PRESETS, RunConfig
from .options import flag, listing, parse_value, plain, schema, show
from .progress import MODES

VERBS = {
    "run": ("lifelong_evo.cli", "Run the lifelong experiment (the default verb)."),
    "replay": ("lifelong_evo.replay", "Run a stored controller on fresh episodes and record them."),
    "view": ("lifelong_evo.view", "Open a run's recording in the Rerun viewer."),
    "plot": ("lifelong_evo.plots", "Write the paper's figures for runs as PNG."),
    "compare": ("lifelong_evo.compare", "Summary table of configurations over seeds, and an overlay figure."),
    "sweep": ("lifelong_evo.sweep", "Grid of runs (algorithms x lambda x seeds x ...) on Ray."),
    "options": ("lifelong_evo.options", "List the environment's and each optimiser's options, with defaults."),
}

_FIELD_DOCS = {
    "algo": "optimiser: neat, cmaes, sep-cmaes, openai-es, pgpe, snes",
    "reg": "regularisation strength lambda (0 = off)",
    "schedule": "red-green-red, four-tasks, or e.g. red:200,green:100,red:50",
    "generations": "generations per task where the schedule gives none",
    "population": "population size (ES: samples; the centre is scored too)",
    "evals": "environments per controller and task each generation (N)",
    "seed": "seed of everything",
    "retention_every": "score earlier tasks every this many generations",
    "checkpoint_every": "checkpoint every this many generations",
    "device": "torch device (cpu, cuda, ...)",
    "threads": "torch CPU threads",
    "eval_threads": ("evaluation threads, each playing a slice of the population with its own env; "
                     "1 in the smoke preset; use 1 on a GPU"),
    "episodes_every": "also record episodes every this many generations (0: task ends only)",
}


class CliError(Exception):
    pass


class Parser(argparse.ArgumentParser):
    """argparse with the command line's error contract: one line and exit status 2."""

    def error(self, message: str):
        self.exit(2, f"error: {message} (see {self.prog} --help)\n")


def _typed(kind):
    """An argparse ``type`` parsing a flag's text as ``kind`` (``lifelong_evo.options``)."""
    def parse(text: str):
        try:
            return parse_value(kind, text)
        except ConfigError as error:
            raise argparse.ArgumentTypeError(str(error)) from None
    return parse


def add_run_options(parser: argparse.ArgumentParser) -> None:
    """The run options (shared with ``sweep``): defaults are None so that a TOML file and a
    preset can sit underneath; the help shows the paper defaults."""
    defaults = RunConfig()
    kinds = schema(RunConfig)
    for f in fields(RunConfig):
        if f.name in _FIELD_DOCS:
            parser.add_argument(flag(f.name), dest=f.name, type=_typed(kinds[f.name]), default=None,
                                help=f"{_FIELD_DOCS[f.name]} (default: {show(getattr(defaults, f.name))})")
    parser.add_argument("--no-record", dest="record", action="store_const", const=False, default=None,
                        help="do not write recording.rrd")
    parser.add_argument("--compile", dest="compile", action="store_const", const=True, default=None,
                        help="torch.compile the environment's step: about 2.5x faster steps, 20-60 s to compile "
                             "per batch shape, needs a C++ compiler (default: on; the smoke preset: off)")
    parser.add_argument("--no-compile", dest="compile", action="store_const", const=False,
                        help="run the environment's step eagerly")
    parser.add_argument("--env", action="append", default=[], metavar="KEY=VALUE",
                        help="environment option, e.g. --env see_other_agents=true (repeatable; listed below)")
    parser.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                        help="optimiser option, e.g. --option sigma=0.05 (repeatable; listed below)")
    parser.add_argument("--preset", default="paper", choices=sorted(PRESETS),
                        help="paper (default) or smoke (a run of seconds)")
    parser.add_argument("--config", default=None, metavar="FILE", help="TOML file; flags override it")


def parse_assignments(items: list[str], what: str) -> dict[str, str]:
    """``KEY=VALUE`` items as ``{KEY: VALUE}``, the value still text: validating the run's
    configuration parses it by its option's declared type."""
    values = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise CliError(f"{what} {item!r} is not KEY=VALUE")
        values[key.strip()] = text
    return values


def run_layers(args: argparse.Namespace, **forced) -> tuple[str, dict, dict]:
    """The preset, the TOML file's values and the flags' values of a command (``config.resolve``'s layers)."""
    from .config import load_toml

    overrides = {f.name: getattr(args, f.name) for f in fields(RunConfig)
                 if getattr(args, f.name, None) is not None and f.name not in ("env", "algo_options")}
    env = parse_assignments(args.env, "--env")
    options = parse_assignments(args.option, "--option")
    if env:
        overrides["env"] = env
    if options:
        overrides["algo_options"] = options
    overrides.update(forced)
    file_values = load_toml(args.config) if args.config else {}
    return args.preset, file_values, overrides


def resolve_run_config(args: argparse.Namespace, **forced) -> RunConfig:
    from .config import resolve

    return resolve(*run_layers(args, **forced))


def default_name(config: RunConfig) -> str:
    schedule = re.sub(r"[^A-Za-z0-9]+", "-", config.schedule).strip("-")
    return f"{config.algo}-{schedule}-reg{config.reg:g}-seed{config.seed}"


def _run_parser(parser: argparse.ArgumentParser) -> None:
    add_run_options(parser)
    parser.add_argument("--out", default="runs", help="parent folder of run directories (default: runs)")
    parser.add_argument("--name", default=None, help="run directory name (default: from algo, schedule, reg, seed)")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run from its last checkpoint: give its --name, or the flags of "
                             "the command that started it (flags that differ from its stored settings are refused)")
    parser.add_argument("--overwrite", action="store_true", help="delete an existing run directory first")
    parser.add_argument("--progress", choices=MODES, default=None,
                        help="bar (the default on a terminal), lines (a line at every task end and at least "
                             "every 30 s: the default where stderr is a file) or off")
    parser.add_argument("--quiet", dest="progress", action="store_const", const="off", help="same as --progress off")


RESUMABLE = ("record", "episodes_every")
"""Settings a resumed run may change (``loop.run`` allows them): recording only."""


def _same(a, b) -> bool:
    """Equal as config.json stores them (tuples are lists; 11 and 11.0 are one value)."""
    return json.loads(json.dumps(a)) == json.loads(json.dumps(b))


def resumed_config(args: argparse.Namespace, stored: RunConfig, where: Path) -> RunConfig:
    """``stored`` with the recording settings the command gives; any other setting the command
    states (flags, --config, --preset) must equal the stored one, else CliError names each
    difference with both values."""
    from algorithms import REGISTRY

    from .config import merge_layers

    stated = merge_layers(*run_layers(args))
    # the stated values parsed to their types, as the run that stored them was
    typed = replace(stored, **{key: value for key, value in stated.items() if key not in ("env", "algo_options")},
                    env={**stored.env, **stated.get("env", {})},
                    algo_options={**stored.algo_options, **stated.get("algo_options", {})}).validate(machine=False)
    differ = []
    for key, value in stated.items():
        if key in RESUMABLE:
            continue
        if key in ("env", "algo_options"):
            # an option the run left at its default was run with that default
            flag, kept = (("--env", {**stored.env_config().to_dict(), **stored.env}) if key == "env"
                          else ("--option", {**asdict(REGISTRY[stored.algo].Options()), **stored.algo_options}))
            for sub in value:
                given = getattr(typed, key)[sub]
                if sub not in kept or not _same(kept[sub], given):
                    differ.append(f"{flag} {sub}={given!r} (stored: {repr(kept[sub]) if sub in kept else 'not set'})")
        elif not _same(getattr(stored, key), getattr(typed, key)):
            differ.append(f"--{key.replace('_', '-')} {getattr(typed, key)!r} (stored: {getattr(stored, key)!r})")
    if differ:
        raise CliError(f"--resume continues {where} with its stored settings, and the command differs from them: "
                       f"{'; '.join(differ)}: drop these flags or give the stored values")
    return replace(stored, **{key: stated[key] for key in RESUMABLE if key in stated})


def resume_command(args: argparse.Namespace, name: str) -> str:
    """The command line that continues run ``name`` under ``args.out``."""
    words = ["python", "-m", "lifelong_evo", "--resume", "--name", name]
    if args.out != "runs":
        words += ["--out", args.out]
    return shlex.join(words)


def _run(args: argparse.Namespace) -> int:
    from .loop import run, stored_config
    from .rundir import RunDir

    if args.resume:
        # the command that started the run, plus --resume, names the same directory
        run_dir = RunDir(Path(args.out) / (args.name or default_name(resolve_run_config(args))))
        config = resumed_config(args, stored_config(run_dir), run_dir.path)
    else:
        config = resolve_run_config(args)
        run_dir = RunDir(Path(args.out) / (args.name or default_name(config)))
    print(f"run directory: {run_dir.path}", flush=True)
    recorder = None
    if config.record:
        from .rerun_recorder import RerunRecorder

        recorder = RerunRecorder.for_run(run_dir, config, resume=args.resume)
    try:
        summary = run(config, run_dir, resume=args.resume, overwrite=args.overwrite, recorder=recorder,
                      progress=args.progress)
    except KeyboardInterrupt:
        if not run_dir.config.exists():
            print(f"\ninterrupted before {run_dir.path} was written: nothing to resume", file=sys.stderr)
        else:
            print(f"\ninterrupted: {run_dir.path} keeps everything up to its last checkpoint; continue with\n"
                  f"  {resume_command(args, run_dir.path.name)}", file=sys.stderr)
        return 130
    from .report import summary_table

    print(summary_table(summary))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="python -m lifelong_evo", description=plain(__doc__),
                    formatter_class=argparse.RawDescriptionHelpFormatter)
    verbs = parser.add_subparsers(dest="verb", metavar="VERB")
    for verb, (module, help_text) in VERBS.items():
        sub = verbs.add_parser(verb, help=help_text, description=help_text)
        if verb == "run":
            _run_parser(sub)
            sub.set_defaults(handler=_run)
            sub.formatter_class = argparse.RawDescriptionHelpFormatter
            sub.epilog = listing()
            parser.epilog = "The default verb, run:\n\n" + sub.format_help()
        else:
            command = importlib.import_module(module)
            command.add_arguments(sub)
            sub.set_defaults(handler=command.main)
    return parser


def main(argv: list[str] | None = None) -> int:
    """The command line with ``argv`` (default: ``sys.argv[1:]``); returns the exit status."""
    from algorithms import UnknownAlgorithmError

    from .checkpoint import CheckpointError
    from .loop import ResumeError
    from .rundir import RunDirError

    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or (argv[0] not in VERBS and argv[0] not in ("-h", "--help")):
        argv = ["run", *argv]
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exit_:  # --help, or argparse's one-line error: main returns the status either way
        return exit_.code
    try:
        return args.handler(args) or 0
    except (CliError, ConfigError, RunDirError, ResumeError, CheckpointError, UnknownAlgorithmError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("\ninterrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
