"""`lift3d bench --quick`: the benchmark's smoke test (tiny scenes, few steps; every section and report)."""

import csv
import json
import subprocess
import sys

import pytest


@pytest.mark.slow
def test_bench_quick_writes_every_report(tmp_path):
    out = tmp_path / "bench"
    cmd = [sys.executable, "-m", "lift3d", "bench", "--quick", "--scenes", "indoor", "--presets", "fast",
           "--out", str(out), "--docs-dir", str(tmp_path / "docs")]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1200,
                          env={**__import__("os").environ, "LIFT3D_NO_PROGRESS": "1"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads((out / "results.json").read_text())
    assert results["machine"]["cpu"] and results["machine"]["torch_threads"] >= 1
    runs = results["runs"]
    assert {(r["noise"], r["preset"], r["variant"]) for r in runs} == {
        ("moderate", "fast", "all"), ("hard", "fast", "all"), ("moderate", "fast", "rgb-only")}
    # The synthetic scenes ship depth maps: the presets use them, the RGB-only row and the ablation do not.
    assert {r["variant"]: r["depth_supervision"] for r in runs} == {"all": True, "rgb-only": False}
    assert not any(r["depth_supervision"] for r in results["ablation"])
    for r in runs:
        assert r["train_seconds"] > 0 and r["peak_rss_mb"] > 100 and r["render_ms_per_2048_rays"] > 0
        assert 0 <= r["miou"] <= 1 and 0 <= r["pq_scene"] <= 1 and r["psnr"] > 5
        assert r["pseudo_labels"]["miou"] is not None and r["points3d"]["fscore"] is not None
    assert [r["variant"] for r in results["ablation"]] == ["base", "base+S", "base+S+L_seg", "base+S+L_feat", "all"]
    assert {s["factor"] for s in results["scaling"]} == {"resolution", "views", "instance_channels", "classes"}
    ex = results["export"]
    assert ex["points"] > 0 and ex["seconds"] > 0 and ex["peak_rss_mb"] > 100 and ex["preset"] == "fast"
    prof = results["profile"]
    assert prof["step_ms"] > 0 and prof["render_ms"] > 0
    stages = {r["name"] for r in prof["train"]["stages"]}
    assert {"step.sample_batch", "step.forward_and_losses", "step.backward", "step.optimizer",
            "render.field_geometry"} <= stages
    assert "render.field_geometry" in {r["name"] for r in prof["render"]["stages"]}
    for block in (prof["train"], prof["render"]):
        assert block["ops"] and all(r["self_ms"] >= 0 for r in block["ops"])
        assert sum(r["percent"] for r in block["ops"]) <= 100.0 + 1e-6
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert len(rows) == len(runs) + len(results["ablation"])
    for name in ("pareto.png", "scaling.png", "benchmarks.md"):
        assert (out / name).is_file()
    md = (tmp_path / "docs" / "benchmarks.md").read_text()
    assert results["machine"]["cpu"] in md and "| indoor | hard | RGB + depth | fast |" in md
    assert "| indoor | moderate | RGB | fast |" in md
    assert "## Where the time goes" in md and "`step.backward`" in md
    assert "## Export: labelled points" in md
    # Resumable: a second run reuses every cached measurement (fast, same numbers).
    proc2 = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc2.returncode == 0
    again = json.loads((out / "results.json").read_text())
    assert [r["train_seconds"] for r in again["runs"]] == [r["train_seconds"] for r in runs]
    # --reevaluate: metrics are computed again from the cached runs; training and render timing are kept.
    for path in (out / "cache").glob("run_*.json"):
        if not path.name.endswith(".spec.json"):
            cached = json.loads(path.read_text())
            cached["metrics"]["points3d"]["miou"] = -1.0  # stale: must be replaced
            path.write_text(json.dumps(cached))
    proc3 = subprocess.run(cmd + ["--reevaluate", "--no-ablation", "--no-scaling", "--no-profile"],
                           capture_output=True, text=True, timeout=600)
    assert proc3.returncode == 0, proc3.stderr[-3000:]
    third = json.loads((out / "results.json").read_text())
    assert [r["train_seconds"] for r in third["runs"]] == [r["train_seconds"] for r in runs]
    assert [r["render_ms_per_2048_rays"] for r in third["runs"]] == [r["render_ms_per_2048_rays"] for r in runs]
    for r in third["runs"]:
        assert 0 <= r["points3d"]["miou"] <= 1 and r["points3d"]["miou_strict"] is not None
    assert all("reevaluated" in json.loads(p.read_text()) for p in (out / "cache").glob("run_*_s0.json"))
    assert not list((out / "cache").glob("*.eval.json"))
    assert "`lift3d bench --reevaluate`" in (tmp_path / "docs" / "benchmarks.md").read_text()


def test_reevaluate_names_a_cached_run_whose_folder_is_gone(tmp_path, capfd, monkeypatch):
    from lift3d.cli.main import main

    monkeypatch.setenv("LIFT3D_NO_PROGRESS", "1")
    out = tmp_path / "bench"
    (out / "cache").mkdir(parents=True)
    cached = out / "cache" / "run_indoor_fast_s0.json"
    cached.write_text(json.dumps({"run": str(tmp_path / "gone"), "metrics": {}}))
    rc = main(["bench", "--quick", "--scenes", "indoor", "--presets", "fast", "--no-hard", "--no-rgb-only",
               "--no-ablation", "--no-scaling", "--no-export", "--no-profile", "--reevaluate", "--out", str(out),
               "--docs-dir", str(tmp_path / "docs")])
    err = capfd.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "run_indoor_fast_s0.json" in err[0] and "is gone" in err[0], err
    assert json.loads(cached.read_text())["run"] == str(tmp_path / "gone")  # the cache is left as it was


def test_under_load_measures_step_and_render_alone_and_beside_a_busy_neighbour(tmp_path):
    from lift3d.bench.runner import _QUICK_TRAIN, under_load_markdown
    from lift3d.bench.worker import run_under_load
    from lift3d.synth import make_scene

    scene = tmp_path / "room"
    make_scene(scene, kind="indoor", seed=105, noise="moderate", n_views=6, width=32, height=32, progress=False)
    res = run_under_load({"scene": str(scene), "preset": "fast", "overrides": _QUICK_TRAIN,
                          "output_dir": str(tmp_path / "runs"), "warmup": 1, "steps": 1, "repeats": 1, "rounds": 1,
                          "settle_seconds": 0.1})
    for key in ("step_ms", "render_ms", "loaded_step_ms", "loaded_render_ms", "step_slowdown", "render_slowdown"):
        assert res[key] > 0, key  # numbers only: no timing is asserted
    text = "\n".join(under_load_markdown(res))
    assert "## Under load" in text and "slowdown" in text
