"""The error a user can fix: ``python -m lifelong_evo`` prints its message as one line,
``error: ...``, and exits with status 2.

Every such error of the lifelong tools derives from ``UserError``: a message that names what was
given and what would work. ``envs.ConfigError`` and ``algorithms.UnknownAlgorithmError`` are
user errors too, but the environment and the optimisers import nothing from ``lifelong_evo``, so
they keep their own base classes and the command line catches them beside ``UserError``.

Interruptions: Ctrl-C (SIGINT) raises ``KeyboardInterrupt``; ``terminating_as_interrupt`` makes
SIGTERM (``kill``, a batch scheduler's time limit) raise ``Terminated``, a ``KeyboardInterrupt``,
so that both take one way out: checkpoints kept, the line that says how to continue printed.
``interrupted_status`` is the exit status: 130 after Ctrl-C, 143 after SIGTERM (128 plus the
signal's number, what a shell reports for a process the signal killed).
"""
from __future__ import annotations

import argparse
import signal
import threading
from contextlib import contextmanager
from typing import Iterator


class UserError(Exception):
    """A mistake in what the user gave (a path, a flag, a run directory): one line that says what to do."""


class RunDirError(UserError):
    """A run directory, or one of its files, that is missing or not what the contract says
    (``lifelong_evo.rundir``, whose readers raise it; ``lifelong_evo.run_files`` checks the files)."""


RESTORE = "restore it from a copy of the run, or run the run again"
"""A RunDirError's way out for a damaged file: the toolkit wrote it, so only another copy can mend it."""


class Parser(argparse.ArgumentParser):
    """argparse with the command line's error contract: one line, ``error: ...``, and exit status 2."""

    def error(self, message: str):
        self.exit(2, f"error: {message} (see {self.prog} --help)\n")


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C raises ``KeyboardInterrupt``."""


_terminated = threading.Event()
"""Set when SIGTERM arrives: a library that catches the ``Terminated`` and raises a plain
``KeyboardInterrupt`` of its own (Ray's ``wait`` does) loses its class, not this."""


def _terminate(signum, frame):
    _terminated.set()
    raise Terminated


@contextmanager
def terminating_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM raises ``Terminated`` in the main thread (elsewhere the block
    runs as it is: only the main thread can handle signals); the previous handler afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _terminate)
    if previous is not _terminate:  # not a block nested in another: a fresh start
        _terminated.clear()
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def interrupted_status(interruption: KeyboardInterrupt) -> int:
    """The exit status after ``interruption``: 143 for SIGTERM, 130 for Ctrl-C."""
    terminated = isinstance(interruption, Terminated) or _terminated.is_set()
    return 128 + (signal.SIGTERM if terminated else signal.SIGINT)


def one_line(error: BaseException) -> str:
    """``error`` as one line: its class and the first line of its message (for a failed trial's report)."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return f"{type(error).__name__}: {lines[0] if lines else ''}".rstrip(": ")
