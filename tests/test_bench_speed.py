"""`lift3d bench --quick` end to end for the speed sections: scaling (step and render time and memory against
resolution, views, V and U) and the profile of a training step and a render, with tiny scenes and few steps.

Trains only on a tuning seed's scenes (>= 100): seeds 0-4 are reserved for the reported numbers.
"""

from lift3d.bench.runner import BenchConfig, run_benchmark


def test_bench_quick_scaling_and_profile(tmp_path, monkeypatch):
    monkeypatch.setenv("LIFT3D_NO_PROGRESS", "1")
    # (The under-load section has its own test in tests/test_bench.py.)
    cfg = BenchConfig(out=tmp_path / "bench", scenes=("indoor",), presets=("fast",), seeds=(100,), preset_table=False,
                      curves=False, ablation=False, bounded_check=False, export=False, under_load=False, quick=True,
                      progress=False, docs_dir=tmp_path / "docs")
    results = run_benchmark(cfg)
    assert {s["factor"] for s in results["scaling"]} == {"resolution", "views", "instance_channels", "classes"}
    assert all(s["step_ms"] > 0 and s["render_ms"] > 0 and s["pixels"] > 0 for s in results["scaling"])
    prof = results["profile"]
    assert prof["step_ms"] > 0 and prof["render_ms"] > 0
    assert {"step.sample_batch", "step.forward_and_losses", "step.backward", "step.optimizer",
            "render.field_geometry"} <= {r["name"] for r in prof["train"]["stages"]}
    assert (cfg.out / "scaling.png").is_file()
    md = (tmp_path / "docs" / "benchmarks.md").read_text()
    assert "### Scaling" in md and "### Where the time goes" in md
