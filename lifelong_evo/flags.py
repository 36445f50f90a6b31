"""The run options as command-line flags, shared by ``run`` and ``sweep``.

Every ``RunConfig`` field is a flag (``--eval-threads``), typed and documented by the field
itself: its type parses the value (``lifelong_evo.options``), its docstring is the help line. A
boolean field gets ``--name`` and ``--no-name``. The nested tables are the repeatable ``--env
KEY=VALUE`` and ``--option KEY=VALUE``; ``--preset`` and ``--config FILE`` add the layers below
the flags (``config.resolve``). Flag defaults are None, so that a preset and a TOML file can sit
underneath; the help shows the paper's defaults.
"""
from __future__ import annotations

import argparse
from dataclasses import fields

from envs import ConfigError

from .config import PRESETS, RunConfig, load_toml, resolve
from .errors import UserError
from .options import field_docs, flag, parse_value, plain, schema, show
from .schedule import NAMED_SCHEDULES

NESTED = {"env": "--env", "algo_options": "--option"}
"""The RunConfig tables set key by key, and the repeatable flag of each."""


def _typed(kind):
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
    parse = _typed(kind)

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


def add_run_options(parser: argparse.ArgumentParser, axes: bool = False) -> None:
    """One flag per RunConfig field, ``--env``, ``--option``, ``--preset`` and ``--config``.
    ``axes``: the sweep's flags, where a value flag takes a comma-separated list (``_typed_list``)
    and ``--preset`` defaults to the config file's."""
    defaults = RunConfig()
    kinds = schema(RunConfig)
    docs = field_docs(RunConfig)
    for f in fields(RunConfig):
        if f.name in NESTED:
            continue
        doc = plain(docs[f.name]).rstrip(".")
        default = show(getattr(defaults, f.name))
        if kinds[f.name] is bool:
            parser.add_argument(flag(f.name), dest=f.name, action="store_const", const=True, default=None,
                                help=f"{doc} (default: {default})")
            parser.add_argument(f"--no-{f.name.replace('_', '-')}", dest=f.name, action="store_const", const=False,
                                help=f"the opposite of {flag(f.name)}")
        else:
            parse = _typed_list(f.name, kinds[f.name]) if axes else _typed(kinds[f.name])
            parser.add_argument(flag(f.name), dest=f.name, type=parse, default=None,
                                help=f"{doc} (default: {default})" + ("; comma-separated values make an axis"
                                                                      if axes else ""))
    parser.add_argument("--env", action="append", default=[], metavar="KEY=VALUE",
                        help="environment option, e.g. --env see_other_agents=true (repeatable; listed below)")
    parser.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                        help="optimiser option, e.g. --option sigma=0.05 (repeatable; listed below)")
    parser.add_argument("--preset", default=None if axes else "paper", choices=sorted(PRESETS),
                        help="paper or smoke (a run of seconds); default: "
                             + ("the config file's preset, else paper" if axes else "paper"))
    parser.add_argument("--config", default=None, metavar="FILE", help="TOML file; flags override it")


def parse_assignments(items: list[str], what: str) -> dict[str, str]:
    """``KEY=VALUE`` items as ``{KEY: VALUE}``, the value still text: validating the run's
    configuration parses it by its option's declared type."""
    values = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise UserError(f"{what} {item!r} is not KEY=VALUE")
        values[key.strip()] = text
    return values


def run_layers(args: argparse.Namespace) -> tuple[str, dict, dict]:
    """The preset, the TOML file's values and the flags' values of a command (``config.resolve``'s layers)."""
    overrides = {f.name: getattr(args, f.name) for f in fields(RunConfig)
                 if f.name not in NESTED and getattr(args, f.name, None) is not None}
    for table, setter in NESTED.items():
        values = parse_assignments(getattr(args, setter[2:]), setter)
        if values:
            overrides[table] = values
    file_values = load_toml(args.config) if args.config else {}
    return args.preset, file_values, overrides


def resolve_run_config(args: argparse.Namespace) -> RunConfig:
    """The validated RunConfig a command's flags, file and preset give."""
    return resolve(*run_layers(args))
