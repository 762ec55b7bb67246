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


def test_progress_speaks_on_a_short_bag(tmp_path, capsys):
    """A 3 s drive (4 pairs): no 100 poses, no 10 s of bag, but the final line."""
    import vo_flatworld as fw

    from rover_vo import cli

    bag = fw.write_bag(fw.stream(fw.Schedule(period_s=1.0).drive(4)), tmp_path / "short")
    assert cli.main(["odometry", str(bag), "--out", str(tmp_path / "o"), "--progress"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err == ["  done: 4 poses, 3.0 s of bag, 1.1 m"], err


def test_progress_every_100_poses_or_10_s_of_bag(capsys):
    from collections import Counter
    from types import SimpleNamespace

    from rover_vo.offline import Progress

    est = SimpleNamespace(state=SimpleNamespace(distance_m=2.5),
                          counts=SimpleNamespace(bad=Counter(imu_nan=1)))
    said = Progress(est)
    outputs = []
    # 150 poses 0.01 s apart (a line at 100), then 3 s apart (a line each 10 s).
    stamps = [0.01 * k for k in range(150)] + [1.5 + 3.0 * k for k in range(1, 8)]
    for t in stamps:
        outputs.append(SimpleNamespace(state=SimpleNamespace(t=t)))
        said.update(outputs)
    said.final(outputs)
    lines = capsys.readouterr().err.splitlines()
    assert [line.split(" poses")[0].strip() for line in lines] == [
        "100", "154", "done: 157"], lines  # 13.5 s is 12.5 s after 1.0 s; 22.5 s, 9 s
    assert lines[0] == "  100 poses, 1.0 s of bag, 2.5 m, 1 bad inputs"
