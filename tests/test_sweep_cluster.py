"""``sweep --address`` against a real cluster started as the README says (``ray start --head``),
on 127.0.0.1 only: Ray's token authentication, which ``ray start`` turns on where a token exists,
is used without the user setting RAY_AUTH_MODE; a missing token, and an address where nothing
listens, are one line and exit 2 long before Ray's own 20 s of retries; Ray's log lines stay out
of the sweep's output. Each sweep runs as its own process, as a user would start it."""
from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

pytest.importorskip("ray")

ROOT = Path(__file__).resolve().parents[1]
RAY = str(Path(sys.executable).parent / "ray")
TRIAL = ["--algo", "neat", "--preset", "smoke", "--generations", "1", "--population", "10", "--env", "duration=20",
         "--no-record"]


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _env(home: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    # Ray maps 127.0.0.1 to the machine's outward address unless multi-node clusters are off:
    # keep the test's cluster on the loopback interface
    env.update(HOME=str(home), PYTHONPATH=str(ROOT), RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0")
    return env


def _sweep(env: dict[str, str], *args: str) -> tuple[subprocess.CompletedProcess, float]:
    started = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "lifelong_evo", "sweep", *args], env=env, cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    return done, time.monotonic() - started


def _startup_took(env: dict[str, str], tmp_path: Path) -> float:
    """Seconds a sweep takes to give up before it contacts anything (an address whose port is no
    number): the interpreter's start and the same imports as the sweeps timed here, under the same
    load, so that a busy machine does not pass for Ray's own retries."""
    done, took = _sweep(env, *TRIAL, "--address", "127.0.0.1:notaport", "--out", str(tmp_path / "never"))
    assert done.returncode == 2 and "notaport" in done.stderr, done.stderr
    return took


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A one-node cluster from `ray start --head` with a token in the (temporary) home folder, so
    that, as on a real machine where Ray has run before, `ray start` turns token auth on."""
    home = tmp_path_factory.mktemp("home")
    env = _env(home)
    subprocess.run([RAY, "get-auth-token", "--generate"], env=env, check=True, capture_output=True, timeout=120)
    port = _free_port()
    temp_dir = tempfile.mkdtemp(prefix="ray-", dir="/tmp")  # short: Ray's socket paths must fit 107 bytes
    log = home / "ray-start.log"
    with open(log, "w") as output:
        head = subprocess.Popen([RAY, "start", "--head", "--node-ip-address", "127.0.0.1", "--port", str(port),
                                 "--num-cpus", "1", "--include-dashboard", "false", "--disable-usage-stats",
                                 "--temp-dir", temp_dir, "--block"],
                                env=env, stdout=output, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while "Ray runtime started" not in log.read_text():
            if head.poll() is not None or time.monotonic() > deadline:
                pytest.fail("ray start --head did not start:\n" + log.read_text())
            time.sleep(0.2)
        assert "Token authentication is enabled" in log.read_text()
        yield f"127.0.0.1:{port}", env
    finally:
        head.terminate()  # `ray start --block` drains and stops its processes on SIGTERM
        try:
            head.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(head.pid, signal.SIGKILL)
            head.wait()
        shutil.rmtree(temp_dir, ignore_errors=True)


def test_sweep_uses_the_clusters_token(cluster, tmp_path):
    address, env = cluster
    done, _ = _sweep(env, *TRIAL, "--address", address, "--out", str(tmp_path), "--name", "on-cluster")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "[1/1] done   neat" in done.stdout
    assert (tmp_path / "on-cluster/neat-red-green-red-reg0-seed42/summary.json").is_file()
    printed = done.stdout + done.stderr
    assert "Traceback" not in printed and "INFO" not in printed and "[state-dump]" not in printed


def test_a_machine_without_the_token_is_told_how_to_get_it(cluster, tmp_path):
    address, env = cluster
    empty = tmp_path / "home"
    empty.mkdir()
    out = tmp_path / "sweeps"
    # Ray's own client would retry once a second, RAY_NUM_REDIS_GET_RETRIES times (20 by default):
    # made 120 here, so that a busy machine's slowness (seconds) cannot pass for them, nor hide them
    without_token = {**env, "HOME": str(empty), "RAY_NUM_REDIS_GET_RETRIES": "120"}
    done, took = _sweep(without_token, *TRIAL, "--address", address, "--out", str(out))
    assert done.returncode == 2 and not out.exists()
    assert done.stderr.startswith(f"error: the Ray cluster at {address} requires its token and this machine has "
                                  "none: copy the head node's ~/.ray/auth_token") and done.stderr.count("\n") == 1
    assert took - _startup_took(without_token, tmp_path) < 60, "the sweep went through Ray's own retries"
    done, _ = _sweep({**env, "HOME": str(empty), "RAY_AUTH_TOKEN": "not-the-token-of-this-cluster-0123456789"},
                     *TRIAL, "--address", address, "--out", str(tmp_path))
    assert done.returncode == 2 and "rejected this machine's token" in done.stderr and done.stderr.count("\n") == 1


def test_nothing_listening_is_one_line(tmp_path):
    port = _free_port()
    out = tmp_path / "sweeps"
    done, took = _sweep(_env(tmp_path), *TRIAL, "--address", f"127.0.0.1:{port}", "--out", str(out))
    assert done.returncode == 2
    assert done.stderr == (f"error: no Ray cluster answers at 127.0.0.1:{port} (Connection refused): start it "
                           "with `ray start --head --port=6379` (docs/usage.md, On a cluster), or fix --address\n")
    assert took - _startup_took(_env(tmp_path), tmp_path) < 30, \
        "Ray's own client waits 40 s or more for an address where nothing listens"
    assert not out.exists(), "the sweep wrote before it knew it could run"


@pytest.mark.parametrize("where", [[], ["--address", "127.0.0.1:6379"]])
def test_a_token_path_that_cannot_be_read_is_one_line(tmp_path, where):
    """RAY_AUTH_TOKEN_PATH naming a missing file was a traceback (from the local Ray's start, after
    the sweep directory was made); an empty one too."""
    out = tmp_path / "sweeps"
    empty = tmp_path / "empty-token"
    empty.write_text("\n")
    for path, why in ((tmp_path / "missing-token", "which cannot be read (No such file or directory)"),
                      (empty, "which is empty")):
        done, _ = _sweep({**_env(tmp_path), "RAY_AUTH_TOKEN_PATH": str(path)}, *TRIAL, *where, "--out", str(out))
        assert done.returncode == 2
        assert done.stderr == (f"error: RAY_AUTH_TOKEN_PATH is {path}, {why}: copy the cluster's token there "
                               "(docs/usage.md, On a cluster), or unset RAY_AUTH_TOKEN_PATH\n")
        assert not out.exists(), "the sweep wrote before it knew it could run"
