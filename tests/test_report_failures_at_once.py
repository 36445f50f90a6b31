"""``benchmarks/report_failures_at_once.py``, the pytest plugin of ``benchmarks/gpu_checks.sh``: a
failing test's report reaches the output even when the session is killed before its summary."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SESSION = '''
import os, signal, sys

def test_fails():
    print("error: a line on", "stderr".upper(), file=sys.stderr)  # not in the traceback's source lines
    assert 6 * 7 == 41, "the answer is off"

def test_then_the_session_is_killed():
    os.kill(os.getpid(), signal.SIGKILL)
'''


def _output(tmp_path: Path, *plugin: str) -> str:
    (tmp_path / "test_session.py").write_text(SESSION)
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-o", "addopts=",
                             "-p", "no:xdist", *plugin, str(tmp_path / "test_session.py")],
                            cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == -9  # killed: pytest never printed its summary
    return result.stdout


def test_a_failure_is_reported_before_the_session_is_killed(tmp_path):
    assert "the answer is off" not in _output(tmp_path)  # without the plugin the kill loses it
    reported = _output(tmp_path, "-p", "benchmarks.report_failures_at_once")
    assert re.search(r"FAILED \S*test_session\.py::test_fails \(call\)", reported) and "the answer is off" in reported
    assert "error: a line on STDERR" in reported
