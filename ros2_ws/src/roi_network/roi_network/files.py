"""File helpers shared by the nodes that keep state on disk (ln_builder, rover_vo) and the
tools that write result files."""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path


def write_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file in the same directory and a
    rename: a reader sees the old file or the new one, never a part (the temporary file
    is removed if the write fails)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def keep_aside(path: Path) -> Path:
    """Rename an unusable saved file to ``<name>.corrupt-<unix time>`` beside it (kept for
    inspection, out of the way of a fresh start) and return the new path.

    Raises:
        OSError: the rename failed.
    """
    aside = path.with_name(f"{path.name}.corrupt-{int(time.time())}")
    path.replace(aside)
    return aside
