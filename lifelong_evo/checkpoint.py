"""Checkpoints: atomic, authenticated, loaded without running code from untrusted files.

A checkpoint is a ``torch.save`` file read back with ``torch.load(weights_only=True)``, which
only rebuilds tensors and plain containers. NEAT's own state (neat-python genomes, species,
reproduction counters) has no such form and travels as pickle bytes inside it; those bytes are
unpickled only after the whole file has passed an HMAC-SHA256 check with this machine's
checkpoint key, so a checkpoint made elsewhere (or edited) is refused before anything in it
runs. The key lives in ``$LIFELONG_EVO_KEY`` or ``~/.config/lifelong-evo/checkpoint.key``
(created on first use); copy it to resume a run on another machine.
"""
from __future__ import annotations

import hashlib
import hmac
import io
import os
import secrets
from pathlib import Path
from typing import Any

import torch

_TAG_BYTES = 32


class CheckpointError(RuntimeError):
    pass


def _key() -> bytes:
    from_env = os.environ.get("LIFELONG_EVO_KEY")
    if from_env:
        return from_env.encode()
    path = Path(os.environ.get("XDG_CONFIG_HOME", Path.home() / ".config")) / "lifelong-evo" / "checkpoint.key"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w") as handle:
            handle.write(secrets.token_hex(32))
    return path.read_text().strip().encode()


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
    atomic_write_bytes(path, hmac.new(_key(), body, hashlib.sha256).digest() + body)


def load(path: Path) -> dict[str, Any]:
    try:
        data = Path(path).read_bytes()
    except OSError as error:
        raise CheckpointError(f"cannot read checkpoint {path}: {error.strerror}") from None
    tag, body = data[:_TAG_BYTES], data[_TAG_BYTES:]
    if len(data) <= _TAG_BYTES or not hmac.compare_digest(tag, hmac.new(_key(), body, hashlib.sha256).digest()):
        raise CheckpointError(
            f"checkpoint {path} is corrupt or was not written by this machine's runs (HMAC mismatch): "
            "delete it to resume from an earlier one, or set LIFELONG_EVO_KEY to the key of the machine that wrote it")
    try:
        return torch.load(io.BytesIO(body), weights_only=True)
    except Exception as error:  # an authenticated file that still fails to load is a bug, not an attack
        raise CheckpointError(f"checkpoint {path} could not be read: {error}") from None
