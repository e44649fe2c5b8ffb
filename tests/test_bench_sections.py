"""`lift3d bench --quick` end to end for the accuracy sections besides the preset table (tests/test_bench.py
has that one; tests/test_bench_speed.py the speed sections): the noise curves, the ablation at equal steps
and equal time, bounded against contracted, on one tuning seed with tiny scenes and few steps. What the
report says about these sections over several seeds is tested on fabricated results in tests/test_bench.py.

Trains only on tuning seeds (>= 100): seeds 0-4 are reserved for the reported numbers.
"""

import csv
import json

from lift3d.bench import runner
from lift3d.bench.runner import BenchConfig, run_benchmark


def test_bench_quick_curves_ablation_bounded(tmp_path, monkeypatch):
    monkeypatch.setenv("LIFT3D_NO_PROGRESS", "1")
    # Two of the five ablation variants (--ablation-variants: the MLP field and the grid one): every code path
    # of the section, fewer runs.
    cfg = BenchConfig(out=tmp_path / "bench", scenes=("indoor", "outdoor"), presets=("fast",), seeds=(100,),
                      ablation_variants=("base", "base+S"),
                      label_noise_levels=("hard",), pose_noise_levels=((0.5, 2.0),), preset_table=False,
                      scaling=False, export=False, profile=False, under_load=False, quick=True, progress=False,
                      docs_dir=tmp_path / "docs")
    results = run_benchmark(cfg)
    curves = results["curves"]
    assert [r["noise"] for r in curves["label_noise"]] == ["hard"]
    (pose,) = curves["pose_noise"]
    assert pose["pose_noise"] == [0.5, 2.0] and pose["poses_scored_at"] == "gt_transform_matrix"
    # The ablation trains on RGB only, at equal steps (the quick schedule) and at equal time.
    abl = results["ablation"]
    assert {(r["mode"], r["variant"]) for r in abl} == {(m, v) for m in ("steps", "time") for v in ("base", "base+S")}
    assert not any(r["depth_supervision"] for r in abl) and {r["inputs"] for r in abl} == {"RGB"}
    assert {r["steps"] for r in abl if r["mode"] == "steps"} == {runner._QUICK_TRAIN["optim"]["steps"]}
    assert all(r["budget_seconds"] == 2.0 and r["steps"] >= 1 for r in abl if r["mode"] == "time")
    # Runs whose tables show no 3D columns skip the 3D metrics (--quick: every run outside the preset table).
    assert all(r["points3d"]["fscore"] is None for r in abl + curves["label_noise"])
    assert {r["variant"] for r in results["parameterisation"]} == {"bounded", "all"}
    assert all(r["scene"] == "outdoor" and r["psnr"] > 5 for r in results["parameterisation"])
    out = cfg.out
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert len(rows) == len(abl) + 2 + len(results["parameterisation"])
    for name in ("noise_curves.png", "benchmarks.md"):
        assert (out / name).is_file(), name
    md = (tmp_path / "docs" / "benchmarks.md").read_text()
    for title in ("### Label noise and pose noise", "**equal steps**", "**equal time**",
                  "### Unbounded vs bounded space"):
        assert title in md, title
    assert "| base → base+S | equal steps |" in md
    assert json.loads((out / "results.json").read_text())["summary"]["ablation_steps"]


def test_regenerating_the_page_keeps_what_was_measured_outside_the_benchmark():
    from lift3d.bench.runner import KEPT_BEGIN, KEPT_END, PAGE_SECTIONS, kept_block, with_kept_block

    block = f"{KEPT_BEGIN}\n### Real captures\n\n| a | b |\n{KEPT_END}"
    old = f"# Benchmarks\n\n{PAGE_SECTIONS[1]}\n\nold\n\n{block}\n\n{PAGE_SECTIONS[2]}\n\nslow\n"
    new = f"# Benchmarks\n\n{PAGE_SECTIONS[1]}\n\nnew\n\n{PAGE_SECTIONS[2]}\n\nfast\n"
    page = with_kept_block(new, kept_block(old))
    assert page.index("new") < page.index("### Real captures") < page.index(PAGE_SECTIONS[2]) < page.index("fast")
    assert with_kept_block(new, kept_block(new)) == new  # nothing kept, nothing added
