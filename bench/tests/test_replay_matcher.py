"""bench/replay_matcher.py on a run directory made here: an outputs bag with a growing LN
and the odometry of a straight drive, a GN, a truth trajectory."""

from __future__ import annotations

import json
from pathlib import Path

import pytest


@pytest.fixture(scope="module")
def replay(bench_script):
    return bench_script("replay_matcher")


def test_replay_localizes_a_clean_run(tmp_path: Path, replay, replay_run, capsys) -> None:
    run, bag = replay_run(tmp_path)
    out = tmp_path / "replay.json"
    assert replay.main([str(run), str(bag), "--variants", "base,notrack", "--events",
                        "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [r["variant"] for r in rows] == ["base", "notrack"]
    for r in rows:
        assert r["first_fix_after_m"] is not None and r["first_fix_after_m"] < 600.0
        assert r["final_error_m"] < 1.0 and r["poses_over_10m"] == 0
        assert r["events"].get("first_fix:ok") == 1
        assert r["consistency_3sigma"] > 0.9
    # --events: one line per decision, the fit's offset from the oracle alignment.
    assert "first_fix:ok" in capsys.readouterr().out


def test_replay_bad_input(tmp_path: Path, replay, replay_run) -> None:
    run, bag = replay_run(tmp_path)
    with pytest.raises(SystemExit, match="no outputs bag"):
        replay.main([str(tmp_path), str(bag)])
    with pytest.raises(SystemExit):
        replay.main([str(run), str(bag), "--variants", "nosuch"])
    with pytest.raises(SystemExit):
        replay.main([str(run), str(tmp_path / "missing")])
