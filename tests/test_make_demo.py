"""`make demo` twice in a row: the second run reuses the bag and the GN the first one made.

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
    "globloc": "true",
}


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
def test_make_demo_twice_reuses_the_bag_and_the_gn(tmp_path: Path) -> None:
    shims = tmp_path / "bin"
    shims.mkdir()
    log = tmp_path / "calls.log"
    for name, body in SHIMS.items():
        path = shims / name
        path.write_text(f'#!/bin/bash\necho "{name} $*" >> "{log}"\n{body}\n')
        path.chmod(0o755)
    bag = tmp_path / "bags" / "quick"
    env = {**os.environ, "PATH": f"{shims}:{os.environ['PATH']}"}

    def demo(run_id: str) -> list[str]:
        before = log.read_text().splitlines() if log.exists() else []
        subprocess.run(["make", "--no-print-directory", "-C", str(ROOT), "-o", "setup",
                        "demo", f"BAG={bag}", "RUN_ENV=", f"RUN_ID={run_id}"],
                       env=env, check=True, capture_output=True, text=True, timeout=60)
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
