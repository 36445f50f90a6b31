"""The command line against generated input: run names and output folders (``.``, ``..``,
separators, absolute paths, names too long, folders that are files or hold other runs),
``--overwrite`` and ``--resume`` in every combination, and numbers no option can take, for
``run``, ``sweep`` (``--dry-run`` and ``--together``) and ``bench``.

For every input: exit status 0 or 2, no traceback (an exception out of ``main`` fails the test),
at most a few lines on stderr (exactly one ``error:`` line on a refusal), and a scratch tree of
two finished runs, an unrelated folder and a file that survives byte for byte, apart from the
one run directory (or sweep folder) the command was meant to write, inside ``--out``."""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from lifelong_evo.commands import bench
from lifelong_evo.commands.cli import main

SIZE = ["--preset", "smoke", "--no-record", "--generations", "2", "--env", "duration=30"]
"""A run of a second or two: the tree is what is checked, not learning."""
OUTS = ["runs", ".", "unrelated", "unrelated/notes.txt", "runs/first", "fresh/deep", "", "y" * 300]
NAMES = [".", "..", "a/b", "../x", "", "first", "second", "fresh", "unrelated", "runs", "notes.txt", "x" * 300,
         "/absolute"]
HUGE = st.integers(min_value=10 ** 20, max_value=10 ** 40).map(str)
NOT_A_NUMBER = st.sampled_from(["-1", "-7", "1e400", "nan", "inf", "-inf", "1.5", "abc", "", "0x10", "\u0661\u0662"])
BAD_NUMBER = st.one_of(HUGE, NOT_A_NUMBER)
"""Values no count or size of a run, a sweep or a benchmark takes (0 aside: a seed takes it)."""


@st.composite
def bad_settings(draw) -> list[str]:
    """Zero or one run setting no run can take: a number too large, negative or not a number."""
    kind = draw(st.sampled_from(["none", "none", "none", "flag", "env", "hidden"]))
    if kind == "flag":
        return [draw(st.sampled_from(["--seed", "--generations", "--population", "--evals", "--held-out-episodes",
                                      "--retention-every"])), draw(BAD_NUMBER)]
    if kind == "env":
        return ["--env", f"{draw(st.sampled_from(['duration', 'max_retrieves', 'n_neighbors', 'n_boxes']))}="
                         f"{draw(BAD_NUMBER)}"]
    if kind == "hidden":
        return ["--algo", "sep-cmaes", "--option", f"hidden=[{draw(HUGE)}]"]
    return []


@st.composite
def commands(draw) -> tuple[str, list[str]]:
    """A verb and its arguments."""
    verb = draw(st.sampled_from(["run", "sweep --dry-run", "sweep --together", "bench"]))
    if verb == "bench":
        flag = draw(st.sampled_from(["--envs", "--steps", "--population", "--evals", "--generations", "--runs",
                                     "--threads", "--eval-threads", "--also"]))
        value = draw(BAD_NUMBER.filter(bool) if flag == "--also" else BAD_NUMBER)  # --also [] is no other size
        argv = [flag, f"[{value}]" if flag == "--also" else value]
        if draw(st.booleans()) and flag not in ("--envs", "--steps", "--also"):
            argv = ["--algo", draw(st.sampled_from(["neat", "openai-es", "nope"])), *argv]
        return verb, argv
    argv = [*verb.split()[1:], *SIZE, "--out", draw(st.sampled_from(OUTS))] + ([] if verb != "run" else ["--quiet"])
    if draw(st.booleans()):
        argv += ["--name", draw(st.one_of(st.sampled_from(NAMES), st.text(max_size=12)))]
    argv += draw(st.lists(st.sampled_from(["--overwrite", "--resume"] if verb == "run" else ["--overwrite"]),
                          unique=True, max_size=2))
    argv += draw(bad_settings())
    return verb, (["sweep", *argv] if verb.startswith("sweep") else argv)


def bench_status(argv: list[str]) -> int:
    """``python -m lifelong_evo.bench``'s exit status (it exits through SystemExit, as argparse does)."""
    try:
        bench.main(argv)
    except SystemExit as stop:
        return stop.code
    return 0


def snapshot(root: Path) -> dict[str, bytes | None]:
    """Every file (its bytes) and folder (None) under ``root``."""
    return {str(p.relative_to(root)): None if p.is_dir() else p.read_bytes() for p in sorted(root.rglob("*"))}


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished run directory, written by the toolkit (so with its marker), to copy."""
    out = tmp_path_factory.mktemp("finished")
    assert main([*SIZE, "--out", str(out), "--name", "done"]) == 0
    return out / "done"


def scratch_tree(finished: Path) -> Path:
    """A fresh working directory: runs/ with two finished runs, an unrelated folder holding a file."""
    work = Path(tempfile.mkdtemp(prefix="fuzz-")) / "work"
    shutil.copytree(finished, work / "runs" / "first")
    shutil.copytree(finished, work / "runs" / "second")
    (work / "unrelated").mkdir()
    (work / "unrelated" / "notes.txt").write_text("keep me")
    return work


def written_outside_its_run(before: dict, after: dict, out: str) -> list[str]:
    """The paths that changed other than those of one entry of ``out`` (the run or sweep folder a
    command writes) and the folders created to hold it."""
    changed = sorted(p for p in before.keys() | after.keys() if before.get(p, b"") != after.get(p, b""))
    prefix = Path(os.path.normpath(out)) if out not in ("", ".") else Path()
    inside = [Path(p) for p in changed if prefix == Path() or prefix in Path(p).parents]
    depth = len(prefix.parts) + 1
    entries = {p.parts[:depth] for p in inside if len(p.parts) >= depth}
    created_parents = {p for p in changed if p not in before and after.get(p, b"") is None
                       and any(Path(*e) == Path(p) or Path(p) in Path(*e).parents for e in entries)}
    outside = [p for p in changed if Path(p) not in inside and p not in created_parents]
    return outside + ([f"{len(entries)} entries of {out!r}: {sorted(entries)}"] if len(entries) > 1 else [])


@settings(max_examples=40, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(command=commands())
def test_nothing_outside_the_named_run_is_touched_whatever_the_command_line(command, finished, capsys, monkeypatch):
    verb, argv = command
    work = scratch_tree(finished)
    monkeypatch.chdir(work)
    try:
        before = snapshot(work.parent)
        code = bench_status(argv) if verb == "bench" else main(argv)
        captured = capsys.readouterr()
        after = snapshot(work.parent)
    finally:
        monkeypatch.undo()
        shutil.rmtree(work.parent)
    event(f"{verb}: exit {code}")  # --hypothesis-show-statistics: how many inputs ran and how many were refused
    assert code in (0, 2), (argv, code, captured.err)
    assert "Traceback" not in captured.err and captured.err.count("\n") <= 3, (argv, captured.err)
    if code == 2:
        assert captured.err.startswith("error: ") and captured.err.count("\n") == 1, (argv, captured.err)
        assert after == before, (argv, sorted(after.keys() ^ before.keys()))
    else:
        out = argv[argv.index("--out") + 1]
        assert not written_outside_its_run(before, after, os.path.join("work", out)), (argv, captured.err)


def test_the_tree_check_sees_a_write_outside_the_run():
    """The check itself: a second run's folder, a changed unrelated file, and a deleted one, show."""
    before = {"work": None, "work/runs": None, "work/runs/first": None, "work/runs/first/a": b"1",
              "work/unrelated": None, "work/unrelated/notes.txt": b"keep me"}
    new_run = {**before, "work/runs/new": None, "work/runs/new/config.json": b"{}"}
    assert written_outside_its_run(before, new_run, "work/runs") == []
    assert written_outside_its_run(before, {**new_run, "work/runs/other": None}, "work/runs")
    assert written_outside_its_run(before, {**new_run, "work/unrelated/notes.txt": b""}, "work/runs")
    assert written_outside_its_run(before, {k: v for k, v in new_run.items() if k != "work/unrelated/notes.txt"},
                                   "work/runs")
    fresh = {**before, "work/fresh": None, "work/fresh/deep": None, "work/fresh/deep/x": None,
             "work/fresh/deep/x/m": b""}
    assert written_outside_its_run(before, fresh, "work/fresh/deep") == []
