"""The tables the docs quote from ``compare`` are ``compare``'s output on the data the docs keep.

A quoted block in a page under docs/ (docs/results.md, docs/studies/*.md) reads

    <!-- compare docs/data/PART [compare's options] -->
    ...lines copied from compare's comparison.md...
    <!-- /compare -->

Every line of the block is a line of ``compare``'s markdown for that command, in the same order;
a table in the block is the header of one of ``compare``'s tables and some of its rows (a quote
may leave rows out, never change or move one between tables). To refresh a block after the data
or ``compare`` changed, run the command in its marker and copy the lines again."""
from __future__ import annotations

import functools
import re
import shlex
from pathlib import Path

import pytest

from lifelong_evo.commands import compare
from lifelong_evo.commands.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
BLOCK = re.compile(r"<!-- compare (?P<command>[^\n]*?) -->\n(?P<body>.*?)<!-- /compare -->", re.S)
QUOTED = ["docs/data/paper-genetics", "docs/data/families", "docs/data/study/paper-claim",
          "docs/data/study/ms-lambda", "docs/data/study/neat-lambda-grid", "docs/data/study/families",
          "docs/data/study/see-other-agents", "docs/data/study-nest-relocation", "docs/data/baselines",
          "docs/data/regularisers-lambda", "docs/data/regularisers-and-archive"]
"""Data folders whose tables the docs must quote through a checked block, given whole or run by run
(so that removing a block's marker cannot pass unnoticed)."""


def blocks() -> list[tuple[str, str, str]]:
    found = []
    for page in sorted((ROOT / "docs").rglob("*.md")):
        for match in BLOCK.finditer(page.read_text()):
            found.append((str(page.relative_to(ROOT / "docs")), match["command"], match["body"]))
    return found


def segments(markdown: str) -> list[str | list[str]]:
    """``markdown``'s non-blank lines, each run of table lines (``|...``) gathered into a list."""
    result: list[str | list[str]] = []
    for line in markdown.splitlines():
        line = line.rstrip()
        if not line:
            continue
        if line.startswith("|"):
            if result and isinstance(result[-1], list):
                result[-1].append(line)
            else:
                result.append([line])
        else:
            result.append(line)
    return result


def is_subsequence(part: list[str], whole: list[str]) -> bool:
    remaining = iter(whole)
    return all(any(line == candidate for candidate in remaining) for line in part)


def quotes(block: str, markdown: str) -> bool:
    """Whether every segment of ``block`` is found in ``markdown``'s, in order: a text line as
    itself, a table as one of ``markdown``'s tables with the same header holding its rows in order."""
    source = segments(markdown)
    position = 0
    for segment in segments(block):
        while position < len(source):
            candidate = source[position]
            position += 1
            if isinstance(segment, str):
                if candidate == segment:
                    break
            elif isinstance(candidate, list) and candidate[:2] == segment[:2] and is_subsequence(segment[2:], candidate[2:]):
                break
        else:
            return False
    return True


@functools.lru_cache(maxsize=None)  # blocks quoting the same command share one report
def report(command: str) -> str:
    args = build_parser().parse_args(["compare", *shlex.split(command)])
    args.paths = [ROOT / path for path in args.paths]
    return compare.requested_comparison(args).markdown


def test_the_quoted_data_have_blocks():
    quoted_paths = [path for _, command, _ in blocks() for path in shlex.split(command)]
    for folder in QUOTED:
        assert any(path == folder or path.startswith(f"{folder}/") for path in quoted_paths), f"no block quotes {folder}"


@pytest.mark.parametrize("page, command, body", blocks(), ids=lambda value: value.split("\n")[0][:60])
def test_a_quoted_block_is_compares_output(page, command, body):
    assert segments(body), f"{page}: the block of 'compare {command}' is empty"
    assert quotes(body, report(command)), (
        f"{page}: the block of 'compare {command}' is not compare's output: run "
        f"'python -m lifelong_evo compare {command}' and copy its lines again")


def test_a_changed_number_a_moved_row_or_a_made_up_line_is_not_a_quote():
    markdown = "# title\n\n| a | b |\n|---|---|\n| x | 1.00 |\n| y | 2.00 |\n\ntext\n\n| a | b |\n|---|---|\n| z | 3.00 |\n"
    assert quotes("| a | b |\n|---|---|\n| y | 2.00 |\ntext\n| a | b |\n|---|---|\n| z | 3.00 |", markdown)
    assert not quotes("| a | b |\n|---|---|\n| y | 2.01 |", markdown)  # a number changed
    assert not quotes("| a | b |\n|---|---|\n| x | 1.00 |\n| z | 3.00 |", markdown)  # rows of two tables
    assert not quotes("| a | b |\n|---|---|\n| y | 2.00 |\n| x | 1.00 |", markdown)  # rows reordered
    assert not quotes("text\n# title", markdown)  # lines out of order
    assert not quotes("another text", markdown)
