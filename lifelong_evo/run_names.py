"""Run names: a run directory's name is one folder name inside ``--out``, checked before anything
is written (``check_run_name``, ``check_out_folder``); RunDirError, one ``error:`` line, otherwise.

Contract: a name that passes is not empty, ``.`` or ``..``, holds no ``/``, ``\\`` or NUL and is at
most ``NAME_MAX`` bytes, so the run directory it names always lies directly inside ``--out``.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from .errors import RunDirError


NAME_MAX = 255
"""The longest folder name, in bytes, that Linux's and macOS's file systems take."""


def _name_bytes(name: str) -> int:
    """The length of folder name ``name`` as the file system counts it (``NAME_MAX``)."""
    return len(os.fsencode(name))


def check_run_name(name: Any, what: str = "--name",
                   fix: str = "give a folder name, and --out for the folder it goes in") -> str:
    """``name`` if it is one folder name (not empty, ``.`` or ``..``, without ``/``, ``\\`` or NUL,
    at most ``NAME_MAX`` bytes), so that the run directory it names lies directly inside
    ``--out``; RunDirError otherwise."""
    if not isinstance(name, str) or name in ("", ".", "..") or any(c in name for c in "/\\\0"):
        raise RunDirError(f"{what} {name!r} is not one folder name (a run name is not empty, '.' or '..' "
                          f"and has no / or \\ in it): {fix}")
    if _name_bytes(name) > NAME_MAX:
        raise RunDirError(f"{what} {name[:40]!r}... is {_name_bytes(name)} bytes long, longer than a folder "
                          f"name may be ({NAME_MAX} bytes): give a shorter one")
    return name


def check_out_folder(out: str | Path) -> Path:
    """``--out`` as a path, if each folder name in it is one a file system takes (at most
    ``NAME_MAX`` bytes) and the nearest part of it that exists is a folder; RunDirError otherwise."""
    path = Path(out)
    too_long = [part for part in path.parts if _name_bytes(part) > NAME_MAX]
    if too_long:
        raise RunDirError(f"--out {str(out)[:40]!r}... has a folder name of {_name_bytes(too_long[0])} bytes, "
                          f"longer than a folder name may be ({NAME_MAX} bytes): choose another --out")
    existing = next((p for p in (path, *path.parents) if p.exists()), None)
    if existing is not None and not existing.is_dir():
        raise RunDirError(f"--out {str(out)!r} cannot be a folder: {existing} is a file: choose another --out")
    return path
