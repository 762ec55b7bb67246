"""`make demo`: twice in a row the second run reuses the bag and the GN the first one made;
a degraded run is still evaluated, a failed one not.

The Makefile's own logic is run (``make demo``), with the commands it calls replaced by
shims on PATH that log their arguments (and make what the real ones would: the bag's
``rosbag/`` and ``orbital.tif``, the GN file), so the test takes a second instead of the
demo's ten minutes. ``setup`` is taken as done (``make -o setup``)."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

SHIMS = {
    # atacama_sim generate --preset quick --seed 1 --out BAG
    "atacama_sim": 'mkdir -p "$7/rosbag" && touch "$7/orbital.tif"',
    # orbital_gn prepare ORTHO --out GN --preview PNG
    "orbital_gn": 'echo "{}" > "$4"',
    # globloc run BAG --out out --rate R --run-id ID / globloc eval RUN_DIR
    # (the run's exit status from $GLOBLOC_RUN_EXIT, default 0)
    "globloc": '[ "$1" = run ] && exit "${GLOBLOC_RUN_EXIT:-0}"; true',
}


def with_shims(tmp_path: Path) -> tuple[dict, Path, Path]:
    """The environment with the shims first on PATH, their call log, the demo bag."""
    shims = tmp_path / "bin"
    shims.mkdir()
    log = tmp_path / "calls.log"
    for name, body in SHIMS.items():
        path = shims / name
        path.write_text(f'#!/bin/bash\necho "{name} $*" >> "{log}"\n{body}\n')
        path.chmod(0o755)
    return {**os.environ, "PATH": f"{shims}:{os.environ['PATH']}"}, log, tmp_path / "bags/quick"


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
def test_make_demo_twice_reuses_the_bag_and_the_gn(tmp_path: Path) -> None:
    env, log, bag = with_shims(tmp_path)

    def demo(run_id: str, run_exit: int = 0) -> list[str]:
        before = log.read_text().splitlines() if log.exists() else []
        r = subprocess.run(["make", "--no-print-directory", "-C", str(ROOT), "-o", "setup",
                            "demo", f"BAG={bag}", "RUN_ENV=", f"RUN_ID={run_id}"],
                           env={**env, "GLOBLOC_RUN_EXIT": str(run_exit)},
                           capture_output=True, text=True, timeout=60)
        assert (r.returncode == 0) == (run_exit == 0), r.stderr
        return log.read_text().splitlines()[len(before):]

    first = demo("r1")
    assert [c.split()[:2] for c in first] == [
        ["atacama_sim", "generate"], ["orbital_gn", "prepare"], ["globloc", "run"],
        ["globloc", "eval"]]
    assert f"--out {bag}" in first[0] and f"--out {bag}/gn.geojson" in first[1]
    made = {p: p.stat().st_mtime_ns for p in (bag / "orbital.tif", bag / "gn.geojson")}

    second = demo("r2")
    assert second == [f"globloc run {bag} --out out --rate 5 --run-id r2",
                      "globloc eval out/quick/r2"]
    assert {p: p.stat().st_mtime_ns for p in made} == made  # neither made again


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
def test_make_demo_evaluates_a_degraded_run_and_not_a_failed_one(tmp_path: Path) -> None:
    env, log, bag = with_shims(tmp_path)
    for run_exit, evaluated in ((3, True), (1, False), (130, False)):
        before = log.read_text().splitlines() if log.exists() else []
        r = subprocess.run(["make", "--no-print-directory", "-C", str(ROOT), "-o", "setup",
                            "demo", f"BAG={bag}", "RUN_ENV=", f"RUN_ID=r{run_exit}"],
                           env={**env, "GLOBLOC_RUN_EXIT": str(run_exit)},
                           capture_output=True, text=True, timeout=60)
        calls = [c.split()[:2] for c in log.read_text().splitlines()[len(before):]]
        assert (["globloc", "eval"] in calls) == evaluated, (run_exit, calls)
        assert r.returncode != 0  # make says the run was not ok
