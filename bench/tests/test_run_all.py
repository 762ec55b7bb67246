"""bench/run_all.py: the commands of each tier, and one driver run on stand-in benches."""

from __future__ import annotations

import json
import os
import sys
import time

import pytest


@pytest.fixture(scope="module")
def run_all(bench_script):
    return bench_script("run_all")


def test_quick_tier_dry_run_lists_every_bench_on_the_demo_bag(run_all, tmp_path, capsys):
    results = tmp_path / "current"
    assert run_all.main(["--dry-run", "--bags-dir", str(tmp_path), "--results",
                         str(results)]) == 0
    out = capsys.readouterr().out
    lines = [ln for ln in out.splitlines() if ln.startswith("[")]
    steps = [ln.split("]")[0][1:] for ln in lines]
    assert steps[:2] == ["bags", "bags"] and set(steps) == set(run_all.STEPS) - {"heldout", "sun"}
    assert f"atacama_sim generate --preset quick --seed 1 --no-progress --out {tmp_path}/quick" \
        in out
    assert "skipped" not in out  # nothing exists under tmp_path: everything is generated
    # The same world with panoramas and with the fixed camera, side by side.
    assert f"generate --preset quick --seed 1 --no-panoramas --no-progress --out " \
        f"{tmp_path}/quick_fixed" in out
    assert f"e2e_bench.py {tmp_path}/quick {tmp_path}/quick_fixed --rate 5 --jobs 2 " \
        "--tag evaluation" in out
    assert f"--vo quick=<e2e run of quick>/vo.tum --gn quick={tmp_path}/quick/gn.geojson" in out
    assert "quality --bags" in out and "--recipes sun_aware" in out
    assert "generality --max-lns 120 --stress-lns 100 --seed 7 --gns" in out
    assert "atacama_1km" not in out and "darces_bench.py paper" not in out
    assert not results.exists()  # a dry run writes nothing


def test_full_tier_adds_the_1km_seeds_and_the_paper_protocol(run_all, tmp_path, capsys):
    (tmp_path / "atacama_1km_s2" / "rosbag").mkdir(parents=True)
    assert run_all.main(["--tier", "full", "--dry-run", "--bags-dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    for seed in (1, 3):
        assert (f"generate --preset atacama_1km --seed {seed} --no-progress "
                f"--out {tmp_path}/atacama_1km_s{seed}") in out
    assert "--seed 2 --no-progress" in out.split("skipped")[0].splitlines()[-1]
    assert f"--seed 3 --no-panoramas --no-progress --out {tmp_path}/atacama_1km_s3_fixed" in out
    assert f"{tmp_path}/atacama_1km_s3_fixed --rate 5 --jobs 2" in out  # two graphs at a time
    assert "darces_bench.py paper" in out and "darces_bench.py stress" in out
    assert "--recipes" not in out and "--methods darces" not in out
    # Held-out worlds, each with panoramas and fixed, end to end and through roi_bench.
    held = [ln for ln in out.splitlines() if ln.startswith("[heldout]")]
    assert sum("atacama_sim generate" in ln for ln in held) == 2 * len(run_all.HELDOUT_SEEDS)
    assert f"--seed 201 --no-panoramas --no-progress --out {tmp_path}/quick_s201_fixed" in out
    e2e = [ln for ln in held if "e2e_bench.py" in ln]
    assert len(e2e) == 1 and "--tag heldout" in e2e[0]
    n = run_all.HELDOUT_E2E_SEEDS
    assert sum(f"{tmp_path}/quick_s" in w for w in e2e[0].split()) == 2 * n  # pano and fixed
    roi = [ln for ln in held if "roi_bench.py --name heldout" in ln]
    assert len(roi) == 1 and "--vo" not in roi[0]  # on truth odometry, before the e2e runs
    assert held.index(roi[0]) < next(i for i, ln in enumerate(held) if "e2e_bench.py" in ln)
    assert f"--gn quick_s206_fixed={tmp_path}/quick_s206_fixed/gn.geojson --jobs 2" in roi[0]
    # The sun heading: the demo bag and held-out worlds with panoramas, each with and
    # without, generated here when missing (``--only sun``).
    sun = [ln for ln in out.splitlines() if ln.startswith("[sun]")]
    assert f"--seed 201 --no-progress --out {tmp_path}/quick_s201" in "\n".join(sun)
    e2e = [ln for ln in sun if "e2e_bench.py" in ln]
    assert len(e2e) == 1 and "--tag sun" in e2e[0]
    assert "--compare rover_vo:imu.sun_heading=false --compare-label no_sun" in e2e[0]
    bags = [w for w in e2e[0].split() if w.startswith(str(tmp_path))]
    assert bags == [f"{tmp_path}/quick", *(f"{tmp_path}/quick_s{s}" for s in
                                           run_all.HELDOUT_SEEDS[:run_all.SUN_HELDOUT_SEEDS])]


def test_a_run_stamps_every_result_and_summarises_it(run_all, tmp_path, monkeypatch):
    results = tmp_path / "current"
    results.mkdir()
    (results / "stale.md").write_text("# from another commit\n")
    e2e = {"bags": [{"bag": "bags/quick", "run_dir": "out/bench/quick/r1",
                     "continuous": {"route_length_m": 399.6, "distance_before_first_fix_m": 154.04,
                                    "final_error_m": 0.384, "rmse_after_first_fix_m": 0.391,
                                    "false_fixes": 0, "consistency_3sigma": 1.0},
                     "end_of_route": {"status": "fix", "final_error_m": 1.5, "rmse_m": 2.25}}]}
    vo_md = ("# rover_vo benchmark\n\nMade by ...\n\n"
             "| bag | method |\n|---|---|\n| quick | paper |\n")
    write = ("import json, os, pathlib, sys; r = pathlib.Path(os.environ['BENCH_RESULTS']); "
             "r.joinpath(sys.argv[1]).write_text(sys.argv[2])")
    cmds = [run_all.Command("e2e", [sys.executable, "-c", write, "e2e_evaluation.json",
                                    json.dumps(e2e)]),
            run_all.Command("vo", [sys.executable, "-c", write, "vo_bench.md", vo_md]),
            run_all.Command("roi", [sys.executable, "-c", "raise SystemExit(3)"]),
            run_all.Command("bags", ["false"], skip_if=lambda: True, why_skip="exists")]
    monkeypatch.setattr(run_all, "plan", lambda *a, **k: cmds)
    assert run_all.main(["--results", str(results)]) == 1  # the roi stand-in failed
    assert not (results / "stale.md").exists()
    doc = json.loads((results / "e2e_evaluation.json").read_text())
    prov = doc["provenance"]
    assert len(prov["commit"]) == 40 and isinstance(prov["dirty"], bool)
    assert prov["tier"] == "quick" and prov["machine"]["cpus"] >= 1
    assert prov["command"].startswith("python bench/run_all.py")
    vo = (results / "vo_bench.md").read_text().splitlines()
    assert vo[0] == "# rover_vo benchmark" and vo[2].startswith("Provenance: Commit `")
    summary = (results / "summary.md").read_text()
    assert "| quick | 400 | 154.0 | 0.38 | 0.39 | 0 | 100.0 % | 1.50 / 2.25 |" in summary
    assert "| quick | paper |" in summary and "Failed: `python -c raise SystemExit(3)`" in summary


def test_an_only_run_stamps_only_what_it_wrote(run_all, tmp_path, monkeypatch):
    results = tmp_path / "current"
    results.mkdir()
    earlier = {"bags": [], "provenance": {"command": "python bench/run_all.py --only e2e"}}
    (results / "e2e_evaluation.json").write_text(json.dumps(earlier))
    old = time.time() - 60
    os.utime(results / "e2e_evaluation.json", (old, old))
    write = ("import os, pathlib; r = pathlib.Path(os.environ['BENCH_RESULTS']); "
             "r.joinpath('vo_bench.md').write_text('# rover_vo benchmark\\n')")
    monkeypatch.setattr(run_all, "plan", lambda *a, **k: [
        run_all.Command("vo", [sys.executable, "-c", write])])
    assert run_all.main(["--only", "vo", "--results", str(results)]) == 0
    kept = json.loads((results / "e2e_evaluation.json").read_text())["provenance"]
    assert kept["command"] == "python bench/run_all.py --only e2e"
    assert "Provenance: Commit" in (results / "vo_bench.md").read_text()
