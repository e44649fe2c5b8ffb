"""``lift3d demo``: the main job, end to end, on a built-in synthetic scene.

synthesise a scene → train (``fast`` preset) → evaluate (2D and 3D, beside the pseudo-label baseline) →
export the labelled point cloud and mesh → pictures → a short summary (files, metrics, time per stage).
Everything lands in one output folder::

    demo_out/
      scene/                 the synthetic scene folder (lift3d synth)
      runs/<scene>/<preset>/<stamp>/   the run folder (config.yml, checkpoints/, metrics.json, ...)
      export/                points.ply, mesh.ply, instances.json, classes.json, metadata.json
      pictures/              points_iso.png (instances | classes), views.png, curves.png
      summary.json           what the printed summary says, machine-readable
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lift3d.eval.evaluate import EvalOptions, evaluate_run
from lift3d.export import export_run
from lift3d.synth import SynthOptions, make_scene
from lift3d.train.trainer import train
from lift3d.utils.atomic import write_json_atomic
from lift3d.viz.points import PlotStyle, save_views
from lift3d.viz.run import plot_run

# Tiny settings (--quick, used by the test suite): every stage and code path, about a minute.
QUICK = {
    "scene": {"n_views": 12, "width": 40, "height": 40},
    "train": {
        "field": {"grid": {"resolution_cap": 32, "min_resolution": 16, "head_hidden_dim": 32}},
        "sampling": {"proposal_resolutions": [24], "proposal_samples": [32], "num_samples": 16},
        "data": {"images_per_batch": 4, "rays_per_image": 64, "patch_size": 8},
        "optim": {"steps": 60, "warmup_steps": 5},
        "trainer": {"eval_every": 30, "eval_images": 2, "checkpoint_every": 30},
    },
    "num_points": 30_000,
    "mesh_resolution": 64,
}


@dataclass
class DemoResult:
    output_dir: Path
    files: dict[str, Path]
    metrics: dict[str, Any]
    stages: dict[str, float]


def run_demo(output_dir: str | Path = "demo_out", *, kind: str = "indoor", preset: str = "fast", seed: int = 0,
             quick: bool = False, progress: bool = True, print_summary: bool = True) -> DemoResult:
    """Run every stage; see the module docstring. Returns where everything is and the key metrics."""
    out = Path(output_dir)
    out.mkdir(parents=True, exist_ok=True)
    stages: dict[str, float] = {}
    files: dict[str, Path] = {}

    def stage(name: str):
        class _Timer:
            def __enter__(self_inner):
                self_inner.t0 = time.perf_counter()
                if progress:
                    print(f"lift3d demo: {name} ...", flush=True)

            def __exit__(self_inner, *exc):
                stages[name] = time.perf_counter() - self_inner.t0
        return _Timer()

    scene_dir = out / "scene"
    with stage("synthesise"):
        scene_args = QUICK["scene"] if quick else {}
        make_scene(scene_dir, SynthOptions(kind=kind, seed=seed, noise="moderate", **scene_args), progress=progress)
    files["scene"] = scene_dir

    with stage("train"):
        overrides = QUICK["train"] if quick else {}
        overrides = {**overrides, "trainer": {**overrides.get("trainer", {}), "seed": seed}}
        result = train(scene_dir, preset=preset, output_dir=out / "runs", overrides=overrides, progress=progress,
                       print_summary=False)
    files["run"] = result.run.path

    with stage("evaluate"):
        options = EvalOptions(split="test", num_points=QUICK["num_points"] if quick else 200_000,
                              timing_repeats=3 if quick else 10)
        metrics = evaluate_run(result.run.path, options, progress=progress)
    files["metrics"] = result.run.metrics_path

    with stage("export"):
        export_dir = out / "export"
        export_run(result.run.path, export_dir, pointcloud=True, mesh=True, formats=("ply", "pcd"),
                   resolution=QUICK["mesh_resolution"] if quick else 256,
                   num_points=QUICK["num_points"] if quick else 1_000_000, progress=progress)
    for name in ("points.ply", "points.pcd", "mesh.ply", "instances.json", "classes.json", "metadata.json"):
        files[name] = export_dir / name

    with stage("pictures"):
        pictures = out / "pictures"
        shots = save_views(export_dir / "points.ply", pictures, views=("iso",), style=PlotStyle(boxes=True),
                           stem="points")
        files["points picture"] = shots[0]
        run_pics = plot_run(result.run.path, pictures, frames=3)
        for key, path in run_pics.items():
            files[f"{key} picture"] = path

    summary = {
        "output_dir": str(out.resolve()),
        "files": {k: str(v) for k, v in files.items()},
        "stages_seconds": stages,
        "total_seconds": sum(stages.values()),
        "metrics": {k: metrics.get(k) for k in ("psnr", "miou", "pq_scene", "sq_scene", "rq_scene",
                                                 "render_ms_per_2048_rays")},
        "pseudo_labels": {k: (metrics.get("pseudo_labels") or {}).get(k) for k in ("miou", "pq_scene", "sq_scene",
                                                                                  "rq_scene")},
        "points3d": {k: (metrics.get("points3d") or {}).get(k) for k in ("fscore", "miou", "miou_strict", "pq",
                                                                            "chamfer", "instance_recall",
                                                                            "n_instances")},
        "train": {"steps": result.steps, "seconds": result.seconds, "peak_rss_mb": result.peak_rss_mb},
    }
    write_json_atomic(out / "summary.json", summary)
    files["summary"] = out / "summary.json"
    if print_summary:
        print(format_summary(summary))
    return DemoResult(out, files, metrics, stages)


def _f(x: Any, nd: int = 3) -> str:
    return "  –  " if x is None else f"{x:.{nd}f}"


def metrics_block(s: dict) -> list[str]:
    """The printed summary's table of results (README.md shows it, from one run; tests/test_demo.py keeps the two
    in the same format)."""
    m, p, d = s["metrics"], s["pseudo_labels"], s["points3d"]
    return [
        "  test views        lifted   2D pseudo-labels",
        f"  mIoU              {_f(m['miou'])}    {_f(p['miou'])}",
        f"  PQ^scene          {_f(m['pq_scene'])}    {_f(p['pq_scene'])}",
        f"  SQ / RQ           {_f(m['sq_scene'], 2)}/{_f(m['rq_scene'], 2)}  {_f(p['sq_scene'], 2)}/{_f(p['rq_scene'], 2)}",
        f"  PSNR              {_f(m['psnr'], 2)} dB",
        f"  3D vs GT points   F-score {_f(d['fscore'])}, point mIoU {_f(d['miou'])} (strict "
        f"{_f(d.get('miou_strict'))}), point PQ {_f(d['pq'])}",
        f"  objects found     {_f(d['instance_recall'], 2)} of {d['n_instances']} GT objects (point IoU > 0.5)",
        f"  render            {_f(m['render_ms_per_2048_rays'], 1)} ms per 2048 rays",
    ]


def format_summary(s: dict) -> str:
    f = s["files"]
    lines = [
        "",
        "lift3d demo: done in {:.0f} s ({})".format(
            s["total_seconds"], ", ".join(f"{k} {v:.0f} s" for k, v in s["stages_seconds"].items())),
        "",
        *metrics_block(s),
        "",
        "  files",
        f"    scene           {f['scene']}",
        f"    run             {f['run']}",
        f"    metrics         {f['metrics']}",
        f"    point cloud     {f['points.ply']}  (+ points.pcd, instances.json, classes.json)",
        f"    mesh            {f['mesh.ply']}",
        f"    pictures        {Path(f['points picture']).parent}/",
        "",
        "  look at it:  lift3d plot " + f["points.ply"] + " --show",
    ]
    return "\n".join(lines)
