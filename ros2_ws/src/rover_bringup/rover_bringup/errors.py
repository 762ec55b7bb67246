"""The one exception type for user errors (bad bag, bad graph file, missing executable...).

The CLI prints it as a single ``globloc: error: <message>`` line and exits non-zero; anything
else escaping is a bug and keeps its traceback. :func:`say` writes globloc's own lines.
"""

import contextlib
import os
import sys


class GloblocError(Exception):
    """A user-facing error: the message is the whole explanation, no traceback is shown."""


def say(line: str) -> None:
    """One line of globloc's on stderr. A stderr whose reader is gone (a closed pipe: the
    process that started the run died; a closed terminal) does not stop the caller: the
    line is dropped, and so are the later ones, so that a run still stops its graph and
    writes run.yaml (its logs and run.yaml keep what it would have said)."""
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):  # BrokenPipeError; ValueError: stderr closed
        with contextlib.suppress(OSError):
            sys.stderr = open(os.devnull, 'w')  # noqa: SIM115 - lives as long as the process
