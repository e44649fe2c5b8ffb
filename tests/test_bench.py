"""`lift3d bench`: the seed statistics and the report written from them (fabricated results, no training),
the plan, bad flags, and one preset-table row end to end with `--quick` (tiny scenes, few steps); the other
sections end to end are in tests/test_bench_sections.py.

Tests train only on tuning seeds (>= 100): seeds 0-4 are reserved for the reported numbers.
"""

import csv
import json
import re
from pathlib import Path

import pytest

from lift3d.bench import tables, worker
from lift3d.bench.runner import (PAGE_SECTIONS, BenchConfig, failure_record, plan_jobs, report_config, run_inputs,
                                 write_reports)
from lift3d.bench.stats import mean_std, paired_difference
from lift3d.cli.main import main
from lift3d.errors import InputError

DOCS = Path(__file__).resolve().parents[1] / "docs"


# ------------------------------------------------------------------------------------------ statistics
def test_mean_std_and_paired_differences():
    m, s, n = mean_std([0.5, 0.7, 0.6, None])
    assert (round(m, 9), round(s, 9), n) == (0.6, 0.1, 3)
    # The scenes differ a lot, the change is small but the same on every seed: significant when paired.
    a = {0: 0.30, 1: 0.80, 2: 0.55}
    b = {0: 0.28, 1: 0.79, 2: 0.525}
    d = paired_difference(a, b)
    assert d["n"] == 3 and d["mean"] == pytest.approx(0.055 / 3) and d["significant"]
    # A change whose sign flips between seeds is noise; missing seeds are left out of the pairs.
    d = paired_difference({0: 0.5, 1: 0.6, 2: 0.7}, {0: 0.45, 1: 0.66, 3: 0.1})
    assert d["n"] == 2 and d["significant"] is False and set(d["per_seed"]) == {0, 1}
    assert paired_difference({0: 1.0}, {0: 0.5})["significant"] is None  # one pair: no spread, no verdict


# ------------------------------------------------------------------------------------------ report
def _run(seed, **kw):
    """A fabricated run record (what runner._record writes)."""
    rec = {"scene": "indoor", "noise": "moderate", "scene_depth": "sensor", "pose_noise": [0.0, 0.0],
           "preset": "fast", "seed": seed, "variant": "all", "inputs": "RGB + depth", "train_seconds": 500.0 + seed,
           "steps": 1500, "peak_rss_mb": 800.0, "render_ms_per_2048_rays": 80.0, "psnr": 30.0, "miou": 0.8,
           "pq_scene": 0.6, "sq_scene": 0.8, "rq_scene": 0.7, "pseudo_labels": {"miou": 0.6, "pq_scene": 0.4},
           "points3d": {"fscore": 0.95, "miou": 0.7, "instance_recall": 0.9, "n_instances": 10,
                        "n_pred_instances": 14}}
    rec.update(kw)
    return rec


def _results(seeds=(0, 1, 2)):
    spread = {0: -0.05, 1: 0.05, 2: 0.0}
    runs = []
    for s in seeds:
        runs.append(_run(s, miou=0.8 + spread[s]))
        runs.append(_run(s, scene_depth="none", inputs="RGB", miou=0.6 + spread[s], pq_scene=0.45 + spread[s],
                         points3d={"fscore": 0.4, "miou": 0.3}))
        runs.append(_run(s, noise="view-correlated", pq_scene=0.5 + spread[s]))
    label = [_run(s, noise=n, pq_scene=q + spread[s], pseudo_labels={"miou": 0.9 - q, "pq_scene": q - 0.1})
             for n, q in (("clean", 0.8), ("moderate", 0.6), ("hard", 0.5), ("view-correlated", 0.45)) for s in seeds]
    # Pose noise costs 0.1 PQ^scene on every seed at 0.5 deg / 2 cm; refinement wins 0.06 of it back.
    pose = [_run(s, pose_noise=[d, c], variant=v, pq_scene=0.6 + spread[s] - cost + gain)
            for (d, c), cost in (((0.0, 0.0), 0.0), ((0.5, 2.0), 0.1), ((1.0, 5.0), 0.2))
            for v, gain in (("all", 0.0), ("pose-refinement", 0.06 if c else 0.0)) for s in seeds]
    ablation = []
    for mode in ("steps", "time"):
        for variant, miou, pq in (("base", 0.1, 0.05), ("base+S", 0.5, 0.4), ("base+S+L_seg", 0.55, 0.45),
                                  ("base+S+L_feat", 0.45, 0.41), ("all", 0.5, 0.4)):
            for s in seeds:
                # +L_feat: mIoU down on every seed (opposite to the paper); PQ^scene: +0.01 +- 0.05 (noise).
                jitter = {"base+S+L_feat": {0: 0.06, 1: -0.05, 2: 0.02}}.get(variant, {}).get(s, 0.0)
                ablation.append(_run(s, variant=variant, mode=mode, miou=miou + spread[s], pq_scene=pq + jitter,
                                     budget_seconds=600.0 if mode == "time" else None))
    bounded = [_run(s, scene="outdoor", variant=v, psnr=p + spread[s]) for v, p in (("bounded", 27.0), ("all", 35.0))
               for s in seeds]
    return {"machine": {"cpu": "test cpu", "cpus_available": 2, "torch": "x", "torch_threads": 2, "cuda": None},
            "created": "2026-11-23T00:00:00", "quick": False, "seeds": list(seeds), "runs": runs,
            "curves": {"label_noise": label, "pose_noise": pose}, "ablation": ablation,
            "parameterisation": bounded, "skipped": [], "scaling": [], "export": None, "profile": None}


def test_report_is_written_from_the_results(tmp_path):
    results = _results()
    results["summary"] = tables.summarize(results)
    write_reports(results, BenchConfig(out=tmp_path, docs_dir=tmp_path / "docs"))
    md = (tmp_path / "docs" / "benchmarks.md").read_text()
    assert "scene seeds 0, 1, 2" in md and "not used for tuning" in md
    # Mean ± standard deviation over the seeds, per row; the RGB row says so.
    assert "| indoor | moderate | RGB + depth | fast | 501 ± 1 |" in md
    assert "0.800 ± 0.050 (0.600)" in md and "| indoor | moderate | RGB | fast |" in md
    assert "0.90 ± 0.00 of 10 | 14 ± 0 |" in md  # objects found (of how many GT objects), instances exported
    # Margins over the pseudo-labels and what depth maps buy, as sentences with the numbers in them.
    assert "lifting raises mIoU over its pseudo-labels significantly in 2 of 3 rows" in md
    assert "3D F-score is 0.950 against 0.400 from RGB" in md
    # Noise curves: the picture, the label table and the pose-noise cost, paired by seed.
    assert "![PQ^scene and mIoU against label noise and pose noise](images/bench_noise_curves.png)" in md
    assert (tmp_path / "docs" / "images" / "bench_noise_curves.png").is_file()
    assert "| clean | 0.800 ± 0.000 | 0.100 ± 0.000 |" in md
    assert "0.5°/2 cm of pose noise costs 0.100 PQ^scene against none (paired over 3 seeds" in md
    assert "pose refinement changes PQ^scene by +0.060" in md
    # Ablation: each step as a paired difference; a consistent change agrees or not, a flipping one is noise.
    assert "| base+S → base+S+L_feat | equal steps | -0.050 ± 0.000 (n=3) |" in md
    line = next(x for x in md.splitlines() if x.startswith("| base+S → base+S+L_feat | equal steps"))
    assert line.endswith("| up, up, up | **opposite**, within noise, within noise |")
    line = next(x for x in md.splitlines() if x.startswith("| base → base+S | equal time"))
    assert line.endswith("| agrees, agrees, within noise |")
    assert "Equal steps: 4 changes go the paper's way significantly" in md
    assert "| unbounded (contracted) |" in md and "PSNR +8.000 ± 0.000 (n=3)" in md
    # Per-seed values are kept: results.csv has one row per run and section.
    rows = list(csv.DictReader((tmp_path / "results.csv").open()))
    assert len(rows) == sum(len(v) for v in (results["runs"], results["ablation"], results["parameterisation"],
                                              *results["curves"].values()))
    assert {r["section"] for r in rows} == {"runs", "curves/label_noise", "curves/pose_noise", "ablation",
                                             "parameterisation"}
    summary = json.loads((tmp_path / "results.json").read_text())["summary"]
    row = summary["runs"][0]
    assert row["seeds"] == [0, 1, 2]
    assert row["metrics"]["miou"]["per_seed"] == pytest.approx({"0": 0.75, "1": 0.85, "2": 0.8})


def _every_section():
    """Fabricated results with every section of the page at full size: two presets and both scene kinds, per-class
    IoU, a failed run, 16 scaling points, the export, a profile of 8 stages and 12 operators, under load."""
    results = _results()
    results["runs"] += [_run(s, preset="balanced", train_seconds=1500.0 + s, psnr=32.0 + s / 10) for s in (0, 1, 2)]
    results["runs"] += [_run(s, scene="outdoor", noise=n, scene_depth=d, inputs=i) for s in (0, 1, 2)
                        for n in ("moderate", "view-correlated") for d, i in (("sensor", "RGB + depth"),
                                                                               ("none", "RGB + SfM points"))]
    for r in results["runs"]:
        r["thing_iou"] = {"chair": {"iou": 0.8 + r["seed"] / 100, "gt_pixels": 2000},
                          "cup": {"iou": 0.1, "gt_pixels": 20}}  # under 300 px: left out
    results["config"] = report_config(BenchConfig())
    failure = worker.MeasurementFailed("evaluation", "run: the fused rendered depth has no surface | train longer",
                                       log="cache/run.failed.log")
    results["failed"] = [failure_record({"scene": "outdoor", "seed": 1, "noise": "moderate", "scene_depth": "sensor",
                                         "pose_noise": [0.0, 0.0], "preset": "fast", "variant": "all"}, "runs", failure)]
    results["scaling"] = [{"factor": f, "value": v, "step_ms": 400.0, "render_ms": 90.0, "peak_rss_mb": 800.0,
                           "grid_resolution": 128, "pixels": 294912}
                          for f in ("resolution", "views", "instance_channels", "classes") for v in (1, 2, 3, 4)]
    results["export"] = {"points": 1_000_000, "seconds": 3.9, "extract_seconds": 3.8, "write_seconds": 0.0,
                         "peak_rss_mb": 916.0, "load_seconds": 0.2, "threads": 2, "stages": {"isosurface": 0.1},
                         "repeats": 5, "all_seconds": [4.3, 4.0, 3.9, 3.4, 3.7], "preset": "fast"}

    def block(name):
        return {"profiled_ms": 100.0, "stages": [{"name": f"{name}.stage{i}", "ms": 5.0, "calls": 1.0} for i in range(8)],
                "ops": [{"name": f"aten::op{i}", "self_ms": 2.0, "percent": 2.0, "calls": 3} for i in range(12)]}
    results["profile"] = {"preset": "fast", "threads": 2, "steps": 10, "repeats": 10, "step_ms": 136.5,
                          "render_ms": 29.7, "train": block("step"), "render": block("render"),
                          "batch": {"rays_per_step": 2048, "num_samples": 32}}
    results["under_load"] = {"preset": "fast", "threads": 2, "openmp_waiting": "GOMP_SPINCOUNT=3000", "steps": 10,
                             "repeats": 10, "rounds": 3, "step_ms": 134.3, "render_ms": 23.8, "loaded_step_ms": 279.5,
                             "loaded_render_ms": 50.5, "step_slowdown": 2.08, "render_slowdown": 2.13}
    results["summary"] = tables.summarize(results)
    return results


def test_the_generated_page_is_the_users_page_and_stays_short(tmp_path):
    """`lift3d bench` regenerates docs/benchmarks.md: which preset, how good, how fast, the trade, how to reproduce
    each table; at most 400 lines with every section at full size, and no dated notes."""
    write_reports(_every_section(), BenchConfig(out=tmp_path, docs_dir=tmp_path / "docs"))
    md = (tmp_path / "docs" / "benchmarks.md").read_text()
    lines = md.splitlines()
    assert len(lines) <= 400, len(lines)
    assert [x for x in lines if x.startswith("## ")] == ["## Runs that failed", *PAGE_SECTIONS]
    subsections = [x for x in lines if x.startswith("### ")]
    for title in ("### Per-class IoU of the thing classes", "### Label noise and pose noise", "### Ablation",
                  "### Unbounded vs bounded space", "### Export: labelled points", "### Scaling",
                  "### Where the time goes", "### Under load: one busy neighbour",
                  "### Timing the render on a run of your own"):
        assert any(x.startswith(title) for x in subsections), title
    assert not any(re.search(r"\d{4}-\d{2}-\d{2}", x) for x in lines if x.startswith("#"))  # no dated sections
    # The failed run is a row with its one-line reason (the pipe escaped for the table).
    assert ("| runs | outdoor seed 1, moderate labels, with depth maps, `fast` | evaluation | run: the fused rendered "
            "depth has no surface \\| train longer |") in md
    # Which preset: the further preset against the first, paired by seed.
    assert "`balanced` against `fast` (indoor moderate RGB + depth, paired by seed): PSNR +2.10" in md
    assert "| chair | 0.81 (n=3) |" in md and "| cup |" not in md
    # Each table with the command that makes it again.
    for only in ("presets", "curves", "ablation", "bounded", "export", "scaling", "profile", "under-load"):
        assert f"`lift3d bench --only {only}`" in md, only


def test_the_checked_in_page_has_the_generated_pages_shape():
    """docs/benchmarks.md (tables measured by hand-run benchmarks of several days) keeps the generated page's
    sections, stays under 400 lines, and links only files that are in the repository."""
    md = (DOCS / "benchmarks.md").read_text()
    lines = md.splitlines()
    assert len(lines) <= 400, len(lines)
    assert [x for x in lines if x.startswith("## ")] == list(PAGE_SECTIONS)
    prose = re.sub(r"```.*?```", "", md, flags=re.S)
    for target in re.findall(r"\]\(([^)\s#]+)", prose):
        assert (DOCS / target).exists(), target
    for name in re.findall(r"[\w./-]+\.(?:md|py|yaml)\b", prose):
        assert (DOCS / name).exists() or (DOCS.parent / name).exists() or (DOCS.parent / "lift3d" / name).exists(), name


def test_inputs_column_is_what_the_run_records():
    """The run's own record wins (a run may say `RGB + SfM points`); older runs: from depth supervision."""
    assert run_inputs({"inputs": "RGB + SfM points", "depth_supervision": False}) == "RGB + SfM points"
    assert run_inputs({"inputs": None, "depth_supervision": True}) == "RGB + depth"
    assert run_inputs({"depth_supervision": False}) == "RGB"
    rows = tables.group_rows([_run(0, inputs="RGB + SfM points"), _run(1, inputs="RGB + SfM points")], ["scene"])
    assert rows[0]["inputs"] == "RGB + SfM points"


def test_tuning_seeds_are_called_development_numbers():
    assert "not used for tuning" in tables.seed_note([0, 1, 2])
    note = tables.seed_note([0, 1, 7])
    assert "tuning seeds" in note and "not used for tuning" not in note


# ------------------------------------------------------------------------------------------ plan and flags
def test_plan_lists_every_run_once_with_its_sections_and_an_estimate(tmp_path, capsys):
    cfg = BenchConfig(out=tmp_path, seeds=(100, 101))
    jobs = plan_jobs(cfg)
    caches = {j.cache for j in jobs}
    # presets: 2 scenes x 2 inputs x 2 noises + balanced 2 noises; curves: clean, hard + 2 pose levels; ablation
    # 5 x 2 modes; bounded: 1 (+ the shared unbounded run) -- per seed.
    assert len(caches) == 2 * (8 + 2 + 2 + 2 + 10 + 1)
    assert main(["bench", "--plan", "--out", str(tmp_path), "--seeds", "100,101"]) == 0
    out = capsys.readouterr().out
    assert "indoor_s100_moderate_fast_all (presets, label-noise curve, pose-noise curve, export)" in out
    assert "50 training runs: 0 cached, 50 to do" in out and " h of training" in out
    # A cached run is listed as such and no longer counted; its measured time calibrates the estimates.
    first = next(j for j in jobs if j.name == "run_indoor_s100_moderate_fast_all")
    first.cache.parent.mkdir(parents=True)
    first.cache.write_text(json.dumps({"steps": 1500, "train_seconds": 3000.0,
                                       "metrics": {"seconds": 100.0, "points3d": {"fscore": 0.9}}}))
    assert main(["bench", "--plan", "--out", str(tmp_path), "--seeds", "100,101", "--only", "presets"]) == 0
    out = capsys.readouterr().out
    assert "cached       0.0  indoor_s100_moderate_fast_all (presets)" in out
    assert "to do       51.7  indoor_s101_moderate_fast_all" in out  # 1500 x 2 s + 100 s
    assert "20 training runs: 1 cached, 19 to do" in out and not list(tmp_path.glob("scenes"))
    # --quick is a smoke test: by default it trains on tuning seeds, never on the reserved ones.
    assert main(["bench", "--plan", "--quick", "--out", str(tmp_path / "quick"), "--only", "presets"]) == 0
    out = capsys.readouterr().out
    assert "indoor_s100_moderate_fast_all" in out and "indoor_s101_" in out and "_s0_" not in out
    # Each ablation is a cost of its own: --ablation-modes time plans the equal-time variants only.
    assert main(["bench", "--plan", "--out", str(tmp_path), "--seeds", "100", "--only", "ablation",
                 "--ablation-modes", "time"]) == 0
    out = capsys.readouterr().out
    assert out.count("_equal-time (ablation)") == 5 and "_equal-steps" not in out
    # ... and --ablation-variants some of the variants (Base, the plain MLP, is most of the cost).
    assert main(["bench", "--plan", "--out", str(tmp_path), "--seeds", "100", "--only", "ablation",
                 "--ablation-modes", "steps", "--ablation-variants", "base+S,all"]) == 0
    out = capsys.readouterr().out
    assert out.count("(ablation)") == 2 and "base+S_equal-steps" in out and "all_equal-steps" in out


@pytest.mark.parametrize("argv, message", [
    (["--only", "presets,speed"], "--only: 'speed' is not a section"),
    (["--seeds", "0,0"], "--seeds: scene seeds must be distinct"),
    (["--inputs", "depth"], "--inputs: 'depth' is not one of"),
    (["--ablation-budget", "0"], "--ablation-budget"),
    (["--ablation-modes", "steps,wall"], "--ablation-modes: 'wall' is not one of steps, time"),
    (["--ablation-variants", "base,S"], "--ablation-variants: 'S' is not one of base, base+S,"),
])
def test_bad_flags_are_one_line_errors(argv, message, tmp_path, capfd):
    assert main(["bench", "--plan", "--out", str(tmp_path), *argv]) == 2
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_reevaluate_names_a_cached_run_whose_folder_is_gone(tmp_path, capfd, monkeypatch):
    monkeypatch.setenv("LIFT3D_NO_PROGRESS", "1")
    out = tmp_path / "bench"
    (out / "cache").mkdir(parents=True)
    cached = out / "cache" / "run_indoor_s100_moderate_fast_all.json"
    cached.write_text(json.dumps({"run": str(tmp_path / "gone"), "metrics": {}}))
    rc = main(["bench", "--quick", "--scenes", "indoor", "--presets", "fast", "--seeds", "100", "--only", "presets",
               "--inputs", "rgb+depth", "--noises", "moderate", "--reevaluate", "--out", str(out),
               "--docs-dir", str(tmp_path / "docs")])
    err = capfd.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and cached.name in err[0] and "is gone" in err[0], err
    assert json.loads(cached.read_text())["run"] == str(tmp_path / "gone")  # the cache is left as it was


def test_a_run_cached_for_other_settings_is_an_error_not_a_stand_in(tmp_path, capfd, monkeypatch):
    """An equal-time ablation run cached at another budget (same file name) must not stand in silently."""
    monkeypatch.setenv("LIFT3D_NO_PROGRESS", "1")
    out = tmp_path / "bench"
    (out / "cache").mkdir(parents=True)
    cached = out / "cache" / "run_indoor_s100_moderate_fast_base+S_equal-time.json"
    over = {"losses": {"depth": 0.0, "segment": 0.0, "feature": 0.0}, "trainer": {"time_budget": 300.0},
            "optim": {"steps": 100000}}
    cached.write_text(json.dumps({"run": str(tmp_path / "run"), "metrics": {},
                                  "spec": {"kind": "train", "preset": "fast", "seed": 100, "overrides": over}}))
    rc = main(["bench", "--seeds", "100", "--only", "ablation", "--ablation-modes", "time", "--ablation-variants",
               "base+S", "--ablation-budget", "600", "--out", str(out), "--docs-dir", str(tmp_path / "docs")])
    err = capfd.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and cached.name in err[0] and "'time_budget': 300.0" in err[0], err


# ------------------------------------------------------------------------------------------ end to end
def test_bench_quick_one_row_over_two_seeds(tmp_path, monkeypatch):
    """One preset-table row trained on two scene seeds (tiny scenes, few steps): the report shows mean ± std,
    the per-seed values are kept, a second run reuses the cache, --reevaluate recomputes the metrics only,
    and the export of the first indoor run is timed. (The other sections: tests/test_bench_sections.py.)"""
    monkeypatch.setenv("LIFT3D_NO_PROGRESS", "1")
    out, docs = tmp_path / "bench", tmp_path / "docs"

    def bench(seeds: str, only: str, *extra: str) -> int:
        return main(["bench", "--quick", "--scenes", "indoor", "--presets", "fast", "--seeds", seeds, "--noises",
                     "moderate", "--inputs", "rgb+depth", "--only", only, "--out", str(out), "--docs-dir", str(docs),
                     *extra])

    assert bench("100,101", "presets,export") == 0
    results = json.loads((out / "results.json").read_text())
    assert results["machine"]["cpu"] and results["machine"]["torch_threads"] >= 1 and results["seeds"] == [100, 101]
    runs = results["runs"]
    assert sorted(r["seed"] for r in runs) == [100, 101]
    for r in runs:
        assert (r["scene_depth"], r["depth_supervision"], r["inputs"]) == ("sensor", True, "RGB + depth")
        assert r["train_seconds"] > 0 and r["peak_rss_mb"] > 100 and r["render_ms_per_2048_rays"] > 0
        assert 0 <= r["miou"] <= 1 and 0 <= r["pq_scene"] <= 1 and r["psnr"] > 5
        assert r["pseudo_labels"]["miou"] is not None and r["points3d"]["fscore"] is not None
        assert r["points3d"]["n_pred_instances"] is not None
    row = results["summary"]["runs"][0]
    assert row["seeds"] == [100, 101] and row["metrics"]["miou"]["std"] is not None
    assert set(row["metrics"]["miou"]["per_seed"]) == {"100", "101"}
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert sorted(r["seed"] for r in rows) == ["100", "101"]
    ex = results["export"]
    assert ex["points"] > 0 and ex["seconds"] > 0 and ex["preset"] == "fast"
    assert ex["repeats"] == 1 and ex["all_seconds"] == [ex["seconds"]]  # --quick: one export
    md = (docs / "benchmarks.md").read_text()
    line = next(x for x in md.splitlines() if x.startswith("| indoor | moderate | RGB + depth | fast |"))
    miou = runs[0]["miou"], runs[1]["miou"]
    assert f"{(miou[0] + miou[1]) / 2:.3f} ± {abs(miou[0] - miou[1]) / 2 ** 0.5:.3f}" in line
    assert "**Seeds ≥ 5 are tuning seeds**" in md and "### Export: labelled points" in md
    assert (out / "pareto.png").is_file() and (docs / "images" / "bench_pareto.png").is_file()
    # Resumable: a second run reuses every cached measurement (same numbers).
    assert bench("100,101", "presets,export") == 0
    again = json.loads((out / "results.json").read_text())
    assert [r["train_seconds"] for r in again["runs"]] == [r["train_seconds"] for r in runs]
    # --reevaluate: metrics computed again from the cached run; training and render timing are kept.
    path = out / "cache" / "run_indoor_s100_moderate_fast_all.json"
    cached = json.loads(path.read_text())
    cached["metrics"]["points3d"]["miou"] = -1.0  # stale: must be replaced
    path.write_text(json.dumps(cached))
    assert bench("100", "presets", "--reevaluate") == 0
    third = json.loads((out / "results.json").read_text())
    (r,) = third["runs"]
    assert (r["train_seconds"], r["render_ms_per_2048_rays"]) == (runs[0]["train_seconds"],
                                                                  runs[0]["render_ms_per_2048_rays"])
    assert 0 <= r["points3d"]["miou"] <= 1 and r["reevaluated"]
    assert not list((out / "cache").glob("*.eval.json"))
    assert "`lift3d bench --reevaluate`" in (docs / "benchmarks.md").read_text()


def _fake_metrics(miou: float) -> dict:
    """What `lift3d eval` returns, as far as the benchmark's records read it."""
    return {"psnr": 30.0, "miou": miou, "pq_scene": 0.6, "sq_scene": 0.8, "rq_scene": 0.7,
            "render_ms_per_2048_rays": 20.0, "pseudo_labels": {"miou": 0.5, "pq_scene": 0.4},
            "points3d": {"fscore": 0.9, "miou": 0.7, "instance_recall": 1.0, "n_instances": 3, "n_pred_instances": 4}}


def test_a_failed_run_is_a_row_marked_failed_and_the_benchmark_goes_on(tmp_path, monkeypatch, capsys):
    """Training raises on one seed and the timed export raises too: both become rows marked failed with their
    one-line reason in results.json, results.csv and benchmarks.md; the other seed's row is there, and the exit
    code says some runs failed. (Nothing is trained: the trainer, the evaluation and the scene are stand-ins.)"""
    from types import SimpleNamespace

    import lift3d.bench.runner as runner

    monkeypatch.setenv("LIFT3D_NO_PROGRESS", "1")
    monkeypatch.setattr(runner, "_scene", lambda cfg, kind, seed, *a, **k: tmp_path / f"scene_{kind}_{seed}")

    def train(scene, preset, output_dir, overrides, **kw):
        if overrides["trainer"]["seed"] == 101:
            raise RuntimeError("simulated: the optimiser diverged\nat step 12")
        return SimpleNamespace(run=SimpleNamespace(path=tmp_path / "run100"), steps=40, seconds=1.5,
                               summary={"depth_supervision": True, "inputs": "RGB + depth"})

    def export(spec):
        raise InputError(spec["run"], "simulated: no checkpoint")

    monkeypatch.setattr(worker, "train", train)
    monkeypatch.setattr(worker, "evaluate_run", lambda run, options=None, **kw: _fake_metrics(0.8))
    monkeypatch.setattr(worker, "load_scene", lambda path: SimpleNamespace(categories=[]))
    monkeypatch.setattr(worker, "run_export", export)
    out, docs = tmp_path / "bench", tmp_path / "docs"
    rc = main(["bench", "--quick", "--scenes", "indoor", "--presets", "fast", "--seeds", "100,101", "--noises",
               "moderate", "--inputs", "rgb+depth", "--only", "presets,export", "--out", str(out), "--docs-dir",
               str(docs)])
    assert rc == 1
    printed = capsys.readouterr().out
    assert "2 measurements failed" in printed
    results = json.loads((out / "results.json").read_text())
    assert [r["seed"] for r in results["runs"]] == [100]
    trained, exported = results["failed"]
    assert (trained["seed"], trained["stage"], trained["status"]) == (101, "training", "failed")
    assert trained["reason"] == "RuntimeError: simulated: the optimiser diverged | at step 12"
    assert trained["sections"] == ["runs"] and "Traceback" in Path(trained["log"]).read_text()
    assert exported["stage"] == "export" and exported["reason"].endswith("run100: simulated: no checkpoint")
    assert not (out / "cache" / "run_indoor_s101_moderate_fast_all.json").exists()  # tried again next time
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert [(r["seed"], r["status"]) for r in rows] == [("100", "ok"), ("101", "failed"), ("", "failed")]
    assert rows[1]["reason"] == "training: RuntimeError: simulated: the optimiser diverged | at step 12"
    md = (docs / "benchmarks.md").read_text()
    assert ("| runs | indoor seed 101, moderate labels, with depth maps, `fast` | training | RuntimeError: simulated: "
            "the optimiser diverged \\| at step 12 |") in md
    assert "| indoor | moderate | RGB + depth | fast (n=1) |" in md  # the row averages over the seed that finished


def test_a_worker_process_that_fails_says_where_and_why(tmp_path):
    """Out of process (the full benchmark's way), a failing measurement writes no result; the runner reads the
    worker's stage and one-line reason and keeps its stderr."""
    from lift3d.bench.runner import _worker

    out = tmp_path / "cache" / "export_indoor_fast_r0.json"
    with pytest.raises(worker.MeasurementFailed) as info:
        _worker({"kind": "export", "run": str(tmp_path / "gone")}, out)
    assert info.value.stage == "export" and str(tmp_path / "gone") in info.value.reason
    assert "\n" not in info.value.reason and not out.exists()
    assert Path(info.value.log).read_text().strip() and not worker.failure_path(out).exists()


def test_quick_runs_give_a_street_with_depth_maps_a_surface_to_export(tmp_path):
    """`lift3d bench --quick` stopped at its first outdoor run with depth maps: exported from the fused rendered
    depth (`--source auto`), a street trained 10 steps is opaque only at its contracted background, beyond the
    fused cube. The export now says so, and the quick settings train long enough for a surface."""
    from lift3d.bench.runner import _QUICK_SCENE, _QUICK_TRAIN, _merge
    from lift3d.bench.worker import run_train
    from lift3d.export.pointcloud import extract_labelled_points
    from lift3d.model.run import load_run
    from lift3d.synth import SynthOptions, make_scene
    from lift3d.train.trainer import train

    scene = tmp_path / "street"
    make_scene(scene, SynthOptions(kind="outdoor", seed=100, noise="moderate", depth="sensor", **_QUICK_SCENE),
               progress=False)
    ten = train(scene, preset="fast", output_dir=tmp_path / "ten", progress=False, print_summary=False,
                overrides=_merge(_QUICK_TRAIN, {"optim": {"steps": 10}, "trainer": {"seed": 100}}))
    loaded = load_run(ten.run.path, "cpu")
    with pytest.raises(InputError, match="opaque only beyond the fused cube .* no foreground surface yet"):
        extract_labelled_points(loaded, loaded.scene(), num_points=1000)
    res = run_train({"scene": str(scene), "preset": "fast", "seed": 100, "overrides": _QUICK_TRAIN,
                     "output_dir": str(tmp_path / "quick"), "num_points": 5000, "timing_repeats": 1})
    p3 = res["metrics"]["points3d"]
    assert p3["source"] == "export.tsdf" and p3["fscore"] is not None and res["metrics"]["instances_from"] == "export"


def test_under_load_measures_step_and_render_alone_and_beside_a_busy_neighbour(tmp_path):
    from lift3d.bench.runner import _QUICK_TRAIN, under_load_markdown
    from lift3d.bench.worker import run_under_load
    from lift3d.synth import SynthOptions, make_scene

    scene = tmp_path / "room"
    make_scene(scene, SynthOptions(kind="indoor", seed=105, noise="moderate", n_views=6, width=32, height=32),
               progress=False)
    res = run_under_load({"scene": str(scene), "preset": "fast", "overrides": _QUICK_TRAIN,
                          "output_dir": str(tmp_path / "runs"), "warmup": 1, "steps": 1, "repeats": 1, "rounds": 1,
                          "settle_seconds": 0.1})
    for key in ("step_ms", "render_ms", "loaded_step_ms", "loaded_render_ms", "step_slowdown", "render_slowdown"):
        assert res[key] > 0, key  # numbers only: no timing is asserted
    text = "\n".join(under_load_markdown(res))
    assert "### Under load" in text and "slowdown" in text


def test_a_narrowed_run_leaves_the_checkouts_benchmark_page_alone(tmp_path, monkeypatch, capsys):
    """Without --docs-dir only a full run regenerates docs/benchmarks.md: a run narrowed to one scene kind would
    replace the whole page with its two rows."""
    import lift3d.bench.runner as runner

    seen = []

    def fake_run(cfg):
        seen.append(cfg.docs_dir)
        return {"runs": [], "curves": {}, "ablation": [], "scaling": []}

    monkeypatch.setattr(runner, "run_benchmark", fake_run)
    assert main(["bench", "--scenes", "indoor", "--seeds", "0,1,2", "--out", str(tmp_path / "b")]) == 0
    assert seen[-1] is None and "partial run (--scenes)" in capsys.readouterr().out
    assert main(["bench", "--only", "presets", "--out", str(tmp_path / "b"), "--docs-dir", str(tmp_path / "d")]) == 0
    assert seen[-1] == tmp_path / "d"
    assert main(["bench", "--seeds", "0,1,2", "--out", str(tmp_path / "b")]) == 0
    assert seen[-1] is not None and seen[-1].name == "docs"  # a full run: the checkout's docs/
