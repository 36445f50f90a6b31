"""Locking a run directory: one process writes a run directory at a time.

``RunLock`` takes the run directory's ``LOCK`` file with ``fcntl.flock`` at once or refuses with
``RunDirInUseError`` naming the holder (its PID and host, which the file holds while locked);
``held_by`` asks who holds it without taking it. The kernel releases the lock when its process
ends, however it ends, so a lock left behind by a killed run never blocks a resume.
"""
from __future__ import annotations

import fcntl
import json
import os
import socket
from pathlib import Path

from .errors import RunDirError

LOCK = ".lock"
"""The file in every run directory that the process writing the run holds locked (``RunLock``)."""


class RunDirInUseError(RunDirError):
    """A run directory whose lock another process holds."""

    def __init__(self, path: Path, holder: str, fix: str = "or choose another --name"):
        super().__init__(f"run directory {path} is in use by {holder}: wait for it to end (or stop it), {fix}")


class RunLock:
    """The lock of one run directory (its ``LOCK`` file, ``fcntl.flock``), taken at once or refused
    with RunDirInUseError naming the process that holds it; then the file holds this process's
    PID and host. The kernel releases it when the process ends, however it ends (SIGKILL too),
    so a lock left behind never blocks a resume. Release it with ``release`` or a ``with`` block."""

    def __init__(self, path: Path):
        self.path = path
        self._fd: int | None = None
        lock_file = path / LOCK
        try:
            self._fd = os.open(lock_file, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as error:
            raise RunDirError(f"cannot lock run directory {path}: {error.strerror} ({lock_file}): "
                              "choose another --out or --name") from None
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as error:
            os.close(self._fd)
            self._fd = None
            if isinstance(error, BlockingIOError):
                raise RunDirInUseError(path, lock_holder(lock_file)) from None
            raise RunDirError(f"cannot lock run directory {path}: {error.strerror}: "
                              "put --out on a file system that supports locks") from None
        os.ftruncate(self._fd, 0)
        os.write(self._fd, json.dumps({"pid": os.getpid(), "host": socket.gethostname()}).encode())

    def release(self) -> None:
        """Let go of the lock (again: nothing); the file is emptied first, as nobody holds it then."""
        if self._fd is not None:
            os.ftruncate(self._fd, 0)
            os.close(self._fd)  # closing releases the flock
            self._fd = None

    def __del__(self) -> None:
        # a run that fails between taking its lock and the loop's ``finally`` lets go of it with this object
        self.release()

    def __enter__(self) -> RunLock:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def lock_holder(lock_file: Path) -> str:
    """The process a run directory's lock file names: ``process 1234 on host node1``."""
    try:
        holder = json.loads(lock_file.read_text())
        return f"process {int(holder['pid'])} on host {holder['host']}"
    except (OSError, ValueError, TypeError, KeyError):  # taken a moment ago: its PID is not written yet
        return "another process"


def held_by(lock_file: Path) -> str | None:
    """The process that holds ``lock_file`` locked (``lock_holder``), or None: nobody holds it, or
    there is no such file (nobody has locked it)."""
    try:
        fd = os.open(lock_file, os.O_RDONLY)
    except OSError:  # no lock file: nobody has locked it
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return lock_holder(lock_file)
    finally:
        os.close(fd)
    return None
