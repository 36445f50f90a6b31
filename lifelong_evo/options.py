"""Typed options: every value a user gives (a flag, ``--env``/``--option KEY=VALUE``, a TOML key) is
parsed to the type its dataclass field declares, and ``python -m lifelong_evo options`` lists
every option with its default and meaning.

The declarations are the dataclasses themselves: ``RunConfig`` (run options),
``envs.ForagingConfig`` (``--env``) and each optimiser's ``Options`` (``--option``): a field's
type says how its value is parsed, its attribute docstring is the line the listing shows.

Parsing contract: text (from the command line, or a TOML string) is read by the field's type,
surrounding spaces ignored; any other TOML value must already have it (an integer is fine for a
number). Booleans: true/false, yes/no, on/off, 1/0 in any case. Integers: decimal digits.
Numbers: decimal, finite. Choices (``Literal``): one of the listed words. Lists: ``[32,16]`` (or
``32,16``; ``[]`` is empty). Anything else raises ``envs.ConfigError`` naming the option, the
value and what is accepted.
"""
from __future__ import annotations

import argparse
import ast
import inspect
import math
import re
import textwrap
from dataclasses import fields, is_dataclass
from functools import cache
from typing import Any, Literal, get_args, get_origin, get_type_hints

from envs import ConfigError

TRUE_WORDS = ("true", "yes", "on", "1")
FALSE_WORDS = ("false", "no", "off", "0")


def expected(kind: Any) -> str:
    """What a value of type ``kind`` must look like (in messages and the listing)."""
    origin = get_origin(kind)
    if origin is Literal:
        return "one of " + ", ".join(map(str, get_args(kind)))
    if origin in (tuple, list):
        return f"a list of {_plural(get_args(kind)[0])} like [1,2]"
    return {bool: "a boolean: true/false, yes/no, on/off or 1/0", int: "an integer", float: "a finite number",
            str: "text"}.get(kind, f"a {getattr(kind, '__name__', kind)}")


def _plural(kind: Any) -> str:
    return {int: "integers", float: "numbers", str: "words"}.get(kind, expected(kind))


def parse_value(kind: Any, value: Any, name: str | None = None) -> Any:
    """``value`` as type ``kind`` (see the module docstring); otherwise ConfigError saying what
    ``kind`` accepts, after ``name`` where given."""
    try:
        return _parse(kind, value)
    except ValueError:
        refusal = f"{value!r} is not {expected(kind)}"
        raise ConfigError(f"{name}: {refusal}" if name else refusal) from None


def _parse(kind: Any, value: Any) -> Any:
    text = value.strip() if isinstance(value, str) else None
    origin = get_origin(kind)
    if origin is Literal:
        if text in get_args(kind):
            return text
    elif origin in (tuple, list):
        item_kind, *rest = get_args(kind)
        if rest not in ([], [Ellipsis]):
            raise TypeError(f"cannot parse options of type {kind}")
        if text is not None:
            inner = text[1:-1] if text[:1] == "[" and text[-1:] == "]" else text
            if not inner.strip() and inner == text:
                raise ValueError  # empty text without brackets: say [] for an empty list
            value = inner.split(",") if inner.strip() else []
        if isinstance(value, (list, tuple)):
            return origin(_parse(item_kind, item) for item in value)
    elif kind is bool:
        if isinstance(value, bool):
            return value
        if text is not None and text.lower() in TRUE_WORDS + FALSE_WORDS:
            return text.lower() in TRUE_WORDS
    elif kind is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if text is not None and re.fullmatch(r"[+-]?[0-9]+", text):
            return int(text)
    elif kind is float:
        number = None
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            number = float(value)
        elif text is not None and re.fullmatch(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?", text):
            number = float(text)
        if number is not None and math.isfinite(number):
            return number
    elif kind is str:
        if text:
            return text
    else:
        raise TypeError(f"cannot parse options of type {kind}")
    raise ValueError


def flag(name: str) -> str:
    """The command-line flag of run option ``name``."""
    return "--" + name.replace("_", "-")


def schema(cls: type) -> dict[str, Any]:
    """The init fields of dataclass ``cls`` and their types."""
    hints = get_type_hints(cls)
    return {f.name: hints[f.name] for f in fields(cls) if f.init}


def parse_table(cls: type, values: dict[str, Any], owner: str, setter: str, listed_by: str) -> dict[str, Any]:
    """``values`` (some fields of dataclass ``cls``, as the user gave them) parsed to their types;
    an unknown key is refused with the accepted ones. ``owner`` names the table in messages
    (``environment``, ``neat``), ``setter`` is the flag that sets a key (``--env``), ``listed_by``
    the command that describes them."""
    kinds = schema(cls)
    for key in values:
        if key not in kinds:
            raise ConfigError(f"unknown {owner} option {key!r}: the {owner} options are "
                              f"{', '.join(kinds) or 'none'} ({listed_by} describes them)")
    return {key: parse_value(kinds[key], value, f"{setter} {key}") for key, value in values.items()}


# ------------------------------------------------------------------------------------------- listing

@cache
def field_docs(cls: type) -> dict[str, str]:
    """The attribute docstrings of a dataclass's fields (the string right after each field), the
    most derived class's where a subclass redeclares a field; the project's dataclasses document
    their fields this way, so the listing and the code read from one place."""
    docs: dict[str, str] = {}
    names = {f.name for f in fields(cls)}
    for klass in reversed(cls.__mro__):
        if not is_dataclass(klass):
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError):  # defined where there is no source (an interactive session)
            continue
        body = tree.body[0].body
        for node, after in zip(body, body[1:]):
            if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.target.id in names
                    and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
                    and isinstance(after.value.value, str)):
                docs[node.target.id] = " ".join(plain(after.value.value).split())
    return docs


def plain(text: str) -> str:
    """``text`` without reStructuredText's double backticks, for the terminal."""
    return re.sub(r"``(.*?)``", r"\1", text, flags=re.S)


def show(value: Any) -> str:
    """A value as one would type it on the command line."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (tuple, list)):
        return "[" + ",".join(map(show, value)) + "]"
    return str(value)


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


# ------------------------------------------------------------------------------ the ``options`` verb

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
