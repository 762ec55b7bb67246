"""The offline odometry's own measurements."""

from __future__ import annotations

import subprocess
import sys

import numpy as np


def test_peak_rss_is_the_process_own_not_its_parents():
    """A process started by a big parent reports its own peak (ru_maxrss would not)."""
    big = np.ones(40_000_000)  # 320 MB held while the child starts
    code = ("import resource; from rover_vo.offline import peak_rss_mb; "
            "print(peak_rss_mb(), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    own, inherited = float(out[0]), float(out[1])
    assert big.sum() == 40_000_000
    # ``inherited`` is ~400 MB on Linux: ru_maxrss carries the parent's peak over the exec.
    assert own < 250.0, f"peak {own} MB (ru_maxrss says {inherited} MB)"
