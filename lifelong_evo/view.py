"""``python -m lifelong_evo view RUN [--web] [--port P] [--grpc-port G]``: open a recording in Rerun.

RUN is a run directory (its ``recording.rrd`` and any ``recording-resumed-*.rrd`` continuations,
which the viewer merges into one recording; ``replay-*.rrd`` files open with ``--replays``) or .rrd
files. The native viewer is spawned where a display exists (DISPLAY or WAYLAND_DISPLAY); with
``--web``, or without a display, the web viewer is served on 127.0.0.1 only (port ``--port``, gRPC
``--grpc-port``) and its address printed: open it in a browser (over ssh, forward both ports).
The command runs until the viewer closes or Ctrl-C.
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path
from urllib.parse import quote

from .cli import CliError

HOST = "127.0.0.1"


def recording_files(target: str | Path, replays: bool = False) -> list[Path]:
    """The .rrd files to open for RUN (a run directory or an .rrd file)."""
    path = Path(target)
    if path.is_file():
        if path.suffix != ".rrd":
            raise CliError(f"{path} is not an .rrd file: give a run directory or a recording.rrd")
        return [path]
    if not path.is_dir():
        raise CliError(f"{path} does not exist: give a run directory (runs/<name>) or an .rrd file")
    files = ([path / "recording.rrd"] if (path / "recording.rrd").is_file() else []) \
        + sorted(path.glob("recording-resumed-*.rrd"))
    if replays:
        files += sorted(path.glob("replay-*.rrd"))
    if not files:
        raise CliError(f"{path} has no recording.rrd: the run was made with --no-record (run it again without), "
                       f"or record fresh episodes with `python -m lifelong_evo replay {path}`")
    return files


def rerun_executable() -> str:
    """The viewer binary: the one rerun-sdk bundles (so that stopping ``view`` stops the viewer,
    which the ``rerun`` wrapper script would leave running), else ``rerun`` on the PATH."""
    import importlib.util

    if os.environ.get("RERUN_CLI_PATH"):
        return os.environ["RERUN_CLI_PATH"]
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin:
        bundled = Path(spec.origin).parent / ("rerun.exe" if sys.platform.startswith("win") else "rerun")
        if bundled.is_file() and sys.platform != "darwin":
            return str(bundled)
    beside = Path(sys.executable).parent / "rerun"
    found = str(beside) if beside.is_file() else shutil.which("rerun")
    if not found:
        raise CliError("the `rerun` viewer is not installed: pip install 'rerun-sdk>=0.41,<0.42'")
    return found


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def web_url(port: int, grpc_port: int) -> str:
    return f"http://{HOST}:{port}/?url={quote(f'rerun+http://{HOST}:{grpc_port}/proxy', safe='')}"


def build_command(files: list[Path], web: bool, port: int, grpc_port: int) -> tuple[list[str], str | None]:
    """The ``rerun`` command line, and the address to print for the web viewer (else None)."""
    executable = rerun_executable()
    if not web:
        return [executable, *map(str, files)], None
    return ([executable, "--web-viewer", "--bind", HOST, "--web-viewer-port", str(port), "--port", str(grpc_port),
             *map(str, files)], web_url(port, grpc_port))


def _stop(signum, frame):
    raise KeyboardInterrupt


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", metavar="RUN", help="run directory or .rrd file")
    parser.add_argument("--web", action="store_true",
                        help="serve the web viewer on 127.0.0.1 (the default where no display exists)")
    parser.add_argument("--port", type=int, default=9090, help="web viewer HTTP port (default: 9090)")
    parser.add_argument("--grpc-port", type=int, default=9876,
                        help="port the web viewer reads data from (default: 9876)")
    parser.add_argument("--replays", action="store_true", help="also open the run's replay-*.rrd recordings")


def main(args: argparse.Namespace) -> int:
    files = recording_files(args.run, args.replays)
    web = args.web or not has_display()
    command, url = build_command(files, web, args.port, args.grpc_port)
    print("opening " + ", ".join(map(str, files)))
    if url:
        print(f"web viewer: {url}  (serving on {HOST} only; Ctrl-C stops it)", flush=True)
    process = subprocess.Popen(command)
    signal.signal(signal.SIGTERM, _stop)  # so that `finally` stops the viewer on kill too
    try:
        return process.wait()
    except KeyboardInterrupt:
        return 0
    finally:
        if process.poll() is None:
            process.terminate()
            process.wait()
