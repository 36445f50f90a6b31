"""Provenance: what a run records of the code and the machine that made its numbers.

``library_versions`` (config.json's ``versions``: Python and the libraries, and the git commit of
the toolkit's code, ``source_commit``) and ``machine`` (summary.json's machines: the CPU, the vector
instructions torch's kernels use, the usable CPUs, the GPU). Nothing here reads or writes a run
directory.
"""
from __future__ import annotations

import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any


def package_version(package: str) -> str:
    """An installed distribution's version, or ``not installed``."""
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "not installed"


def library_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for package in ("torch", "neat-python", "evotorch", "numpy", "gymnasium", "rerun-sdk", "lifelong-evo"):
        versions[package] = package_version(package)
    versions["lifelong-evo-commit"] = source_commit()
    return versions


CODE_FOLDERS = ("lifelong_evo", "algorithms", "envs")
"""The toolkit's packages, whose source a run's commit names."""


def source_commit(package: Path = Path(__file__).resolve().parent) -> str:
    """The git commit of the code this process imports: ``HEAD`` of the checkout that tracks
    ``package``, with `` + local changes`` when a tracked file of the toolkit's packages differs from
    it; ``unknown`` for an installed copy (git does not track it: a version number is all there is),
    or without git. Two runs of one version number can differ in code between commits; this tells."""
    def git(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(["git", "-C", str(package), *args], capture_output=True, text=True, timeout=30)
    try:
        tracked = git("ls-files", "--error-unmatch", "__init__.py")
        head = git("rev-parse", "HEAD")
        if tracked.returncode or head.returncode:
            return "unknown"
        # ":/" names a path from the checkout's top, wherever ``package`` lies in it
        changed = git("diff", "--quiet", "HEAD", "--", *(f":/{folder}" for folder in CODE_FOLDERS))
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"
    return head.stdout.strip() + (" + local changes" if changed.returncode else "")


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity where the system has one, else all)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def machine(device: str) -> dict[str, Any]:
    """The machine a process runs on, as far as it can change a run's numbers or its speed: the
    CPU's name (with its family and model where Linux gives them: a VM often names only the
    vendor's line), the widest vector instructions torch's kernels use on it (AVX2, AVX512, ...:
    torch's and the compiled code's rounding follows them), the CPUs this process may use, and
    the GPU when ``device`` is one."""
    import torch  # here, not above: reading and checking run directories needs no torch

    cpu = platform.processor() or platform.machine()
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()[:30]
        fields = {key.strip(): value.strip() for key, value in (line.split(":", 1) for line in lines if ":" in line)}
        if "model name" in fields:
            cpu = f"{fields['model name']} (family {fields.get('cpu family', '?')}, model {fields.get('model', '?')})"
    except OSError:  # not Linux
        pass
    described: dict[str, Any] = {"cpu": cpu, "vector_isa": torch.backends.cpu.get_cpu_capability(),
                                 "cpus": usable_cpus()}
    if device.startswith("cuda"):
        described["gpu"] = torch.cuda.get_device_name(torch.device(device))
    return described


ARITHMETIC_FIELDS = ("cpu", "vector_isa", "gpu")
"""The fields of ``machine``'s description that torch's native arithmetic follows (not ``cpus``:
the evaluation threads, a run setting, decide how the work is split)."""


def same_native_arithmetic(one: dict[str, Any], other: dict[str, Any]) -> bool:
    """Whether two machines (``machine``'s descriptions) compute a native-arithmetic run alike."""
    return all(one.get(name) == other.get(name) for name in ARITHMETIC_FIELDS)
