"""The run options as command-line flags, shared by ``run`` and ``sweep`` (and, through
``add_flags``, the benchmark's).

Every ``RunConfig`` field is a flag (``--eval-threads``), typed and documented by the field
itself: its type and bounds parse the value (``lifelong_evo.options``), its docstring is the help
line. A boolean field gets ``--name`` and ``--no-name``. The nested tables are the repeatable
``--env KEY=VALUE`` and ``--option KEY=VALUE``; ``--tasks FILE`` reads the ``[tasks.NAME]`` tables
of a task file (as a flag, it wins over the config file's tables of the same names);
``--preset`` and ``--config FILE`` add the layers below the flags (``config.resolve``). ``--no-memory-check`` is no run setting: it lifts the check
that the run fits in memory (``lifelong_evo.memory``) and never changes a run's numbers. Flag
defaults are None, so that a preset and a TOML file can sit underneath; the help shows the
paper's defaults.
"""
from __future__ import annotations

import argparse
from dataclasses import fields

from envs import ConfigError

from ..config import PRESETS, RunConfig, configure, load_tasks, load_toml, merge_layers
from ..errors import UserError
from ..options import expected, field_docs, flag, parse_value, plain, schema, show, unbounded
from ..schedule import NAMED_SCHEDULES

NESTED = {"env": "--env", "algo_options": "--option"}
"""The RunConfig tables set key by key, and the repeatable flag of each."""


def typed(kind):
    """An argparse ``type`` parsing a flag's text as ``kind``."""
    def parse(text: str):
        try:
            return parse_value(kind, text)
        except ConfigError as error:
            raise argparse.ArgumentTypeError(str(error)) from None
    return parse


def _typed_list(name: str, kind):
    """An argparse ``type`` for a sweep's flag: comma-separated values, each parsed as the run's
    flag parses its one value, as a list. Schedules are separated by ``;`` (a custom schedule has
    commas of its own), named ones also by commas."""
    parse = typed(kind)

    def parse_list(text: str) -> list:
        if name == "schedule":
            items = []
            for part in (p.strip() for p in text.split(";")):
                pieces = [p.strip() for p in part.split(",")]
                items += pieces if all(p in NAMED_SCHEDULES for p in pieces) else [part]
        else:
            items = [p.strip() for p in text.split(",")]
        if any(not item for item in items):
            raise argparse.ArgumentTypeError(f"{text!r} has an empty value: write e.g. --seed 1,2,3")
        return [parse(item) for item in items]
    return parse_list


def add_flags(parser: argparse.ArgumentParser, cls: type, skip: tuple[str, ...] = (), axes: bool = False,
              unset: bool = False) -> None:
    """One flag per field of dataclass ``cls`` (but ``skip``): typed by the field's type and
    bounds, its help the field's docstring and default; a boolean field gets ``--name`` and
    ``--no-name``. ``axes``: a value flag takes a comma-separated list (``_typed_list``).
    ``unset``: flags default to None (so that other layers can sit underneath), else to the
    field's default."""
    defaults = cls()
    kinds = schema(cls)
    docs = field_docs(cls)
    for f in fields(cls):
        if f.name in skip:
            continue
        doc = plain(docs[f.name]).rstrip(".")
        default = getattr(defaults, f.name)
        initial = None if unset else default
        if kinds[f.name] is bool:
            parser.add_argument(flag(f.name), dest=f.name, action="store_const", const=True, default=initial,
                                help=f"{doc} (default: {show(default)})")
            parser.add_argument(f"--no-{f.name.replace('_', '-')}", dest=f.name, action="store_const", const=False,
                                help=f"the opposite of {flag(f.name)}")
        else:
            parse = _typed_list(f.name, kinds[f.name]) if axes else typed(kinds[f.name])
            accepted = f"{expected(kinds[f.name])}; " if unbounded(kinds[f.name])[1] else ""
            parser.add_argument(flag(f.name), dest=f.name, type=parse, default=initial,
                                help=f"{doc} ({accepted}default: {show(default)})"
                                     + ("; comma-separated values make an axis" if axes else ""))


def add_run_options(parser: argparse.ArgumentParser, axes: bool = False) -> None:
    """One flag per RunConfig field (``add_flags``), ``--env``, ``--option``, ``--preset``,
    ``--config`` and ``--memory-check``. ``axes``: the sweep's flags, where a value flag takes a
    comma-separated list and ``--preset`` defaults to the config file's."""
    add_flags(parser, RunConfig, skip=(*NESTED, "tasks"), axes=axes, unset=True)
    parser.add_argument("--tasks", dest="tasks_file", default=None, metavar="FILE",
                        help="TOML file of [tasks.NAME] tables (target, season, drop_zone, rewards, failed_robots, "
                             "motor_gain) whose names --schedule can use (docs/usage.md, Tasks)")
    parser.add_argument("--env", action="append", default=[], metavar="KEY=VALUE",
                        help="environment option, e.g. --env see_other_agents=true (repeatable; listed below)")
    parser.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                        help="optimiser option, e.g. --option sigma=0.05 (repeatable; listed below)")
    parser.add_argument("--preset", default=None if axes else "paper", choices=sorted(PRESETS),
                        help="paper or smoke (a run of seconds); default: "
                             + ("the config file's preset, else paper" if axes else "paper"))
    parser.add_argument("--config", default=None, metavar="FILE", help="TOML file; flags override it")
    parser.add_argument("--memory-check", dest="memory_check", action="store_true", default=True,
                        help="refuse, before anything is written, what would not fit in this machine's available "
                             "memory (an upper estimate: docs/usage.md, Memory; the default)")
    parser.add_argument("--no-memory-check", dest="memory_check", action="store_false",
                        help="run without that check (it never changes a run's numbers)")


def parse_assignments(items: list[str], what: str) -> dict[str, str]:
    """``KEY=VALUE`` items as ``{KEY: VALUE}``, the value still text: validating the run's
    configuration parses it by its option's declared type. A key given twice is refused: which
    of its values was meant, no rule can tell."""
    values = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise UserError(f"{what} {item!r} is not KEY=VALUE")
        check_once(what, key.strip(), text, values)
        values[key.strip()] = text
    return values


def check_once(what: str, key: str, text: str, given: dict[str, str]) -> None:
    """UserError where ``key`` (given ``text`` by flag ``what``) is among ``given``, the values
    ``what`` gave so far, by key."""
    if key in given:
        raise UserError(f"{what} {key} is given twice ({key}={given[key]} and {key}={text}): give it once")


def run_layers(args: argparse.Namespace) -> tuple[str, dict, dict]:
    """The preset, the TOML file's values and the flags' values of a command (``config.resolve``'s layers)."""
    overrides = {f.name: getattr(args, f.name) for f in fields(RunConfig)
                 if f.name not in NESTED and getattr(args, f.name, None) is not None}
    for table, setter in NESTED.items():
        values = parse_assignments(getattr(args, setter[2:]), setter)
        if values:
            overrides[table] = values
    if getattr(args, "tasks_file", None):
        overrides["tasks"] = load_tasks(args.tasks_file)
    file_values = load_toml(args.config) if args.config else {}
    return args.preset, file_values, overrides


def stated_settings(args: argparse.Namespace) -> dict:
    """The settings a command's preset, TOML file and flags state, without the defaults (``merge_layers``)."""
    preset, file_values, overrides = run_layers(args)
    return merge_layers(preset, file_values, overrides)


def resolve_run_config(args: argparse.Namespace) -> RunConfig:
    """The validated RunConfig a command's flags, file and preset give."""
    return configure(stated_settings(args))
