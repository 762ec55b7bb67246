"""Child processes of ``globloc run``: start with a log file, watch, stop politely. No rclpy.

Each node runs in its own process with the environment inherited unchanged (the ROS wheels'
bootstrap relies on LD_LIBRARY_PATH and its marker variable travelling together). Stopping
is SIGTERM first: rclpy and rclcpp nodes shut down cleanly on it and Fast DDS removes its
shared-memory files; SIGKILL, only after a timeout, leaves ``/dev/shm/fastrtps_*`` behind.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO


@dataclass
class ManagedProcess:
    """A started child process.

    Attributes:
        name: Node (or tool) name; the log is ``<logs>/<name>.log``.
        argv: Command line.
        log_path: File receiving its stdout and stderr.
        popen: The process.
        stop_requested: Set once we asked it to stop (exits after that are not crashes).
        killed: Whether it needed SIGKILL.
        muted: Once set, an echoed process's output goes to its log only (an interrupted
            run says one line, not each child's farewell).
    """

    name: str
    argv: list[str]
    log_path: Path
    popen: subprocess.Popen[bytes]
    stop_requested: bool = False
    killed: bool = False
    muted: threading.Event = field(default_factory=threading.Event)
    _log: IO[bytes] | None = field(default=None, repr=False)
    _tee: threading.Thread | None = field(default=None, repr=False)

    @property
    def returncode(self) -> int | None:
        """Exit status (negative: killed by that signal), None while running."""
        return self.popen.poll()

    @property
    def crashed(self) -> bool:
        """Exited non-zero before it was asked to stop."""
        code = self.returncode
        return code is not None and code != 0 and not self.stop_requested

    def close_log(self) -> None:
        """Wait for the output copier (if any) and close the log file."""
        if self._tee is not None:
            self._tee.join(timeout=5.0)
        if self._log is not None:
            self._log.close()
            self._log = None


def _copy_lines(source: IO[bytes], log: IO[bytes], console: IO[str],
                muted: threading.Event) -> None:
    # Runs in a thread: one line at a time to the log and (unless muted) to our stderr.
    for line in iter(source.readline, b''):
        log.write(line)
        log.flush()
        if not muted.is_set():
            console.write(line.decode(errors='replace'))
            console.flush()
    source.close()


def start(
    name: str, argv: Sequence[str], log_dir: Path, echo: bool = False, append: bool = False,
    muted: threading.Event | None = None,
) -> ManagedProcess:
    """Start a child process with stdout+stderr going to ``<log_dir>/<name>.log``.

    Args:
        name: Process name (log file name).
        argv: Command line.
        log_dir: Directory of the log files (must exist).
        echo: Also copy its output to our stderr (the player's progress lines).
        append: Append to the log instead of replacing it (a restarted node).
        muted: With ``echo``: stop copying to our stderr once this is set (default: a new
            event, ``ManagedProcess.muted``).

    Returns:
        The started process.
    """
    log_path = log_dir / f'{name}.log'
    log = log_path.open('ab' if append else 'wb')
    popen = subprocess.Popen(
        list(argv),
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE if echo else log,
        stderr=subprocess.STDOUT,
    )
    proc = ManagedProcess(name=name, argv=list(argv), log_path=log_path, popen=popen, _log=log)
    if muted is not None:
        proc.muted = muted
    if echo:
        assert popen.stdout is not None
        proc._tee = threading.Thread(
            target=_copy_lines, args=(popen.stdout, log, sys.stderr, proc.muted), daemon=True
        )
        proc._tee.start()
    return proc


def stop(processes: Sequence[ManagedProcess], timeout_s: float) -> None:
    """Stop processes together: SIGTERM, then SIGKILL whatever is left after ``timeout_s``.

    Args:
        processes: Processes to stop (already exited ones are only reaped).
        timeout_s: Grace period after SIGTERM.
    """
    for proc in processes:
        if proc.returncode is None:  # one that exited already keeps its verdict (crashed?)
            proc.stop_requested = True
            proc.popen.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + timeout_s
    for proc in processes:
        try:
            proc.popen.wait(timeout=max(deadline - time.monotonic(), 0.0))
        except subprocess.TimeoutExpired:
            proc.killed = True
            proc.popen.kill()
            proc.popen.wait()
    for proc in processes:
        proc.close_log()


def tail(path: Path, lines: int = 20) -> str:
    """The last ``lines`` lines of a text file ('' if unreadable)."""
    try:
        with path.open(errors='replace') as fh:
            return ''.join(deque(fh, maxlen=lines))
    except OSError:
        return ''
