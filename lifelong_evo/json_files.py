"""The JSON files of a run directory (config.json, summary.json, controllers, the marker),
written atomically and read back as one ``RunDirError`` line where they are missing or damaged
(``NaN`` and ``Infinity``, which Python's json reads and JSON has not, are damage).
What they must hold is checked by ``run_files``."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from .checkpoint import atomic_write_bytes
from .errors import RESTORE, RunDirError


def write_json(path: Path, value: Any) -> None:
    atomic_write_bytes(path, (json.dumps(value, indent=2, default=_jsonable) + "\n").encode())


def _jsonable(value):
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


class _NotJSON(ValueError):
    """Python's NaN, Infinity or -Infinity, which its json module reads and JSON has not."""


def _refuse_constant(name: str) -> Any:
    raise _NotJSON(name)


def read_json(path: Path) -> Any:
    try:
        return json.loads(Path(path).read_text(), parse_constant=_refuse_constant)
    except _NotJSON as error:  # no figure or weight of a run is one: a damaged file
        raise RunDirError(f"{path} holds {error}, which is no number of JSON's: {RESTORE}") from None
    except (FileNotFoundError, NotADirectoryError):
        raise RunDirError(f"{path} does not exist: is this a run directory?") from None
    except UnicodeDecodeError as error:  # JSON is UTF-8 text: a damaged file
        raise RunDirError(f"{path} is not UTF-8 text (byte {error.start} cannot be decoded): {RESTORE}") from None
    except OSError as error:
        raise RunDirError(f"cannot read {path}: {error.strerror or error}") from None
    except json.JSONDecodeError as error:
        raise RunDirError(f"{path} is not valid JSON ({error}): {RESTORE}") from None
