"""Typed options: every value a user gives (a flag, ``--env``/``--option KEY=VALUE``, a TOML key) is
parsed to the type its dataclass field declares (``python -m lifelong_evo options``,
``commands/option_list.py``, lists every option with its default and meaning).

The declarations are the dataclasses themselves: ``RunConfig`` (run options),
``envs.ForagingConfig`` (``--env``) and each optimiser's ``Options`` (``--option``): a field's
type says how its value is parsed, its attribute docstring is the line the listing shows.

Parsing contract: text (from the command line, or a TOML string) is read by the field's type,
surrounding spaces ignored; any other TOML value must already have it (an integer is fine for a
number). Booleans: true/false, yes/no, on/off, 1/0 in any case. Integers: decimal digits (ASCII
0-9 only). Numbers: decimal, finite; -0 is 0. Choices (``Literal``): one of the listed words.
Lists: ``[32,16]`` (or ``32,16``; ``[]`` is empty). Anything else raises ``envs.ConfigError``
naming the option, the value and what is accepted.

A value that the toolkit wrote (config.json: ``text=False``) is read strictly, as JSON typed it:
text only where the field takes text (``str``, a choice), a JSON boolean for a boolean, a JSON
integer for an integer, a JSON number for a number, a JSON list for a list. A string ``"200"``
where an integer belongs is a damaged file, not a value to convert.

Bounds: a number field may declare the range it accepts in its dataclass field's ``metadata``
(``field(default=500, metadata={"min": 1, "max": 100_000})``): ``min`` and ``max`` (inclusive),
``above`` (an exclusive lower bound, for "> 0"); for a list they bound each item, and
``max_items`` its length. ``schema`` hands them on as ``Annotated[type, Bounds]``, so a value
outside them is refused as it is parsed, before anything is built, and the listing shows them.
They are the values a researcher would give, with room to spare, so that no value overflows a
tensor's integers or asks for memory no machine has; the classes' own checks stay, for their
users in Python.
"""
from __future__ import annotations

import ast
import inspect
import math
import re
import textwrap
from dataclasses import dataclass, fields, is_dataclass
from functools import cache
from typing import Annotated, Any, Literal, Mapping, get_args, get_origin, get_type_hints

from envs import ConfigError
from envs.config import shown

LISTED_BY = "python -m lifelong_evo options"
"""The command that lists every option (``--algo NAME``: one optimiser's)."""
TRUE_WORDS = ("true", "yes", "on", "1")
FALSE_WORDS = ("false", "no", "off", "0")


@dataclass(frozen=True)
class Bounds:
    """The range a number, or each item of a list, must lie in, and at most how many items a list
    holds: a field's ``metadata`` (see the module docstring)."""

    min: float | None = None
    max: float | None = None
    above: float | None = None
    max_items: int | None = None

    def admits(self, value: Any) -> bool:
        items = tuple(value) if isinstance(value, (tuple, list)) else (value,)
        if self.max_items is not None and len(items) > self.max_items:
            return False
        return all((self.min is None or item >= self.min) and (self.max is None or item <= self.max)
                   and (self.above is None or item > self.above) for item in items)

    def describe(self) -> str:
        """``from 1 to 100000``, ``>= 0``, ``> 0 and <= 1000``."""
        if self.min is not None and self.max is not None:
            return f"from {_number(self.min)} to {_number(self.max)}"
        low = f">= {_number(self.min)}" if self.min is not None else (
            f"> {_number(self.above)}" if self.above is not None else "")
        high = f"<= {_number(self.max)}" if self.max is not None else ""
        return " and ".join(part for part in (low, high) if part)


def _number(value: float) -> str:
    """A bound as one would type it: 4294967295, 0.5, 1e9."""
    if isinstance(value, int) or (value.is_integer() and abs(value) < 1e8):
        return str(int(value))
    return re.sub(r"e\+?0*", "e", f"{value:g}")


def bounded(kind: Any, metadata: Mapping[str, Any]) -> Any:
    """``kind`` with the bounds a field's ``metadata`` declares (``Annotated[kind, Bounds]``), or
    ``kind`` itself where it declares none."""
    declared = {key: value for key, value in metadata.items() if key in Bounds.__dataclass_fields__}
    return Annotated[kind, Bounds(**declared)] if declared else kind


def unbounded(kind: Any) -> tuple[Any, Bounds | None]:
    """``kind`` without its bounds, and the bounds (None where it has none)."""
    if get_origin(kind) is Annotated:
        return kind.__origin__, next((m for m in kind.__metadata__ if isinstance(m, Bounds)), None)
    return kind, None


def expected(kind: Any, text: bool = True) -> str:
    """What a value of type ``kind`` must look like (in messages and the listing); ``text``: as
    text is read (``parse_value``), else as a JSON value."""
    kind, bounds = unbounded(kind)
    within = f" {bounds.describe()}" if bounds and bounds.describe() else ""
    origin = get_origin(kind)
    if origin is Literal:
        return "one of " + ", ".join(map(str, get_args(kind)))
    if origin in (tuple, list):
        most = f"at most {bounds.max_items} " if bounds and bounds.max_items is not None else ""
        return f"a list of {most}{_plural(get_args(kind)[0])}{within}, written [a,b,...]"
    boolean = "a boolean: true/false, yes/no, on/off or 1/0" if text else "a boolean (true or false)"
    return {bool: boolean, int: "an integer", float: "a finite number",
            str: "text"}.get(kind, f"a {getattr(kind, '__name__', kind)}") + within


def _plural(kind: Any) -> str:
    return {int: "integers", float: "numbers", str: "words"}.get(kind, expected(kind))


def parse_value(kind: Any, value: Any, name: str | None = None, text: bool = True) -> Any:
    """``value`` as type ``kind`` (see the module docstring), within its bounds; otherwise
    ConfigError saying what ``kind`` accepts, after ``name`` where given. ``text=False``: a JSON
    value the toolkit wrote, read strictly (a string only where ``kind`` takes text)."""
    plain_kind, bounds = unbounded(kind)
    try:
        parsed = _parse(plain_kind, value, text)
        if bounds is not None and not bounds.admits(parsed):
            raise ValueError
        return parsed
    except ValueError:
        written = shown(value)  # a value of thousands of digits: one readable line
        refusal = f"{written} is not {expected(kind, text)}"
        if isinstance(value, str) and not text and not _reads_text(plain_kind):
            refusal = f"{written} is a string, not {expected(kind, text)}"
        choices = get_args(plain_kind) if get_origin(plain_kind) is Literal else ()
        if not isinstance(value, (str, bool)) and str(value) in choices:  # TOML's genetics = 0.92, a number
            refusal += f": write it in quotes, \"{value}\""
        raise ConfigError(f"{name}: {refusal}" if name else refusal) from None


def _reads_text(kind: Any) -> bool:
    """Whether a value of ``kind`` is text itself (a word, a choice), not text to convert."""
    return kind is str or get_origin(kind) is Literal


def _parse(kind: Any, value: Any, text_ok: bool = True) -> Any:
    text = value.strip() if isinstance(value, str) and (text_ok or _reads_text(kind)) else None
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
            return origin(_parse(item_kind, item, text_ok) for item in value)
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
            return number + 0.0  # -0 is 0: one value, one spelling in run names and comparisons
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
    """The init fields of dataclass ``cls`` and their types, with their bounds (``bounded``): a
    field's own, else those of the nearest base class that declares the field with bounds (so a
    subclass that redeclares a field for another default keeps its bounds)."""
    hints = get_type_hints(cls)
    return {f.name: bounded(hints[f.name], _metadata(cls, f.name)) for f in fields(cls) if f.init}


def _metadata(cls: type, name: str) -> Mapping[str, Any]:
    for klass in cls.__mro__:
        declared = getattr(klass, "__dataclass_fields__", {}).get(name)
        if declared is not None and declared.metadata:
            return declared.metadata
    return {}


def parse_table(cls: type, values: dict[str, Any], owner: str, setter: str, listed_by: str,
                text: bool = True) -> dict[str, Any]:
    """``values`` (some fields of dataclass ``cls``, as the user gave them) parsed to their types;
    an unknown key is refused with the accepted ones. ``owner`` names the table in messages
    (``environment``, ``neat``), ``setter`` is the flag that sets a key (``--env``), ``listed_by``
    the command that describes them; ``text``: as ``parse_value``'s."""
    kinds = schema(cls)
    for key in values:
        if key not in kinds:
            raise ConfigError(f"unknown {owner} option {key!r}: the {owner} options are "
                              f"{', '.join(kinds) or 'none'} ({listed_by} describes them)")
    return {key: parse_value(kinds[key], value, f"{setter} {key}", text) for key, value in values.items()}


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
