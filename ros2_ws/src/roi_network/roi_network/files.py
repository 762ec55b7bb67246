"""File helpers shared by the nodes that keep state on disk (ln_builder, rover_vo)."""

from __future__ import annotations

import time
from pathlib import Path


def keep_aside(path: Path) -> Path:
    """Rename an unusable saved file to ``<name>.corrupt-<unix time>`` beside it (kept for
    inspection, out of the way of a fresh start) and return the new path.

    Raises:
        OSError: the rename failed.
    """
    aside = path.with_name(f"{path.name}.corrupt-{int(time.time())}")
    path.replace(aside)
    return aside
