"""``python -m lifelong_evo options [--algo NAME]``: every environment and optimiser option with its
default, meaning and what it accepts (also the epilog of ``run --help``), from the dataclasses that
declare them (``lifelong_evo.options``)."""
from __future__ import annotations

import argparse
import textwrap

from envs import ConfigError

from ..options import expected, field_docs, schema, show


def describe(cls: type, title: str, width: int = 100) -> str:
    """``title`` and one entry per field of dataclass ``cls``: ``name=default``, its meaning and
    what it accepts."""
    docs = field_docs(cls)
    lines = [title]
    defaults = cls()
    for name, kind in schema(cls).items():
        head = f"  {name}={show(getattr(defaults, name))}"
        body = f"{docs.get(name, '')} ({expected(kind)})".strip()
        indent = " " * 30
        wrapped = textwrap.wrap(body, width, initial_indent=indent, subsequent_indent=indent,
                                break_on_hyphens=False)
        if len(head) < len(indent) - 1:
            wrapped[0] = head.ljust(len(indent)) + wrapped[0].lstrip()
        else:
            wrapped.insert(0, head)
        lines += wrapped
    return "\n".join(lines)


def listing(algos: list[str] | None = None) -> str:
    """The environment's options and each optimiser's (``algos``; default: all of them), one
    section for the optimisers that share their options."""
    from algorithms import REGISTRY
    from envs import ForagingConfig

    sections = [] if algos else [describe(ForagingConfig, "environment options (--env KEY=VALUE):")]
    sharing: dict[type, list[str]] = {}
    for name in algos or REGISTRY:
        sharing.setdefault(REGISTRY[name].Options, []).append(name)
    for options, names in sharing.items():
        title = f"{', '.join(names)} options (--option KEY=VALUE)"
        sections.append(describe(options, title + ":") if schema(options) else title + ": none")
    return "\n\n".join(sections)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--algo", action="append", default=None, metavar="NAME",
                        help="only this optimiser's options (repeatable; default: the environment's and every optimiser's)")


def main(args: argparse.Namespace) -> int:
    from algorithms import REGISTRY

    for name in args.algo or []:
        if name not in REGISTRY:
            raise ConfigError(f"unknown algorithm {name!r}: choose one of {', '.join(REGISTRY)}")
    print(listing(args.algo))
    return 0
