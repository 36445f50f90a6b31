"""Process-wide CPU settings for fast runs: torch threads and the C allocator's reuse of memory."""
from __future__ import annotations

import ctypes
import ctypes.util

import torch

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 << 20
"""Blocks below this come from the reusable heap, not from fresh pages (glibc's maximum)."""
TRIM_THRESHOLD_BYTES = 1 << 30
"""Free heap memory kept for reuse rather than returned to the system."""


def configure_cpu(threads: int) -> None:
    """Set torch's thread count and keep freed memory for reuse (see ``reuse_freed_memory``)."""
    torch.set_num_threads(threads)
    reuse_freed_memory()


def reuse_freed_memory() -> bool:
    """Ask glibc to serve tensor-sized blocks from its heap and keep freed memory there.

    An eager step allocates and frees hundreds of tensors of about a megabyte. By default glibc
    maps each such block afresh and the kernel faults its pages in one at a time: on a 2-vCPU VM
    that was about half of an eager step at 3000 environments (850 page faults for a 7-operation
    expression). Returns False where the C library has no ``mallopt`` (not glibc); nothing changes.
    """
    name = ctypes.util.find_library("c")
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError, TypeError):
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
