"""Checkpoints: written atomically, checked for damage, read without running code from the file.

A checkpoint file is the line ``HEADER``, the SHA-256 digest (32 bytes) of the rest, and a
``torch.save`` file of the payload, read back with ``torch.load(weights_only=True)``, which
rebuilds only tensors and plain containers. Every optimiser's state is of that form (NEAT's as
JSON text, see ``algorithms.neat.state``), so a checkpoint needs nothing from the machine that
wrote it: a run directory copied elsewhere resumes there. The digest is a checksum, not a
signature: torch does not check its own file for damage, and a flipped bit must not resume a
run with different numbers.

``load`` raises ``CheckpointError``, one line for the command line: for a file it cannot read,
for a checkpoint of the earlier signed format (an HMAC tag, then a torch file with NEAT's state
pickled: ``older_version_error``), and, as ``CorruptCheckpointError``, for a damaged or
truncated file.
"""
from __future__ import annotations

import hashlib
import io
import os
from pathlib import Path
from typing import Any

import torch

from .errors import UserError

HEADER = b"lifelong-evo checkpoint 2\n"
_DIGEST_BYTES = 32
_OLD_TAG_BYTES = 32  # the HMAC-SHA256 tag that preceded the torch file in the signed format
_ZIP_START = b"PK\x03\x04"  # how a torch.save file begins


class CheckpointError(UserError):
    """A checkpoint that cannot be resumed from."""


class CorruptCheckpointError(CheckpointError):
    """A checkpoint whose bytes are damaged or cut short."""


def older_version_error(path: Path) -> CheckpointError:
    return CheckpointError(
        f"checkpoint {path} was written by an older version of lifelong-evo (signed, with pickled NEAT state), "
        "which this version does not read: start the run again with --overwrite, or finish it with the older version")


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename: a kill leaves either
    the old file or the new one, never half of one. Missing folders are made: a run copied
    without its ``controllers/`` still resumes."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)


def save(path: Path, payload: dict[str, Any]) -> None:
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    body = buffer.getvalue()
    atomic_write_bytes(path, HEADER + hashlib.sha256(body).digest() + body)


def load(path: Path) -> dict[str, Any]:
    try:
        data = Path(path).read_bytes()
    except OSError as error:
        raise CheckpointError(f"cannot read checkpoint {path}: {error.strerror}") from None
    if not data.startswith(HEADER):
        if data[_OLD_TAG_BYTES:_OLD_TAG_BYTES + len(_ZIP_START)] == _ZIP_START:
            raise older_version_error(path)
        raise CorruptCheckpointError(f"checkpoint {path} is corrupt or truncated (it does not begin as a checkpoint)")
    digest, body = data[len(HEADER):len(HEADER) + _DIGEST_BYTES], data[len(HEADER) + _DIGEST_BYTES:]
    if hashlib.sha256(body).digest() != digest:
        raise CorruptCheckpointError(f"checkpoint {path} is corrupt or truncated (its checksum does not match)")
    try:
        payload = torch.load(io.BytesIO(body), weights_only=True)
    except Exception as error:  # intact, yet not loadable: torch's first line says why
        reason = (str(error).strip().splitlines() or [""])[0][:200]
        raise CheckpointError(f"checkpoint {path} is intact but torch {torch.__version__} cannot load it "
                              f"({type(error).__name__}: {reason})") from None
    if not isinstance(payload, dict):
        raise CheckpointError(f"checkpoint {path} holds a {type(payload).__name__}, not a checkpoint's dict")
    return payload
