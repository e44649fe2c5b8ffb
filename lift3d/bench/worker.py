"""One benchmark measurement in its own process, so that peak memory (RSS) belongs to that run alone.

``python -m lift3d.bench.worker SPEC.json OUT.json`` where SPEC is one of:

* ``{"kind": "train", "scene": DIR, "preset": NAME, "seed": N, "overrides": {...}, "output_dir": DIR}``:
  train, then ``lift3d eval`` (2D, pseudo-label baseline, 3D through the export path, render timing).
* ``{"kind": "scaling", "scene": DIR, "overrides": {...}, "steps": N, "repeats": N}``: median training-step
  and render times of a model built for that scene, and the peak memory.
* ``{"kind": "export", "run": RUN, "num_points": N}``: time and peak memory of a labelled point-cloud export
  of a trained run (:func:`lift3d.export.pointcloud.benchmark_export`).
* ``{"kind": "profile", "scene": DIR, "preset": NAME, "steps": N, "repeats": N}``: where the time of one
  training step and of one 2048-ray render goes (``torch.profiler``: the named stages and the operators with
  the most self time), next to the unprofiled medians.
* ``{"kind": "under_load", "scene": DIR, "preset": NAME, "steps": N, "repeats": N, "rounds": N}``: training
  step and 2048-ray render alone and beside one busy 2-thread process (:data:`BUSY_NEIGHBOUR`), in
  interleaved rounds; medians and the slowdown.

The result is written atomically to OUT.json; the benchmark skips specs whose result already exists. A
measurement that fails (training, evaluation, export, ...) writes no result: it raises :class:`MeasurementFailed`
in-process, and as a process writes OUT.failed.json (stage, one-line reason, traceback) and exits with 1, so that
the benchmark reports it as a failed row and goes on.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import traceback
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch
from torch.profiler import ProfilerActivity, profile

from lift3d.data.scene import load_scene
from lift3d.errors import Lift3DError
from lift3d.eval.evaluate import EvalOptions, evaluate_run, json_safe
from lift3d.export.pointcloud import benchmark_export
from lift3d.model.run_folder import RunFolder
from lift3d.train.trainer import Trainer, resolve_config, train
from lift3d.utils.atomic import write_json_atomic
from lift3d.utils.device import set_threads
from lift3d.utils.memory import peak_rss_mb
from lift3d.utils.threads import openmp_waiting


class MeasurementFailed(Exception):
    """A measurement that did not finish: the ``stage`` it stopped in (``training``, ``evaluation``, ``export``,
    ...), a one-line ``reason`` and the ``details`` (the traceback, or the end of the worker's stderr)."""

    def __init__(self, stage: str, reason: str, details: str = "", log: str | None = None):
        super().__init__(f"{stage}: {reason}")
        self.stage, self.reason, self.details = stage, reason, details
        #: The file that keeps ``details`` (set by the benchmark runner).
        self.log = log


def one_line(exc: BaseException) -> str:
    r"""An exception as one line: lift3d's own errors as they read on the CLI, others with their type.

    Examples
    --------
    >>> one_line(RuntimeError("CUDA out of memory.\nTried to allocate 2 GiB"))
    'RuntimeError: CUDA out of memory. | Tried to allocate 2 GiB'
    """
    text = " | ".join(part.strip() for part in str(exc).splitlines() if part.strip())
    if isinstance(exc, Lift3DError):
        return text or type(exc).__name__
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


@contextmanager
def stage(name: str):
    """Turn any error of the block into :class:`MeasurementFailed` naming the stage (Ctrl-C still stops)."""
    try:
        yield
    except MeasurementFailed:
        raise
    except Exception as exc:
        raise MeasurementFailed(name, one_line(exc), traceback.format_exc()) from exc


def _eval_options(spec: dict) -> EvalOptions:
    """The test-split evaluation a spec asks for (``num_points``, ``timing_repeats``, ``points3d``)."""
    return EvalOptions(split="test", num_points=int(spec.get("num_points", 200_000)),
                       timing_repeats=int(spec.get("timing_repeats", 10)),
                       with_points3d=bool(spec.get("points3d", True)))


def run_train(spec: dict) -> dict:
    overrides = json.loads(json.dumps(spec.get("overrides", {})))
    overrides.setdefault("trainer", {})["seed"] = int(spec.get("seed", 0))
    start = time.perf_counter()
    with stage("training"):
        result = train(spec["scene"], preset=spec["preset"], output_dir=spec["output_dir"], overrides=overrides,
                       progress=bool(spec.get("progress", False)), print_summary=False)
    train_wall = time.perf_counter() - start
    rss_train = peak_rss_mb()  # the peak only grows: read it before evaluation adds its own
    with stage("evaluation"):  # the 3D metrics' labelled export included
        metrics = evaluate_run(result.run.path, _eval_options(spec), progress=False)
    return json_safe({
        "run": str(result.run.path),
        "steps": result.steps,
        "train_seconds": result.seconds,
        "train_wall_seconds": train_wall,
        "peak_rss_mb": rss_train,
        "depth_supervision": bool(result.summary.get("depth_supervision", False)),
        # What the run trained on and whether it refined its poses, as the run records them (None: the
        # benchmark derives the inputs from depth_supervision, runner.run_inputs).
        "inputs": result.summary.get("inputs"),
        "pose_refinement": bool(result.summary.get("pose_refinement", False)),
        # The scene's thing classes by id: the report's per-class table names the classes of per_class_iou_strict.
        "thing_classes": {str(c.id): c.name for c in load_scene(spec["scene"]).categories if c.isthing},
        "metrics": metrics,
    })


def run_evaluate(spec: dict) -> dict:
    """Evaluate an existing run folder again (``lift3d bench --reevaluate``)."""
    metrics = evaluate_run(spec["run"], _eval_options(spec), progress=False)
    return json_safe({"run": spec["run"], "metrics": metrics})


def _trainer(spec: dict):
    """A fresh trainer for the spec's scene and preset (CPU), and the thread count in use."""
    threads = set_threads()
    scene = load_scene(spec["scene"])
    cfg, norm = resolve_config(scene, spec.get("preset", "fast"), spec.get("overrides", {}))
    run = RunFolder.create(spec["output_dir"], scene.name, cfg.preset)
    return Trainer(scene, cfg, norm, run, torch.device("cpu"), progress=False), scene, cfg, threads


def _one_step(trainer) -> None:
    """One training step, advancing the step counter as ``Trainer.fit`` does (the schedule follows it)."""
    trainer.train_step()
    trainer.step += 1


def _timed_steps(trainer, n: int) -> list[float]:
    """Seconds of each of ``n`` training steps."""
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        _one_step(trainer)
        times.append(time.perf_counter() - t0)
    return times


def _render_rays(trainer, scene):
    """The first 2048 rays of the first test view, and a function that renders them once."""
    model = trainer.model.eval()
    o, d, _, _ = trainer.rays.image_rays(int(scene.split("test")[0]))
    o, d = o[:2048], d[:2048]
    return lambda: model.render_chunked(o, d, chunk_size=2048)


def _timed_calls(fn, n: int, warmup: int = 2) -> list[float]:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def run_scaling(spec: dict) -> dict:
    trainer, scene, cfg, threads = _trainer(spec)
    warmup, steps = int(spec.get("warmup", 10)), int(spec.get("steps", 20))
    times = _timed_steps(trainer, warmup + steps)[warmup:]
    render = _timed_calls(_render_rays(trainer, scene), int(spec.get("repeats", 10)))
    return {
        "step_ms": 1e3 * float(np.median(times)),
        "render_ms": 1e3 * float(np.median(render)),
        "peak_rss_mb": peak_rss_mb(),
        "threads": threads,
        "grid_resolution": trainer.model.field.finest_resolution,
        "instance_channels": cfg.field.num_instance_channels,
        "semantic_classes": cfg.field.num_semantic_classes,
        "pixels": int(trainer.data.num_pixels),
    }


def _profile_table(fn, calls: int, top: int) -> dict:
    """Profile ``calls`` calls of ``fn``: named stages (inclusive) and top operators (self time), ms per call."""
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(calls):
            fn()
    events = prof.key_averages()
    total_self = sum(e.self_cpu_time_total for e in events) or 1.0
    # Our own record_function labels ("step.*", "render.*") nest, so they are reported inclusive.
    stages = [{"name": e.key, "ms": e.cpu_time_total / 1e3 / calls, "calls": e.count / calls}
              for e in events if e.key.startswith(("step.", "render."))]
    ops = [{"name": e.key, "self_ms": e.self_cpu_time_total / 1e3 / calls,
            "percent": 100.0 * e.self_cpu_time_total / total_self, "calls": e.count / calls}
           for e in sorted(events, key=lambda e: -e.self_cpu_time_total)
           if not e.key.startswith(("step.", "render."))][:top]
    return {"profiled_ms": total_self / 1e3 / calls, "stages": sorted(stages, key=lambda r: -r["ms"]), "ops": ops}


def run_profile(spec: dict) -> dict:
    """Where a training step and a 2048-ray render spend their time (after warm-up, one process)."""
    trainer, scene, cfg, threads = _trainer(spec)
    warmup, steps, top = int(spec.get("warmup", 10)), int(spec.get("steps", 10)), int(spec.get("top", 12))
    step_times = _timed_steps(trainer, warmup + steps)[warmup:]
    step_profile = _profile_table(lambda: _one_step(trainer), steps, top)
    render_fn = _render_rays(trainer, scene)
    repeats = int(spec.get("repeats", 10))
    render_times = _timed_calls(render_fn, repeats)
    render = _profile_table(render_fn, repeats, top)
    return {
        "preset": cfg.preset, "threads": threads, "steps": steps, "repeats": repeats,
        "step_ms": 1e3 * float(np.median(step_times)), "render_ms": 1e3 * float(np.median(render_times)),
        "train": step_profile, "render": render,
        "batch": {"images_per_batch": cfg.data.images_per_batch, "rays_per_image": cfg.data.rays_per_image,
                  "patch_size": cfg.data.patch_size, "segments_per_image": cfg.data.segments_per_image,
                  "rays_per_segment": cfg.data.rays_per_segment, "rays_per_step": cfg.data.rays_per_step,
                  "num_samples": cfg.sampling.num_samples},
    }


#: The neighbour of the "under load" measurement: a process keeping 2 OpenMP threads busy with matrix
#: products (as another training would), with OpenMP's default wait policy (it is not lift3d).
BUSY_NEIGHBOUR = ("import torch\ntorch.set_num_threads(2)\na = torch.randn(384, 384)\n"
                  "while True:\n    a = torch.tanh(a @ a)\n")


def _busy_neighbour() -> subprocess.Popen:
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "LIFT3D_THREADS")}
    env["OMP_NUM_THREADS"] = "2"
    return subprocess.Popen([sys.executable, "-c", BUSY_NEIGHBOUR], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)


def run_under_load(spec: dict) -> dict:
    """A training step and a 2048-ray render alone and with one busy 2-thread neighbour, in ``rounds``
    alternating rounds (alone, loaded, alone, ...) so that drifts of the machine's load hit both alike."""
    trainer, scene, cfg, threads = _trainer(spec)
    warmup, steps, repeats = int(spec.get("warmup", 5)), int(spec.get("steps", 10)), int(spec.get("repeats", 10))
    _timed_steps(trainer, warmup)
    render_fn = _render_rays(trainer, scene)
    times: dict[str, dict[str, list[float]]] = {"alone": {"step": [], "render": []},
                                                 "loaded": {"step": [], "render": []}}
    for _ in range(int(spec.get("rounds", 3))):
        for condition in ("alone", "loaded"):
            neighbour = _busy_neighbour() if condition == "loaded" else None
            try:
                if neighbour is not None:
                    time.sleep(float(spec.get("settle_seconds", 1.0)))  # the neighbour's threads are running
                trainer.model.train()
                times[condition]["step"] += _timed_steps(trainer, steps)
                trainer.model.eval()
                times[condition]["render"] += _timed_calls(render_fn, repeats, warmup=1)
            finally:
                if neighbour is not None:
                    neighbour.kill()
                    neighbour.wait()
    med = {c: {k: 1e3 * float(np.median(v)) for k, v in t.items()} for c, t in times.items()}
    return {
        "preset": cfg.preset, "threads": threads, "openmp_waiting": openmp_waiting(),
        "steps": steps, "repeats": repeats, "rounds": int(spec.get("rounds", 3)),
        "step_ms": med["alone"]["step"], "render_ms": med["alone"]["render"],
        "loaded_step_ms": med["loaded"]["step"], "loaded_render_ms": med["loaded"]["render"],
        "step_slowdown": med["loaded"]["step"] / med["alone"]["step"],
        "render_slowdown": med["loaded"]["render"] / med["alone"]["render"],
    }


def run_export(spec: dict) -> dict:
    set_threads()
    return benchmark_export(spec["run"], num_points=int(spec.get("num_points", 1_000_000)))


#: The stage a measurement fails in when no finer stage says (``train`` names its two, training and evaluation).
KIND_STAGES = {"train": "training or evaluation", "evaluate": "evaluation", "scaling": "scaling",
               "profile": "profile", "export": "export", "under_load": "under load"}


def measure(spec: dict) -> dict:
    """The measurement ``spec`` asks for, with the spec in it; :class:`MeasurementFailed` when it fails."""
    kinds = {"train": run_train, "evaluate": run_evaluate, "scaling": run_scaling, "profile": run_profile,
             "export": run_export, "under_load": run_under_load}
    with stage(KIND_STAGES.get(spec["kind"], spec["kind"])):
        result = kinds[spec["kind"]](spec)
    result["spec"] = spec
    return result


def failure_path(out: Path) -> Path:
    """Where a worker process says why its measurement failed: OUT.failed.json beside OUT.json."""
    return out.with_name(out.stem + ".failed.json")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    spec = json.loads(Path(argv[0]).read_text())
    out = Path(argv[1])
    failure_path(out).unlink(missing_ok=True)
    try:
        result = measure(spec)
    except MeasurementFailed as exc:
        write_json_atomic(failure_path(out), {"stage": exc.stage, "reason": exc.reason, "details": exc.details})
        print(exc.details, file=sys.stderr)
        return 1
    write_json_atomic(out, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
