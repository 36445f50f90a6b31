"""SIGTERM (``kill``, a batch scheduler's time limit) takes Ctrl-C's way out: the run keeps its
checkpoints and prints the command that continues it, a sweep keeps its trials' checkpoints and
says to run the same command again; the exit status is 143 (Ctrl-C's is 130). Each command runs
as a real process, killed while it runs."""
from __future__ import annotations

import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lifelong_evo.rundir import RunDir

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ["--preset", "smoke", "--no-record", "--env", "duration=60"]


def _start(*argv: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "lifelong_evo", *argv], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})


def _terminate_after_a_checkpoint(process: subprocess.Popen, pattern: Path) -> tuple[str, str]:
    """SIGTERM once a run directory matching ``pattern`` holds a checkpoint; the process's output."""
    deadline = time.monotonic() + 300
    while not any(RunDir(path).checkpoint_files() for path in pattern.parent.glob(pattern.name)):
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline, "no checkpoint was written"
        time.sleep(0.05)
    process.send_signal(signal.SIGTERM)
    return process.communicate(timeout=120)


def test_sigterm_keeps_a_run_and_prints_how_to_continue(tmp_path):
    out = tmp_path / "runs"
    run = _start(*SMOKE, "--generations", "10", "--progress", "off", "--out", str(out), "--name", "long")
    _, err = _terminate_after_a_checkpoint(run, out / "long")
    assert run.returncode == 143, err
    assert err.endswith(f"\ninterrupted: {out / 'long'} keeps everything up to its last checkpoint; continue with\n"
                        f"  python -m lifelong_evo --resume --name long --out {out}\n"), err
    resume = shlex.split(err.splitlines()[-1])
    assert resume[:3] == ["python", "-m", "lifelong_evo"]
    done = subprocess.run([sys.executable, *resume[1:], "--quiet"], cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)
    assert done.returncode == 0, done.stderr
    assert len(RunDir(out / "long").read_summary()["current"]) == 3, "the resumed run finished every task"


@pytest.mark.parametrize("where", [["--together", "--eval-threads", "1"], []], ids=["together", "ray"])
def test_sigterm_keeps_a_sweeps_checkpoints_and_says_to_run_it_again(tmp_path, where):
    """On Ray too, whose start installs a SIGTERM handler of its own that killed the sweep without a word."""
    out = tmp_path / "sweeps"
    command = ["sweep", *SMOKE, "--seed", "1,2", "--generations", "10", *where, "--out", str(out), "--name", "s"]
    sweep = _start(*command)
    _, err = _terminate_after_a_checkpoint(sweep, out / "s" / "*")
    assert sweep.returncode == 143, err
    assert err.endswith(f"\ninterrupted: finished trials and checkpoints are kept in {out / 's'}; run the same "
                        "command again to continue\n"), err
    again = subprocess.run([sys.executable, "-m", "lifelong_evo", *command, "--dry-run"], cwd=ROOT,
                           capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)
    assert again.returncode == 0 and "resume  " in again.stdout, again
