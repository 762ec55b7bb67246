"""The estimator's saved state: what a restarted rover_vo node continues from.

The node writes :meth:`VoEstimator.snapshot <rover_vo.estimator.VoEstimator.snapshot>` to
its ``state_path`` (JSON, atomically) after every pose it publishes; a node restarted with
the same path reads it back and :meth:`resumes <rover_vo.estimator.VoEstimator.resume>`
the same odom frame, so the LN already built in odom and the matcher's map -> odom estimate
stay valid. A file that cannot be used is moved aside (``<path>.corrupt-<unix time>``),
the reason reported, and a new odom frame starts.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from roi_network.files import keep_aside, write_atomic
from rover_vo.estimator import VoEstimator


def save_state(path: str | Path, snapshot: dict[str, Any]) -> None:
    """Write a snapshot atomically (a reader never sees half a file)."""
    write_atomic(path, json.dumps(snapshot))


def resume_from_file(estimator: VoEstimator, path: str | Path,
                     report: Callable[[str], None]) -> bool:
    """Resume ``estimator`` from the snapshot at ``path`` if there is one.

    Returns:
        True when resumed; False when there is no file, or it was unusable (moved aside
        and ``report`` told why).
    """
    path = Path(path)
    if not path.exists():
        return False
    try:
        estimator.resume(json.loads(path.read_text()))
        return True
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, ValueError, AttributeError) as exc:
        try:
            aside = keep_aside(path)
        except OSError:
            aside = path
        report(f"saved odometry state {path} is unusable ({exc}); kept as {aside}, a new "
               "odom frame starts")
        return False
