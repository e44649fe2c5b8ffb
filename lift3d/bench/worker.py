"""One benchmark measurement in its own process, so that peak memory (RSS) belongs to that run alone.

``python -m lift3d.bench.worker SPEC.json OUT.json`` where SPEC is one of:

* ``{"kind": "train", "scene": DIR, "preset": NAME, "seed": N, "overrides": {...}, "output_dir": DIR}``:
  train, then ``lift3d eval`` (2D, pseudo-label baseline, 3D through the export path, render timing).
* ``{"kind": "scaling", "scene": DIR, "overrides": {...}, "steps": N, "repeats": N}``: median training-step
  and render times of a model built for that scene, and the peak memory.

The result is written atomically to OUT.json; the benchmark skips specs whose result already exists.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from lift3d.utils.atomic import write_json_atomic
from lift3d.utils.memory import peak_rss_mb


def run_train(spec: dict) -> dict:
    from lift3d.eval.evaluate import evaluate_run, json_safe
    from lift3d.train.trainer import train

    overrides = json.loads(json.dumps(spec.get("overrides", {})))
    overrides.setdefault("trainer", {})["seed"] = int(spec.get("seed", 0))
    start = time.perf_counter()
    result = train(spec["scene"], preset=spec["preset"], output_dir=spec["output_dir"], overrides=overrides,
                   progress=bool(spec.get("progress", False)), print_summary=False)
    train_wall = time.perf_counter() - start
    rss_train = peak_rss_mb()  # the peak only grows: read it before evaluation adds its own
    metrics = evaluate_run(result.run.path, split="test", progress=False, num_points=int(spec.get("num_points", 200_000)),
                           timing_repeats=int(spec.get("timing_repeats", 10)))
    return json_safe({
        "run": str(result.run.path),
        "steps": result.steps,
        "train_seconds": result.seconds,
        "train_wall_seconds": train_wall,
        "peak_rss_mb": rss_train,
        "depth_supervision": bool(result.summary.get("depth_supervision", False)),
        "metrics": metrics,
    })


def run_scaling(spec: dict) -> dict:
    import numpy as np
    import torch

    from lift3d.data.scene import load_scene
    from lift3d.train.run import RunFolder
    from lift3d.train.trainer import Trainer, resolve_config
    from lift3d.utils.device import set_threads

    threads = set_threads()
    scene = load_scene(spec["scene"])
    cfg, norm = resolve_config(scene, spec.get("preset", "fast"), spec.get("overrides", {}))
    run = RunFolder.create(spec["output_dir"], scene.name, cfg.preset)
    trainer = Trainer(scene, cfg, norm, run, torch.device("cpu"), progress=False)
    warmup, steps = int(spec.get("warmup", 10)), int(spec.get("steps", 20))
    times = []
    for k in range(warmup + steps):
        t0 = time.perf_counter()
        trainer.train_step()
        trainer.step += 1
        if k >= warmup:
            times.append(time.perf_counter() - t0)
    model = trainer.model.eval()
    o, d, _, _ = trainer.rays.image_rays(int(scene.split("test")[0]))
    o, d = o[:2048], d[:2048]
    render = []
    for k in range(2 + int(spec.get("repeats", 10))):
        t0 = time.perf_counter()
        model.render_chunked(o, d, chunk_size=2048)
        if k >= 2:
            render.append(time.perf_counter() - t0)
    return {
        "step_ms": 1e3 * float(np.median(times)),
        "render_ms": 1e3 * float(np.median(render)),
        "peak_rss_mb": peak_rss_mb(),
        "threads": threads,
        "grid_resolution": cfg.field.grid_max_resolution,
        "instance_channels": cfg.field.num_instance_channels,
        "semantic_classes": cfg.field.num_semantic_classes,
        "pixels": int(trainer.data.num_pixels),
    }


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    spec = json.loads(Path(argv[0]).read_text())
    out = Path(argv[1])
    result = run_train(spec) if spec["kind"] == "train" else run_scaling(spec)
    result["spec"] = spec
    write_json_atomic(out, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
