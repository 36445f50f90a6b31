"""``python -m lifelong_evo view RUN [--web] [--port P] [--grpc-port G]``: open a recording in Rerun.

RUN is a run directory (its ``recording.rrd`` and any ``recording-resumed-*.rrd`` continuations,
which the viewer merges into one recording; ``replay-*.rrd`` files open with ``--replays``) or .rrd
files. The native viewer is spawned where a display exists (DISPLAY or WAYLAND_DISPLAY); with
``--web``, or without a display, the web viewer is served on 127.0.0.1 only (port ``--port``, gRPC
``--grpc-port``) and its address printed: open it in a browser (over ssh, forward both ports).
The command runs until the viewer closes or Ctrl-C.

Contracts: every file is checked before the viewer starts: one that Rerun cannot read as a
recording (``rerun.chunk.RrdReader``) is a one-line error (exit 2); one that breaks off (a run
killed mid-write) opens where every message before the break reads, since the viewer reads what
is there. A web
viewer's ports are checked before anything is printed, and one in use is a one-line error (exit
2), never a stale viewer behind a fresh address. The viewer process dies with
``view``, even when ``view`` is killed (on Linux the kernel sends it SIGTERM when its parent dies;
elsewhere SIGTERM and Ctrl-C reach it through ``view``). Rerun's own log lines are kept out of the
terminal unless ``--verbose``; when the viewer fails, its last log line is the error.
"""
from __future__ import annotations

import argparse
import ctypes
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
from pathlib import Path
from urllib.parse import quote

from ..errors import UserError
from ..rundir import RunDir

HOST = "127.0.0.1"


CUT_SHORT = re.compile(r"Message payload \(start (\d+), length \d+\) exceeds file size")
"""How ``RrdReader`` reports a recording whose last message breaks off (rerun-sdk 0.41)."""
MESSAGE_HEADER = 16
"""The bytes before a message's payload in an .rrd file: its kind and its length, 8 bytes each."""


def _unreadable(path: Path) -> str | None:
    """Why ``RrdReader`` cannot read ``path`` as a recording, or None where it can."""
    import warnings

    from rerun.chunk import RrdReader

    try:
        with warnings.catch_warnings():  # a file without its footer is read by a scan, with a warning
            warnings.simplefilter("ignore")
            if not RrdReader(path).recordings():
                return "it holds no recording"
        return None
    except Exception as error:  # noqa: BLE001 - rerun raises RuntimeError and others; the reason is shown
        return str(error).split(": ", 1)[-1].splitlines()[0] if str(error) else type(error).__name__


def check_recording(path: Path) -> None:
    """Refuse ``path`` unless Rerun can read it as a recording: ``RrdReader`` reads it whole, or
    it reads every message before the one a killed run cut short (the viewer reads up to the break)."""
    reason = _unreadable(path)
    if reason is None:
        return
    cut = CUT_SHORT.search(reason)
    if cut is not None:
        with tempfile.TemporaryDirectory() as scratch:
            whole = Path(scratch) / "whole-messages.rrd"
            try:
                with open(path, "rb") as handle:
                    whole.write_bytes(handle.read(max(int(cut.group(1)) - MESSAGE_HEADER, 0)))
            except OSError as error:
                reason = error.strerror or str(error)
            else:
                if _unreadable(whole) is None:
                    return
    raise UserError(f"{path} is not a recording Rerun can read ({reason}): give a recording.rrd that a run or "
                    "replay wrote")


def recording_files(target: str | Path, replays: bool = False) -> list[Path]:
    """The .rrd files to open for RUN (a run directory or an .rrd file), each checked (``check_recording``)."""
    files = _recording_files(Path(target), replays)
    for file in files:
        check_recording(file)
    return files


def _recording_files(path: Path, replays: bool) -> list[Path]:
    if path.is_file():
        if path.suffix != ".rrd":
            raise UserError(f"{path} is not an .rrd file: give a run directory or a recording.rrd")
        return [path]
    if not path.is_dir():
        raise UserError(f"{path} does not exist: give a run directory (runs/<name>) or an .rrd file")
    files = RunDir(path).recording_files(replays)
    if not files:
        raise UserError(f"{path} has no recording.rrd: the run was made with --no-record (run it again without), "
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
        raise UserError("the `rerun` viewer is not installed: pip install 'rerun-sdk>=0.41,<0.42'")
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


def port_in_use(port: int) -> bool:
    """Whether a server could not listen on HOST:``port`` now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        # as the viewer's own listener does, so that sockets a closed viewer left in TIME_WAIT do not count
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((HOST, port))
        except OSError:
            return True
    return False


def check_ports(port: int, grpc_port: int) -> None:
    """Refuse ports the web viewer could not listen on, before any address is printed."""
    for flag, number in (("--port", port), ("--grpc-port", grpc_port)):
        if not 0 < number < 65536:
            raise UserError(f"{flag} {number} is not a port: give a number from 1 to 65535")
    if port == grpc_port:
        raise UserError(f"--port and --grpc-port are both {port}: give two different ports")
    for flag, number in (("--port", port), ("--grpc-port", grpc_port)):
        if port_in_use(number):
            raise UserError(f"port {number} on {HOST} is in use (by another viewer or program): stop it, "
                           f"or choose a free port with {flag}")


def _die_with_parent(parent: int):
    """A ``preexec_fn`` for the viewer: on Linux, have the kernel send it SIGTERM when ``view``
    dies, even by SIGKILL, so that it never outlives ``view`` holding the ports."""
    if not sys.platform.startswith("linux"):
        return None
    prctl = ctypes.CDLL(None).prctl  # looked up before the fork: the child only calls it
    pr_set_pdeathsig = 1

    def preexec() -> None:
        prctl(pr_set_pdeathsig, int(signal.SIGTERM))
        if os.getppid() != parent:  # view died before the request took effect
            os._exit(1)

    return preexec


def last_log_line(log) -> str:
    """The last non-empty line of the viewer's log, without its colour codes."""
    log.seek(0)
    lines = [re.sub(r"\x1b\[[0-9;]*m", "", line).strip() for line in log.read().decode(errors="replace").splitlines()]
    lines = [line for line in lines if line]
    return lines[-1] if lines else "no output"


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
    parser.add_argument("--verbose", action="store_true", help="show the viewer's own log lines")


def main(args: argparse.Namespace) -> int:
    files = recording_files(args.run, args.replays)
    web = args.web or not has_display()
    if web:
        check_ports(args.port, args.grpc_port)
    command, url = build_command(files, web, args.port, args.grpc_port)
    print("opening " + ", ".join(map(str, files)), flush=True)
    with tempfile.TemporaryFile() as log:
        output = {} if args.verbose else {"stdout": subprocess.DEVNULL, "stderr": log}
        process = subprocess.Popen(command, preexec_fn=_die_with_parent(os.getpid()), **output)
        signal.signal(signal.SIGTERM, _stop)  # so that `finally` stops the viewer on kill too
        if url:
            print(f"web viewer: {url}  (serving on {HOST} only; Ctrl-C stops it)", flush=True)
        try:
            code = process.wait()
        except KeyboardInterrupt:
            return 0
        finally:
            if process.poll() is None:
                process.terminate()
                process.wait()
        if code != 0 and not args.verbose:
            raise UserError(f"the rerun viewer stopped with exit code {code}: {last_log_line(log)} "
                           "(run again with --verbose for its whole log)")
        return code
