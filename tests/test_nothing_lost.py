"""Nothing a user has is lost: a run name is one folder name inside ``--out`` (for ``run`` and
``sweep``), ``--overwrite`` deletes only a run directory lifelong-evo wrote (its marker), and one
process writes a run directory at a time (its lock), which a killed process never keeps.

Every refusal is checked against a snapshot of the whole scratch tree: two finished runs, an
unrelated folder and the working directory, byte for byte."""
from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from algorithms import REGISTRY
from lifelong_evo.commands.cli import main
from lifelong_evo.commands.sweep import run_trial
from lifelong_evo.run_lock import LOCK
from lifelong_evo.rundir import MARKER, RunDir

ROOT = Path(__file__).resolve().parents[1]
SIZE = ["--preset", "smoke", "--no-record", "--generations", "2", "--env", "duration=30"]
"""A run of a second or two: these tests check the run directory, not learning."""
RUN = [*SIZE, "--quiet"]
HOLDER = f"process {os.getpid()} on host {socket.gethostname()}"
"""How a refusal names this process when it holds a lock."""


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished run directory, written by the toolkit (so with its marker), to copy."""
    out = tmp_path_factory.mktemp("finished")
    assert main([*RUN, "--out", str(out), "--name", "done"]) == 0
    return out / "done"


@pytest.fixture
def work(tmp_path, finished, monkeypatch) -> Path:
    """The working directory of the command: ``runs/`` with two finished runs, an unrelated folder."""
    work = tmp_path / "work"
    shutil.copytree(finished, work / "runs" / "first")
    shutil.copytree(finished, work / "runs" / "second")
    (work / "unrelated").mkdir()
    (work / "unrelated" / "notes.txt").write_text("keep me")
    monkeypatch.chdir(work)
    return work


def snapshot(root: Path) -> dict[str, bytes | None]:
    """Every file (its bytes) and folder (None) under ``root``."""
    return {str(p.relative_to(root)): None if p.is_dir() else p.read_bytes() for p in sorted(root.rglob("*"))}


def refused(argv: list[str], capsys) -> str:
    """``main(argv)`` exits 2 with one ``error:`` line on stderr and nothing on stdout; the line."""
    code = main(argv)
    captured = capsys.readouterr()
    assert code == 2, captured
    assert captured.err.startswith("error: ") and captured.err.count("\n") == 1, captured.err
    assert captured.out == "", captured.out
    return captured.err


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "lifelong_evo", *args]


ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def _wait_for(condition, process: subprocess.Popen) -> None:
    """Poll until ``condition()`` holds; fails if ``process`` ends first."""
    deadline = time.monotonic() + 120
    while not condition():
        assert process.poll() is None, "the run ended before the test could catch it"
        assert time.monotonic() < deadline, "the run never got there"
        time.sleep(0.02)


def _holds_lock_and_checkpoint(run: Path, pid: int) -> bool:
    try:
        holder = json.loads((run / LOCK).read_text() or "{}")
    except (OSError, ValueError):
        return False
    return holder.get("pid") == pid and any((run / "checkpoints").glob("*.pt"))


# ----------------------------------------------------------------------------------------- run names

VERBS = {"run": RUN, "sweep": ["sweep", "--together", *SIZE], "sweep --dry-run": ["sweep", "--dry-run", *SIZE]}
NAMES = {"dot": ".", "dotdot": "..", "nested": "a/b", "parent": "../x", "absolute": None, "empty": "",
         "backslash": "a\\b"}
"""None: the absolute path of the unrelated folder."""


@pytest.mark.parametrize("verb", VERBS)
@pytest.mark.parametrize("name", NAMES)
def test_a_name_is_one_folder_name_and_nothing_outside_it_is_touched(work, verb, name, capsys):
    """``--name . --overwrite`` deleted all of runs/, ``--out $PWD/runs --name .. --overwrite`` the
    working directory, an absolute --name any folder; a/b and ../x escaped --out."""
    given = NAMES[name] if NAMES[name] is not None else str(work / "unrelated")
    before = snapshot(work.parent)
    err = refused([*VERBS[verb], "--out", str(work / "runs"), "--name", given, "--overwrite"], capsys)
    assert f"--name {given!r} is not one folder name" in err
    assert snapshot(work.parent) == before


def test_a_default_or_trial_name_that_is_no_folder_name_is_refused(work, monkeypatch, capsys):
    """A name made from the settings (an optimiser registered as ``my/algo``) obeys the same rule."""
    monkeypatch.setitem(REGISTRY, "my/algo", REGISTRY["neat"])
    before = snapshot(work.parent)
    assert "the run name from --algo, --schedule, --reg and --seed 'my/algo-red-green-red-reg0-seed42' is not " \
        "one folder name" in refused([*RUN, "--algo", "my/algo"], capsys)
    assert "the trial name 'my/algo-red-green-red-reg0-seed42' is not one folder name" in \
        refused(["sweep", "--dry-run", *SIZE, "--algo", "my/algo"], capsys)
    assert snapshot(work.parent) == before


def test_a_sweep_files_name_is_checked_too(work, capsys):
    sweep_file = work / "grid.toml"
    sweep_file.write_text('name = "../escaped"\n[grid]\nseed = [1, 2]\n')
    before = snapshot(work.parent)
    assert "name in grid.toml '../escaped' is not one folder name" in \
        refused(["sweep", "--dry-run", "--config", "grid.toml", *SIZE], capsys)
    assert snapshot(work.parent) == before


@pytest.mark.parametrize("argv, message", [
    ([*RUN, "--name", "x" * 300], "is 300 bytes long, longer than a folder name may be (255 bytes): give a shorter one"),
    ([*RUN, "--out", "y" * 300], "has a folder name of 300 bytes, longer than a folder name may be (255 bytes)"),
    (["sweep", "--dry-run", *SIZE, "--out", "y" * 300], "has a folder name of 300 bytes"),
    (["sweep", "--together", *SIZE, "--out", "unrelated/notes.txt"], "unrelated/notes.txt is a file: choose another"),
    ([*RUN, "--out", "unrelated/notes.txt", "--resume"], "unrelated/notes.txt is a file: choose another --out"),
    ([*RUN, "--out", "unrelated/notes.txt/deeper"], "unrelated/notes.txt is a file: choose another --out"),
])
def test_a_folder_no_file_system_takes_is_one_line(work, argv, message, capsys):
    """Found by the command-line fuzz test: these were tracebacks (OSError) after the checks."""
    before = snapshot(work.parent)
    assert message in refused(argv, capsys)
    assert snapshot(work.parent) == before


@pytest.mark.parametrize("verb", ["plot", "score", "compare", "view", "replay"])
def test_a_path_no_file_system_takes_is_one_line_for_every_verb(work, verb, capsys):
    before = snapshot(work.parent)
    assert "File name too long: give another path" in refused([verb, "y" * 300], capsys)
    assert snapshot(work.parent) == before


def test_a_sweep_folder_that_cannot_be_written_is_one_line(work, monkeypatch, capsys):
    """A read-only --out (root, who runs the tests here, can write anywhere: the refusal is played)."""
    from lifelong_evo.commands import sweep

    def read_only(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(sweep, "write_sweep_json", read_only)
    before = snapshot(work.parent)
    assert main(["sweep", "--together", *SIZE, "--name", "s"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: cannot write the sweep's folder ") and err.count("\n") == 1, err
    assert snapshot(work.parent) == before


def test_a_sweep_does_not_write_into_a_folder_of_someone_elses(work, capsys):
    """``sweep --together --name mine`` replaced the sweep.json and comparison.md a user kept there."""
    mine = work / "runs" / "mine"
    mine.mkdir()
    (mine / "comparison.md").write_text("my notes")
    before = snapshot(work.parent)
    for verb in (["--together"], ["--dry-run"]):
        assert "is not a sweep's folder (it has no sweep.json a sweep wrote) but holds comparison.md" in \
            refused(["sweep", *verb, *SIZE, "--name", "mine"], capsys)
    assert snapshot(work.parent) == before
    # a sweep's own folder is continued (the sweep's files rewritten, its finished trial skipped)
    assert main(["sweep", "--together", *SIZE, "--name", "ours"]) == 0
    assert main(["sweep", "--together", *SIZE, "--name", "ours"]) == 0
    assert "skipped" in capsys.readouterr().out
    # its sweep.json damaged: named as such, not as someone else's folder, and nothing touched
    (work / "runs" / "ours" / "sweep.json").write_bytes(b'{"name": "ours", "gr')
    before = snapshot(work.parent)
    said = refused(["sweep", "--together", *SIZE, "--name", "ours"], capsys)
    assert "sweep.json is damaged (not UTF-8 JSON)" in said and "restore the file from a copy" in said, said
    assert snapshot(work.parent) == before


@pytest.mark.parametrize("verb", ["--together", "--dry-run"])
@pytest.mark.parametrize("where", [["--name", "first"], ["--out", "runs/first", "--name", "grid"]],
                         ids=["a-run-directory", "inside-one"])
def test_a_sweep_does_not_write_into_a_run_directory(work, verb, where, capsys):
    """``sweep --name A`` with runs/A a run wrote its files and trial folders into the run, which
    the run's --overwrite would then delete: refused before anything is written, as is a sweep
    under --out inside a run."""
    before = snapshot(work.parent)
    err = refused(["sweep", verb, *SIZE, *where], capsys)
    if "--out" in where:
        assert f"--out {work / 'runs/first'} is inside run directory {work / 'runs/first'}, whose --overwrite " \
            "would delete the sweep too: choose another --out" in err, err
    else:
        assert f"{work / 'runs/first'} is a run directory, not a sweep's folder" in err, err
        assert "choose another --name or --out" in err, err
    assert snapshot(work.parent) == before


@pytest.mark.parametrize("flags", [[], ["--overwrite"], ["--resume"]], ids=["new", "overwrite", "resume"])
def test_a_run_does_not_write_into_a_sweeps_folder_or_a_run(work, flags, capsys):
    """``--name S`` for a sweep's folder S was "already exists: pass --resume ... --overwrite",
    then "not written by lifelong-evo: delete it yourself": it is a sweep's folder, named so. A run
    under --out inside another run would go with that run's --overwrite."""
    sweep = work / "runs" / "grid"
    shutil.copytree(work / "runs" / "second", sweep / "trial")
    (sweep / "sweep.json").write_text(json.dumps({"name": "grid", "grid": {}, "trials": []}))
    before = snapshot(work.parent)
    assert f"{Path('runs/grid')} is a sweep's folder (it holds sweep.json), not a run directory: its trials are " \
        "the run directories inside it; choose another --name or --out" in refused([*RUN, "--name", "grid", *flags],
                                                                                    capsys)
    if "--resume" not in flags:
        assert f"--out {Path('runs/first')} is inside run directory {work / 'runs/first'}, whose --overwrite " \
            "would delete this run too: choose another --out" in \
            refused([*RUN, "--out", "runs/first", "--name", "inner", *flags], capsys)
    assert snapshot(work.parent) == before


# ----------------------------------------------------------------------------------------- --overwrite

def test_overwrite_refuses_a_folder_lifelong_evo_did_not_write(work, capsys):
    mine = work / "runs" / "mine"
    mine.mkdir()
    (mine / "data.txt").write_text("precious")
    before = snapshot(work.parent)
    err = refused([*RUN, "--name", "mine", "--overwrite"], capsys)
    assert f"{Path('runs/mine')} was not written by lifelong-evo (no {MARKER} marker)" in err
    assert "delete it yourself or choose another --name" in err
    # a sweep's --overwrite restarts trials: the same rule for each trial directory, before anything is written
    (work / "runs" / "grid" / "seed1").mkdir(parents=True)
    (work / "runs" / "grid" / "seed1" / "data.txt").write_text("precious")
    before = snapshot(work.parent)
    err = refused(["sweep", "--together", *SIZE, "--seed", "1,2", "--name", "grid", "--overwrite"], capsys)
    assert f"{work / 'runs/grid/seed1'} was not written by lifelong-evo" in err
    assert snapshot(work.parent) == before


def test_overwrite_refuses_a_run_written_before_the_marker(work, capsys):
    old = work / "runs" / "first"
    (old / MARKER).unlink()
    (old / LOCK).unlink()
    before = snapshot(work.parent)
    err = refused([*RUN, "--name", "first", "--overwrite"], capsys)
    assert "was written before lifelong-evo marked its run directories" in err
    assert snapshot(work.parent) == before


def test_overwrite_does_not_follow_a_link_out_of_out(work, capsys):
    (work / "runs" / "link").symlink_to(work / "runs" / "first")
    before = snapshot(work.parent)
    assert "is a symbolic link" in refused([*RUN, "--name", "link", "--overwrite"], capsys)
    assert snapshot(work.parent) == before


def test_overwrite_starts_a_run_of_its_own_again_keeping_its_lock_file(work, capsys):
    run = work / "runs" / "first"
    (run / "recording.rrd").write_text("from the earlier run")
    lock_file = (run / LOCK).stat().st_ino
    assert main([*RUN, "--name", "first", "--overwrite", "--seed", "7"]) == 0
    assert json.loads((run / "config.json").read_text())["seed"] == 7
    assert not (run / "recording.rrd").exists()
    assert json.loads((run / MARKER).read_text())["written_by"] == "lifelong-evo"
    # the same lock file throughout: there is no moment without the lock
    assert (run / LOCK).stat().st_ino == lock_file
    assert (work / "runs" / "second").is_dir() and (work / "unrelated" / "notes.txt").read_text() == "keep me"


def test_resume_and_overwrite_together_are_refused(work, capsys):
    before = snapshot(work.parent)
    assert "--resume continues a run directory and --overwrite deletes it" in \
        refused([*RUN, "--name", "first", "--resume", "--overwrite"], capsys)
    assert snapshot(work.parent) == before


SAME_RUN = {"as-named": "runs/first", "dotted": "./runs/first/", "through-parent": "runs/../runs/first",
            "absolute": None, "link": "link-to-first"}
"""Spellings of runs/first for --start-from (None: its absolute path)."""


@pytest.mark.parametrize("out", ["runs", "absolute"])
@pytest.mark.parametrize("source", SAME_RUN)
def test_overwrite_never_deletes_the_run_it_starts_from(work, source, out, capsys):
    """``--start-from runs/A --name A --overwrite`` emptied A, then crashed reading A's controllers
    (KeyError, exit 1): every file of the run was gone. Refused, however the two paths are spelt."""
    (work / "link-to-first").symlink_to(work / "runs" / "first")
    given = SAME_RUN[source] or str(work / "runs" / "first")
    before = snapshot(work.parent)
    out_folder = str(work / "runs") if out == "absolute" else "runs"
    for overwrite in (["--overwrite"], []):
        err = refused([*RUN, "--reg", "1", "--start-from", given, "--out", out_folder, "--name", "first", *overwrite],
                      capsys)
        assert f"--start-from {Path(given)} is the run directory this run writes" in err, err
        assert "cannot take over its own first task" in err and "give this run another --name" in err, err
        assert snapshot(work.parent) == before


def test_overwrite_never_deletes_a_run_inside_it_that_it_starts_from(work, capsys):
    """A run copied into another one's directory goes with that run's --overwrite."""
    shutil.copytree(work / "runs" / "second", work / "runs" / "first" / "inner")
    before = snapshot(work.parent)
    err = refused([*RUN, "--reg", "1", "--start-from", "runs/first/inner", "--name", "first", "--overwrite"], capsys)
    assert f"--start-from {Path('runs/first/inner')} lies inside the run directory this run writes " \
        f"({Path('runs/first')}), which --overwrite would empty before it is read: give this run another --name" in err
    assert snapshot(work.parent) == before


def test_a_sweep_trial_never_starts_from_its_own_directory(work, capsys):
    """A trial reached through a link among the first-task sources of ``--share-first-task``
    (``--first-task-from``) is not a source of itself: it runs its first task, its own run intact
    until its ``--overwrite`` deletes it as asked."""
    trial = work / "runs" / "grid" / "first"
    trial.parent.mkdir()
    shutil.move(work / "runs" / "first", trial)
    (work / "link-to-trial").symlink_to(trial)
    values = {**RunDir(trial).read_config().to_dict(), "reg": 1.0}
    result = run_trial(values, str(trial), overwrite=True, first_task_sources=[str(work / "link-to-trial")])
    assert result["status"] == "done" and result["first_task_from"] == "", result
    assert json.loads((trial / "config.json").read_text())["reg"] == 1.0


# --------------------------------------------------------------------------------- one writer per run

@pytest.mark.parametrize("flags", [[], ["--resume"], ["--resume", "--record"], ["--overwrite"],
                                   ["--overwrite", "--seed", "7", "--record"]],
                         ids=["run", "resume", "resume-recording", "overwrite", "overwrite-other-seed"])
def test_a_locked_run_directory_is_refused_naming_its_holder(work, flags, capsys):
    """Nothing of the run that holds the lock is deleted or changed, its recording included."""
    run = RunDir(work / "runs" / "first")
    with run.lock():
        before = snapshot(work.parent)
        code = main([*RUN, "--name", "first", *flags])
        captured = capsys.readouterr()
        err = captured.err
        assert code == 2 and err.count("\n") == 1 and captured.out == "", captured
        assert f"error: run directory {Path('runs/first')} is in use by {HOLDER}: wait for it to end" in err
        assert snapshot(work.parent) == before
    assert run.in_use_by() is None and (run.path / LOCK).read_text() == ""


def test_score_refuses_a_locked_run_before_scoring_any(work, capsys):
    """``score runs/`` with one run in use scores none of them (nothing half-made)."""
    with RunDir(work / "runs" / "second").lock():
        before = snapshot(work.parent)
        err = refused(["score", "runs"], capsys)
        assert f"is in use by {HOLDER}: wait for it to end (or stop it), then score it" in err
        assert snapshot(work.parent) == before


@pytest.mark.parametrize("overwrite", [False, True], ids=["resume", "overwrite"])
def test_a_sweep_trial_takes_the_lock_too(work, overwrite, capsys):
    """Ray runs ``run_trial`` in its workers: on a locked directory it fails in one line and
    writes nothing (the recording included); the sweep itself refuses before it writes anything."""
    config = RunDir(work / "runs" / "first").read_config()
    trial = RunDir(work / "runs" / "grid" / config.default_name())  # a grid without axes names it so
    shutil.copytree(work / "runs" / "first", trial.path)
    trial.summary.unlink()  # unfinished: the sweep resumes it
    values = {**config.to_dict(), "record": True}
    with trial.lock():
        before = snapshot(work.parent)
        result = run_trial(values, str(trial.path), overwrite=overwrite)
        assert result["status"] == "failed" and f"is in use by {HOLDER}" in result["error"], result
        code = main(["sweep", "--together", *SIZE, "--name", "grid", *(["--overwrite"] if overwrite else [])])
        err = capsys.readouterr().err
        assert code == 2 and err == f"error: run directory {trial.path} is in use by {HOLDER}: wait for it to " \
            "end (or stop it), or choose another --name\n"
        assert snapshot(work.parent) == before


def test_a_run_that_fails_after_taking_its_lock_lets_go_of_it(work, capsys):
    run = RunDir(work / "runs" / "first")
    latest = run.checkpoint_files()[-1]
    latest.write_bytes(latest.read_bytes()[:-1000])  # --resume refuses it after taking the lock
    assert main([*RUN, "--name", "first", "--resume"]) == 2
    assert f"checkpoint {latest.relative_to(work)} is corrupt or truncated" in capsys.readouterr().err
    assert run.in_use_by() is None
    with run.lock():
        pass


def test_two_real_writers_exactly_one_proceeds(tmp_path):
    """A running run (stopped with SIGSTOP while it holds its lock, so it cannot finish meanwhile):
    --resume and --overwrite on it exit 2 naming it, and change nothing; then it finishes."""
    common = [*SIZE, "--quiet", "--generations", "4", "--checkpoint-every", "1", "--out", str(tmp_path),
              "--name", "busy"]
    first = subprocess.Popen(_cli(*common), env=ENV, cwd=ROOT, stdout=subprocess.DEVNULL)
    run = tmp_path / "busy"
    try:
        _wait_for(lambda: _holds_lock_and_checkpoint(run, first.pid), first)
        first.send_signal(signal.SIGSTOP)
        before = snapshot(tmp_path)
        for second in (["--resume"], ["--overwrite", "--seed", "7"]):
            done = subprocess.run(_cli(*common, *second), env=ENV, cwd=ROOT, capture_output=True, text=True)
            assert done.returncode == 2, done.stderr
            assert done.stderr.count("\n") == 1, done.stderr
            assert f"is in use by process {first.pid} on host {socket.gethostname()}" in done.stderr
            assert snapshot(tmp_path) == before
    finally:
        first.send_signal(signal.SIGCONT)
    assert first.wait(timeout=120) == 0
    assert json.loads((run / "config.json").read_text())["seed"] == 42
    assert len(json.loads((run / "summary.json").read_text())["current"]) == 3


def test_a_killed_run_resumes_without_touching_its_lock(tmp_path):
    """SIGKILL leaves the lock file naming the dead process; the kernel let go of the lock, so
    --resume goes on, to the metrics of an uninterrupted run."""
    common = [*SIZE, "--quiet", "--generations", "4", "--checkpoint-every", "2", "--out", str(tmp_path)]
    subprocess.run(_cli(*common, "--name", "whole"), check=True, env=ENV, cwd=ROOT)
    killed = subprocess.Popen(_cli(*common, "--name", "killed"), env=ENV, cwd=ROOT)
    run = tmp_path / "killed"
    _wait_for(lambda: _holds_lock_and_checkpoint(run, killed.pid), killed)
    killed.send_signal(signal.SIGKILL)
    assert killed.wait() == -signal.SIGKILL
    assert json.loads((run / LOCK).read_text())["pid"] == killed.pid  # left behind by the dead process
    subprocess.run(_cli("--resume", "--out", str(tmp_path), "--name", "killed", "--quiet", "--no-record"),
                   check=True, env=ENV, cwd=ROOT)
    assert (run / "metrics.csv").read_text() == (tmp_path / "whole" / "metrics.csv").read_text()
    assert (run / LOCK).read_text() == ""
