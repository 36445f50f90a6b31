"""Everything that touches Ray, and the only module that imports it: starting or joining a cluster
(``check_cluster``: the address answers and accepts this machine's token, within seconds;
``check_token_file``), and running a list of jobs on it (``run_jobs``), with Ray's own messages
kept in a file. The sweep (``commands/sweep.py``) decides what the jobs are and records what they
return.

Token authentication (Ray >= 2.52; ``ray start`` turns it on where a token exists): where
RAY_AUTH_MODE is not set and this machine has a token (RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH or
~/.ray/auth_token), the sweep connects with it, as Ray itself does for ``--address auto``.
"""
from __future__ import annotations

import contextlib
import logging
import os
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from ..errors import UserError, one_line, terminating_as_interrupt
from ..provenance import usable_cpus

CONNECT_TIMEOUT_S = 5.0
"""How long the sweep waits for a cluster's address to answer before giving up."""
def _start_ray(address: str | None, given_address: str | None):
    """Ray for the jobs: the cluster at ``address`` (checked by ``check_cluster``; ``given_address``
    as the user wrote it), else a local one with one CPU per core; and whether this call started it."""
    import ray

    if ray.is_initialized():
        return ray, False
    _quiet_token_notice()
    quiet = {"log_to_driver": False, "logging_level": logging.WARNING}
    if address:
        import algorithms
        import envs
        import lifelong_evo

        modules = [str(Path(m.__file__).parent) for m in (lifelong_evo, algorithms, envs)]
        try:
            ray.init(address=address, runtime_env={"py_modules": modules, "excludes": ["__pycache__"]}, **quiet)
        except (ConnectionError, RuntimeError, ray.exceptions.RayError) as error:
            raise UserError(f"could not join the Ray cluster at {given_address}: {one_line(error)}") from None
    else:
        cores = usable_cpus()
        # "local": always a new instance, never a cluster that `ray start` left running on this machine
        ray.init(address="local", num_cpus=cores, include_dashboard=False, **quiet)
    return ray, True


RAY_LOG = "ray.log"
"""In the sweep directory: the messages Ray's driver would print (task retries, dead nodes' state dumps)."""


@contextlib.contextmanager
def _ray_messages_to(path: Path):
    """Ray's driver prints the cluster's error messages to stdout from a thread of its own, a whole
    state dump of every node that dies among them, whatever ``log_to_driver`` says; the sweep
    appends them to ``path`` instead and reports each trial's outcome itself."""
    from ray._private import worker

    original = worker.print_to_stdstream

    def to_file(data: dict[str, Any], ignore_prefix: bool) -> None:
        stamp = time.strftime("%Y-%m-%d %H:%M:%S")
        with open(path, "a") as log:  # opened per message: they are rare, and come from Ray's thread
            log.writelines(f"{stamp} ({data.get('pid', 'ray')}) {line}\n" for line in data.get("lines", []))

    worker.print_to_stdstream = to_file  # looked up by name on every message
    try:
        yield
    finally:
        worker.print_to_stdstream = original


@contextlib.contextmanager
def _native_stderr_silenced():
    """Ray's C++ client logs its retries to file descriptor 2; the sweep reports the outcome itself."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "wb") as sink:
            os.dup2(sink.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _quiet_token_notice() -> None:
    # Ray's INFO lines and the token notice are for Ray's users; the sweep says what it connected to
    logging.getLogger("ray._private.authentication.authentication_token_setup").setLevel(logging.ERROR)


def check_cluster(given: str) -> str:
    """The HOST:PORT of the cluster ``--address`` names, once it answers and accepts this
    machine's token; otherwise UserError with the fix, within seconds (Ray itself would retry
    for 20 s and end in a traceback). Turns token authentication on where a token is found."""
    from ray._private.authentication.authentication_token_setup import maybe_enable_token_auth_if_token_available
    from ray._private.services import canonicalize_bootstrap_address
    from ray._raylet import AuthenticationMode, AuthenticationTokenLoader, GcsClient, get_authentication_mode
    from ray.exceptions import AuthenticationError, RpcError

    _quiet_token_notice()
    start_hint = "start it with `ray start --head --port=6379` (docs/usage.md, On a cluster), or fix --address"
    try:
        address = canonicalize_bootstrap_address(given)
    except (ConnectionError, ValueError) as error:
        raise UserError(f"--address {given}: {one_line(error)}: {start_hint}") from None
    host, _, port = address.rpartition(":")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except (OSError, ValueError) as error:
        reason = getattr(error, "strerror", None) or str(error) or type(error).__name__
        raise UserError(f"no Ray cluster answers at {given} ({reason}): {start_hint}") from None
    # an explicit address never turns token authentication on in Ray, while `ray start` does
    maybe_enable_token_auth_if_token_available(warn_if_disabled=False)
    copy = ("copy the head node's ~/.ray/auth_token to ~/.ray/auth_token on this machine (or set RAY_AUTH_TOKEN "
            "to its contents)")
    has_token = AuthenticationTokenLoader.instance().has_token(ignore_auth_mode=True)
    token_mode = get_authentication_mode() == AuthenticationMode.TOKEN
    if token_mode and not has_token:  # Ray's client would exit the process on its first request
        raise UserError(f"RAY_AUTH_MODE is token and this machine has no Ray token: {copy}")
    try:
        with _native_stderr_silenced():
            GcsClient(address=address)
    except AuthenticationError:
        if not has_token:
            raise UserError(f"the Ray cluster at {given} requires its token and this machine has none: {copy}") from None
        if not token_mode:
            raise UserError(f"the Ray cluster at {given} requires its token and RAY_AUTH_MODE is "
                           f"{os.environ.get('RAY_AUTH_MODE')!r} here: unset RAY_AUTH_MODE or set it to token") from None
        raise UserError(f"the Ray cluster at {given} rejected this machine's token: {copy}") from None
    except RpcError as error:
        raise UserError(f"{given} does not answer as a Ray cluster ({one_line(error)}): {start_hint}") from None
    return address



def check_token_file() -> None:
    """RAY_AUTH_TOKEN_PATH names the file Ray reads its token from, whenever Ray starts or joins a
    cluster: one that is missing or empty is one line here, not Ray's traceback."""
    path = os.environ.get("RAY_AUTH_TOKEN_PATH")
    if not path:
        return
    fix = "copy the cluster's token there (docs/usage.md, On a cluster), or unset RAY_AUTH_TOKEN_PATH"
    try:
        token = Path(path).read_text().strip()
    except (OSError, UnicodeDecodeError) as error:
        raise UserError(f"RAY_AUTH_TOKEN_PATH is {path}, which cannot be read "
                        f"({getattr(error, 'strerror', None) or error}): {fix}") from None
    if not token:
        raise UserError(f"RAY_AUTH_TOKEN_PATH is {path}, which is empty: {fix}")



@dataclass
class Job:
    """One remote call: its name (for Ray's dashboard), the CPUs it reserves, its arguments."""

    name: str
    cpus: int
    args: tuple


def run_jobs(jobs: list[Job], function: Callable[..., dict[str, Any]], *, address: str | None,
             given_address: str | None, workers: int | None, gpus_per_job: float, retries: int, log: Path,
             on_result: Callable[[int, dict[str, Any] | None, str], None], on_wait: Callable[[int, int], None],
             wait_every_s: float) -> None:
    """Call ``function(*job.args)`` for every job on Ray (at most ``workers`` at once, submitted in
    order), ``on_result(index, result, "")`` as each returns, or ``on_result(index, None, error)``
    where its worker died; ``on_wait(running, queued)`` at least every ``wait_every_s`` in between.
    Ray's own messages go to ``log``. On Ctrl-C or SIGTERM the running jobs are cancelled (their
    workers killed) and KeyboardInterrupt is raised."""
    ray, started = _start_ray(address, given_address)
    in_flight: dict[Any, int] = {}
    messages = contextlib.ExitStack()
    try:
        messages.enter_context(_ray_messages_to(log))
        # ray.init installs a handler of its own that dies on SIGTERM: SIGTERM must take Ctrl-C's way
        messages.enter_context(terminating_as_interrupt())
        resources = ray.cluster_resources()
        if gpus_per_job > resources.get("GPU", 0):
            raise UserError(f"the Ray cluster has {resources.get('GPU', 0):g} GPU(s), a trial asks for "
                            f"{gpus_per_job:g}: drop --gpus-per-trial or add GPU nodes")
        widest = max(job.cpus for job in jobs)
        if widest > resources.get("CPU", 0):
            raise UserError(f"the Ray cluster has {resources.get('CPU', 0):g} CPUs, a trial asks for {widest} "
                            "(--threads times --eval-threads): lower them")
        where = f"the Ray cluster at {given_address}" if given_address else "a local Ray"
        logs = "/tmp/ray/session_latest/logs" + (" on each node" if given_address else "")
        print(f"running on {where}: {resources.get('CPU', 0):g} CPUs, {resources.get('GPU', 0):g} GPUs; "
              f"Ray's messages go to {log}, its logs to {logs}", flush=True)
        remote = ray.remote(function)
        limit = workers or len(jobs)
        queue = list(range(len(jobs)))
        last_line = time.monotonic()
        try:
            while queue or in_flight:
                while queue and len(in_flight) < limit:
                    index = queue.pop(0)
                    job = jobs[index]
                    ref = remote.options(num_cpus=job.cpus, num_gpus=gpus_per_job, max_retries=retries,
                                         name=f"trial:{job.name}").remote(*job.args)
                    in_flight[ref] = index
                ready, _ = ray.wait(list(in_flight), num_returns=1, timeout=1.0)
                for ref in ready:
                    index = in_flight.pop(ref)
                    try:
                        on_result(index, ray.get(ref), "")
                    except ray.exceptions.RayError as error:  # worker killed, out of memory, cancelled
                        on_result(index, None, one_line(error))
                    last_line = time.monotonic()
                if in_flight and time.monotonic() - last_line >= wait_every_s:
                    on_wait(len(in_flight), len(queue))
                    last_line = time.monotonic()
        except KeyboardInterrupt:
            for ref in in_flight:
                ray.cancel(ref, force=True)
            raise
    finally:
        messages.close()
        if started:
            ray.shutdown()
