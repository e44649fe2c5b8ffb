"""``lift3d bench``: the speed/accuracy trade of the presets over several scenes, robustness to label and pose
noise, the paper's ablation, and how cost scales.

Everything is measured on this machine in one benchmark run (the report names the CPU and thread count).
Every accuracy row is trained once per **scene seed** (default 0, 1, 2: each a different synthetic room or
street, camera path and noise, from ``lift3d synth``) and reported as mean ± standard deviation over the
seeds, with the per-seed values kept in ``results.json`` / ``results.csv``. Seeds 0–4 are reserved for these
numbers: nothing was tuned on them (tuning used seeds ≥ 5), and the report says so only when that holds.

Sections (``--only`` picks some; ``--plan`` lists every run with an estimated time and trains nothing):

* **presets** — indoor and outdoor × inputs {RGB only, RGB + sensor depth} × label noise {moderate,
  view-correlated} at the first preset (``fast``), and the further presets (``balanced``) for indoor
  RGB + depth: training wall time and peak memory, ms to render 2048 rays, PSNR, mIoU, PQ^scene/SQ/RQ, 3D
  F-score and point mIoU of the export, objects found and instances exported, and the same 2D metrics of the
  pseudo-labels for the same frames;
* **curves** — PQ^scene and mIoU of the lifted field and of its pseudo-labels as label noise grows (clean →
  moderate → hard → view-correlated) and as pose noise grows (0, 0.5°/2 cm, 1°/5 cm; test views scored at
  their true poses), indoor, first preset, RGB + depth;
* **ablation** (paper Table 6) — Base (plain MLP field), +S (the voxel-grid model), +L_seg, +L_feat, all, on
  RGB only, at equal steps and at equal wall time; each change's sign is tested with paired differences
  over the seeds (significant when the mean is more than 2 standard errors from 0);
* **bounded** — the outdoor scene with a bounded field, against the contracted one of the preset table;
* **scaling** — training-step and render time and peak memory against image resolution, number of views,
  instance channels V and semantic classes U;
* **export** — time and peak memory of a 1M-point labelled export of the first indoor run;
* **profile** — where one training step and one 2048-ray render of the first preset spend their time
  (``torch.profiler``: named stages and the operators with the most self time);
* **under load** — the same training step and render alone and beside one busy 2-thread process, and the
  slowdown.

Each measurement runs in its own process (:mod:`lift3d.bench.worker`) and is cached as JSON under
``OUT/cache``: an interrupted benchmark resumes where it stopped. Results: ``OUT/results.json``,
``OUT/results.csv``, ``OUT/pareto.png``, ``OUT/noise_curves.png``, ``OUT/scaling.png``, ``OUT/benchmarks.md``
(and, with ``docs_dir``, ``docs/benchmarks.md`` plus its pictures).
"""

from __future__ import annotations

import csv
import dataclasses
import datetime as _dt
import io
import json
import os
import platform
import statistics
import subprocess
import sys
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from lift3d import __version__
from lift3d.bench import tables, worker
from lift3d.bench.tables import REPORT_SEEDS
from lift3d.errors import InputError
from lift3d.field import native
from lift3d.model.config import load_config
from lift3d.model.loss_terms import LossConfig
from lift3d.synth import SynthOptions, make_scene
from lift3d.utils.atomic import write_json_atomic, write_text_atomic
from lift3d.utils.device import available_cpus, default_threads
from lift3d.utils.progress import progress_bar
from lift3d.utils.threads import openmp_waiting
from lift3d.viz.bench import plot_noise_curves, plot_pareto, plot_scaling

#: The paper's L_feat weight: the presets keep L_feat off (docs/presets.md), the ablation switches it on.
PAPER_FEATURE_WEIGHT = LossConfig().feature
#: Ablation variants of the paper's Table 6: name → overrides.
ABLATION = {
    "base": {"field": {"kind": "mlp"}, "losses": {"segment": 0.0, "feature": 0.0}},
    "base+S": {"losses": {"segment": 0.0, "feature": 0.0}},
    "base+S+L_seg": {"losses": {"feature": 0.0}},
    "base+S+L_feat": {"losses": {"segment": 0.0, "feature": PAPER_FEATURE_WEIGHT}},
    "all": {"losses": {"feature": PAPER_FEATURE_WEIGHT}},
}
#: The ablation's two comparisons: every variant trains the same number of steps, or for the same wall time.
ABLATION_MODES = ("steps", "time")
#: Every ablation variant trains on RGB only, as the paper does (the synthetic scenes ship depth maps, which
#: the presets would otherwise use).
ABLATION_COMMON = {"losses": {"depth": 0.0}}
#: The paper's Table 6 (one HyperSim scene): mIoU / PQ^scene / PSNR, for the direction of each change.
PAPER_ABLATION = {
    "base": (58.7, 55.4, 29.5), "base+S": (60.6, 65.6, 32.0), "base+S+L_seg": (64.6, 76.7, 32.8),
    "base+S+L_feat": (62.0, 71.3, 32.4), "all": (65.2, 79.2, 32.7),
}
#: Sections of the benchmark (``--only``) and the :class:`BenchConfig` switch of each.
SECTIONS = {"presets": "preset_table", "curves": "curves", "ablation": "ablation", "bounded": "bounded_check",
            "scaling": "scaling", "export": "export", "profile": "profile", "under-load": "under_load"}
#: Inputs of a preset-table row → the ``lift3d synth --depth`` of its scenes, and the label the table shows
#: until the run itself says what it trained on.
INPUTS = {"rgb": "none", "rgb+depth": "sensor"}
#: Label noise and pose noise (degrees, centimetres) of the noise curves, from none to most.
LABEL_NOISE_LEVELS = ("clean", "moderate", "hard", "view-correlated")
POSE_NOISE_LEVELS = ((0.0, 0.0), (0.5, 2.0), (1.0, 5.0))
#: Seconds per training step and per evaluation on a 2-core CPU (docs/benchmarks.md of 2026-11-23): what
#: ``--plan`` assumes until finished runs of the same kind are in the cache. An evaluation without the 3D
#: metrics (ablation and label-noise runs: their tables show 2D metrics only) renders the test views and
#: scores them; the labelled export the 3D metrics score is most of a full evaluation.
REFERENCE_STEP_SECONDS = {"fast": 0.36, "balanced": 0.54, "quality": 1.67, "mlp": 2.4, "quick": 0.15}
REFERENCE_EVAL_SECONDS = {"fast": 60.0, "balanced": 70.0, "quality": 90.0, "quick": 10.0}
REFERENCE_EVAL_2D_SECONDS = {"fast": 15.0, "balanced": 20.0, "quality": 25.0, "quick": 2.0}
#: Minutes of the measurements that are not training runs (2-core CPU): scaling (16 points of a few timed
#: steps and renders), the 1M-point export, the profile, and the step and render timings alone and beside a
#: busy neighbour.
REFERENCE_EXTRA_MINUTES = {"scaling": 25.0, "export": 2.0, "profile": 2.0, "under load": 2.0}
#: Fresh-process repeats of the timed export (:func:`median_export`).
EXPORT_REPEATS = 5

# Tiny settings for --quick: every code path, seconds per run. 40 steps, not fewer: a street with depth maps is
# exported from its fused rendered depth (export --source auto), and after 10 or 20 steps its field is opaque
# only at the contracted background, beyond the fused cube, so the export has no surface; from 30 steps on it has
# one (outdoor seeds 100-103, both label noises). A quick step takes a few hundredths of a second.
_QUICK_TRAIN = {
    "field": {"grid": {"resolution_cap": 32, "min_resolution": 16, "head_hidden_dim": 32},
              "mlp": {"width": 64, "depth": 3}},
    "sampling": {"proposal_resolutions": [24], "proposal_samples": [32], "num_samples": 16},
    "data": {"images_per_batch": 4, "rays_per_image": 64, "patch_size": 8},
    "optim": {"steps": 40, "warmup_steps": 2},
    "trainer": {"eval_every": 0, "checkpoint_every": 0},
}
_QUICK_SCENE = {"n_views": 12, "width": 40, "height": 40}


@dataclass
class BenchConfig:
    """What to measure."""

    out: Path = Path("bench_out")
    scenes: tuple[str, ...] = ("indoor", "outdoor")
    #: The first preset makes every row; the others only the indoor RGB + depth rows.
    presets: tuple[str, ...] = ("fast", "balanced")
    seeds: tuple[int, ...] = REPORT_SEEDS
    #: Label noise of the preset table's scenes.
    noises: tuple[str, ...] = ("moderate", "view-correlated")
    #: Inputs of the preset table's rows (keys of INPUTS).
    inputs: tuple[str, ...] = ("rgb", "rgb+depth")
    label_noise_levels: tuple[str, ...] = LABEL_NOISE_LEVELS
    pose_noise_levels: tuple[tuple[float, float], ...] = POSE_NOISE_LEVELS
    #: Overrides that turn per-frame pose refinement on: the pose-noise curve is drawn with them too.
    #: None (or {}) draws the curve without pose refinement only.
    pose_refinement: dict | None = None
    preset_table: bool = True
    curves: bool = True
    bounded_check: bool = True
    ablation: bool = True
    #: Equal-steps ablation: every variant trains this many steps (the fast preset's schedule).
    ablation_steps: int = 1500
    #: Equal-time ablation: every variant trains this many seconds (the schedule follows the budget).
    ablation_budget: float = 600.0
    #: Which ablations to run: at equal steps, at equal time, or both (each is a separate cost: at 1 500 steps
    #: the plain-MLP Base alone trains about an hour per seed on 2 CPU cores).
    ablation_modes: tuple = ABLATION_MODES
    #: Which variants of :data:`ABLATION` to train (default all; e.g. the cheap ones first, Base later).
    ablation_variants: tuple = tuple(ABLATION)
    scaling: bool = True
    export: bool = True
    profile: bool = True
    under_load: bool = True
    #: Re-run the evaluation (not the training) of cached preset, curve and bounded runs, and the export
    #: timing: after a change to the eval or export code. Ablation runs keep their cached metrics and the
    #: scaling and profile jobs measure training, which did not change.
    reevaluate: bool = False
    quick: bool = False
    docs_dir: Path | None = None
    progress: bool = True
    extra: dict = field(default_factory=dict)

    def check(self) -> "BenchConfig":
        """Bad settings as one-line errors naming the flag."""
        if not self.seeds:
            raise InputError("--seeds", "give at least one scene seed")
        if any(int(s) < 0 for s in self.seeds) or len(set(self.seeds)) != len(self.seeds):
            raise InputError("--seeds", f"scene seeds must be distinct and non-negative, got {list(self.seeds)}")
        bad = [i for i in self.inputs if i not in INPUTS]
        if bad:
            raise InputError("--inputs", f"{bad[0]!r} is not one of {', '.join(INPUTS)}")
        if not self.presets:
            raise InputError("--presets", "give at least one preset")
        if self.ablation_steps < 1:
            raise InputError("--ablation-steps", f"must be positive, got {self.ablation_steps}")
        if self.ablation_budget <= 0:
            raise InputError("--ablation-budget", f"must be positive seconds, got {self.ablation_budget}")
        bad = [m for m in self.ablation_modes if m not in ABLATION_MODES]
        if bad or not self.ablation_modes:
            raise InputError("--ablation-modes", f"{(bad or [''])[0]!r} is not one of {', '.join(ABLATION_MODES)}")
        bad = [v for v in self.ablation_variants if v not in ABLATION]
        if bad or not self.ablation_variants:
            raise InputError("--ablation-variants", f"{(bad or [''])[0]!r} is not one of {', '.join(ABLATION)}")
        return self


@dataclass
class Job:
    """One training run of the benchmark: where its result goes and how to make it."""

    section: str  # key of results: runs, label_noise, pose_noise, ablation, parameterisation, or "" (a dependency)
    tags: dict  # what its record is labelled with (scene, noise, inputs, preset, seed, variant, ...)
    scene: dict  # lift3d synth arguments: kind, seed, noise, depth, pose_noise
    overrides: dict
    cache: Path
    #: Compute the 3D metrics (the labelled export scored against gt/points.ply): only for runs a table
    #: with 3D columns shows (presets, pose-noise curve, bounded, the export's run); see :func:`plan_jobs`.
    points3d: bool = True

    @property
    def name(self) -> str:
        return self.cache.stem


def machine_info() -> dict:
    """CPU model, cores available, torch, thread count, OpenMP wait policy and whether the C++ kernels are in
    use (lift3d.field.native): printed with every table, so that timings are compared like for like."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cpu": cpu,
        "cpus_available": available_cpus(),
        "torch": torch.__version__,
        "torch_threads": default_threads(),
        "openmp_waiting": openmp_waiting(),
        "native_kernels": native.load() is not None,
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "python": platform.python_version(),
        "lift3d": __version__,
    }


#: What a cached measurement must share with the one asked for to stand in for it: the preset, the seed and
#: the settings it trained with (e.g. the equal-time ablation's budget); the cache file's name already says
#: which scene and variant (paths are left out: the same output folder may be named two ways).
CACHE_IDENTITY = ("kind", "preset", "seed", "overrides", "num_points")


def _check_cached_spec(out: Path, cached: dict | None, spec: dict) -> None:
    """A cached result measured with other settings than asked for is an error naming the file (it would
    otherwise stand in silently, e.g. a 300 s ablation run for a 600 s one).

    Examples
    --------
    >>> _check_cached_spec(Path("c.json"), {"seed": 0, "overrides": {"a": 1}}, {"seed": 0, "overrides": {"a": 1}})
    >>> _check_cached_spec(Path("c.json"), {"seed": 0, "overrides": {"a": 1}}, {"seed": 0, "overrides": {"a": 2}})
    Traceback (most recent call last):
    ...
    lift3d.errors.InputError: c.json: cached for other settings (overrides: {'a': 1}, asked for {'a': 2}); delete it to measure again, or ask for what it holds
    """
    if cached is None:
        return
    for key in CACHE_IDENTITY:
        if key in cached and key in spec and json.loads(json.dumps(cached[key])) != json.loads(json.dumps(spec[key])):
            raise InputError(out, f"cached for other settings ({key}: {cached[key]}, asked for {spec[key]}); delete "
                                  "it to measure again, or ask for what it holds")


def _worker(spec: dict, out: Path, in_process: bool = False) -> dict:
    """Run one measurement in a fresh process (cached: an existing result is reused).

    ``in_process`` runs it in this process instead (``--quick``: saves importing torch and Open3D for every
    tiny run; peak memory then is this process's). A measurement that fails raises
    :class:`~lift3d.bench.worker.MeasurementFailed` (nothing is cached: the next benchmark tries it again), its
    traceback or the worker's stderr kept in OUT.failed.log."""
    if out.is_file():
        cached = json.loads(out.read_text())
        _check_cached_spec(out, cached.get("spec"), spec)
        return cached
    out.parent.mkdir(parents=True, exist_ok=True)
    spec_path = out.with_suffix(".spec.json")
    write_json_atomic(spec_path, spec)
    log = out.with_name(out.stem + ".failed.log")
    log.unlink(missing_ok=True)
    if in_process:
        try:
            result = worker.measure(spec)
        except worker.MeasurementFailed as exc:
            write_text_atomic(log, exc.details)
            exc.log = str(log)
            raise
        write_json_atomic(out, result)
        return result
    env = dict(os.environ, LIFT3D_NO_PROGRESS="1")
    proc = subprocess.run([sys.executable, "-m", "lift3d.bench.worker", str(spec_path), str(out)],
                          capture_output=True, text=True, env=env)
    if proc.returncode != 0 or not out.is_file():
        write_text_atomic(log, proc.stderr)
        said = worker.failure_path(out)
        if said.is_file():  # the worker says where and why
            failure = json.loads(said.read_text())
            said.unlink()
            raise worker.MeasurementFailed(failure["stage"], failure["reason"], proc.stderr, log=str(log))
        # it died without saying (killed, out of memory, a crash in native code): its last words
        last = next((line.strip() for line in reversed(proc.stderr.splitlines()) if line.strip()), "")
        reason = f"the worker process exited with {proc.returncode}" + (f": {last}" if last else "")
        raise worker.MeasurementFailed(worker.KIND_STAGES.get(spec["kind"], spec["kind"]), reason, proc.stderr,
                                       log=str(log))
    return json.loads(out.read_text())


def _reevaluate(path: Path, eval_spec: dict, in_process: bool = False) -> dict:
    """Evaluate a cached training run again (fresh process) and store the new metrics in its cache file.

    The render timing is not measured again: it belongs with the training-time measurement (same process
    history, same machine load) and the eval and export code do not change it."""
    cached = json.loads(path.read_text())
    if not (Path(cached["run"]) / "config.yml").is_file():
        raise InputError(path, f"its run folder {cached['run']} is gone; delete this cache file to train the run "
                               "again, or run without --reevaluate")
    spec = {"kind": "evaluate", "run": cached["run"], "num_points": eval_spec["num_points"], "timing_repeats": 0,
            "points3d": eval_spec.get("points3d", True)}
    fresh_path = path.with_name(path.stem + ".eval.json")
    fresh = _worker(spec, fresh_path, in_process=in_process)
    for key in ("render_ms_per_2048_rays", "render_timing"):
        fresh["metrics"][key] = cached["metrics"].get(key)
    cached["metrics"] = fresh["metrics"]
    cached["reevaluated"] = _dt.datetime.now().isoformat(timespec="seconds")
    write_json_atomic(path, cached)
    fresh_path.unlink()
    return cached


def _scene_name(kind: str, seed: int, noise: str, depth: str = "sensor", pose_noise=(0.0, 0.0), **size) -> str:
    """Folder name of a benchmark scene: what makes it differ from the default, e.g.
    ``indoor_s0_moderate``, ``indoor_s1_view-correlated_depthnone``, ``indoor_s2_moderate_pose0.5deg2cm``."""
    name = f"{kind}_s{seed}_{noise}"
    if depth != "sensor":
        name += f"_depth{depth}"
    if any(pose_noise):
        name += f"_pose{pose_noise[0]:g}deg{pose_noise[1]:g}cm"
    return name + ("_" + "_".join(f"{k}{v}" for k, v in sorted(size.items())) if size else "")


def _scene(cfg: BenchConfig, kind: str, seed: int, noise: str, depth: str = "sensor", pose_noise=(0.0, 0.0),
           **size) -> Path:
    """The benchmark scene folder (made by ``lift3d synth`` on first use)."""
    root = cfg.out / "scenes" / _scene_name(kind, seed, noise, depth, pose_noise, **size)
    if not (root / "transforms.json").is_file():
        args = dict(_QUICK_SCENE) if cfg.quick else {}
        args.update(size)
        make_scene(root, SynthOptions(kind=kind, seed=seed, noise=noise, depth=depth, pose_noise=tuple(pose_noise),
                                      **args), progress=False)
    return root


def run_inputs(res: dict) -> str:
    """The *inputs* column of one run: what it trained on, as the run itself records it (the training
    summary's ``inputs``, from the run's config.yml: ``RGB``, ``RGB + SfM points``, ``RGB + depth``); for runs
    that do not record it, derived from whether depth maps supervised the training."""
    return res.get("inputs") or ("RGB + depth" if res.get("depth_supervision") else "RGB")


def _record(res: dict, **tags) -> dict:
    """Flatten one train+eval result into a results.json run record."""
    m = res["metrics"]
    p3 = m.get("points3d") or {}
    rec: dict[str, Any] = dict(tags)
    depth = bool(res.get("depth_supervision", False))
    rec.update({
        "train_seconds": res["train_seconds"],
        "steps": res["steps"],
        "peak_rss_mb": res["peak_rss_mb"],
        "depth_supervision": depth,
        "inputs": run_inputs(res),
        "pose_refinement": bool(res.get("pose_refinement", False)),
        "render_ms_per_2048_rays": m.get("render_ms_per_2048_rays"),
        "run": res["run"],
        "reevaluated": res.get("reevaluated"),
        "poses_scored_at": (m.get("poses") or {}).get("scored_at"),
    })
    for k in ("psnr", "miou", "pq_scene", "sq_scene", "rq_scene", "miou_strict", "pq_scene_strict",
              "sq_scene_strict", "rq_scene_strict"):
        rec[k] = m.get(k)
    rec["points3d"] = {k: p3.get(k) for k in ("fscore", "miou", "miou_strict", "pq", "pq_strict", "chamfer",
                                              "accuracy", "completeness", "instance_recall", "n_instances",
                                              "n_pred_instances", "min_area")}
    pl = m.get("pseudo_labels") or {}
    rec["pseudo_labels"] = {k: pl.get(k) for k in ("miou", "pq_scene", "sq_scene", "rq_scene", "miou_strict",
                                                   "pq_scene_strict")}
    # Test-view IoU of each thing class the GT views show (runs cached before the worker named the classes: none).
    names = res.get("thing_classes") or {}
    rec["thing_iou"] = {names[cid]: {"iou": c["iou"], "gt_pixels": c["gt_pixels"]}
                        for cid, c in (m.get("per_class_iou_strict") or {}).items() if cid in names}
    return rec


# ------------------------------------------------------------------------------------------ the plan
def _steps_of(preset: str, overrides: dict) -> int:
    """Training steps a run of ``preset`` with ``overrides`` is scheduled for (no time budget)."""
    return int(load_config(preset, overrides={"optim": overrides.get("optim", {})} if overrides.get("optim")
                           else None).optim.steps)


#: Sections whose tables show 3D columns: their runs compute the 3D metrics (``--quick``: the preset table
#: and the export's run only, to keep the smoke test short).
_SECTIONS_3D = ("runs", "pose_noise", "parameterisation", "")
_SECTIONS_3D_QUICK = ("runs", "")


def plan_jobs(cfg: BenchConfig) -> list[Job]:
    """Every training run the configured sections need, in the order they run (shared runs once).

    A run two sections need (the indoor moderate RGB + depth run of the preset table is also the moderate
    point of both noise curves) is one job, listed under its first section and reused by the others.

    A run computes the 3D metrics when any section with 3D columns would use it with every section on
    (so a run cached by ``--only curves`` serves the preset table later); the ablation's and the
    label-noise curve's own runs skip them (their tables show 2D metrics; the export is most of an
    evaluation's time). ``--quick`` decides from the sections it runs."""
    jobs = _plan_sections(cfg)
    if cfg.quick:
        with_3d = {j.cache for j in jobs if j.section in _SECTIONS_3D_QUICK}
    else:
        full = dataclasses.replace(cfg, preset_table=True, curves=True, bounded_check=True, export=True, ablation=False)
        with_3d = {j.cache for j in _plan_sections(full) if j.section in _SECTIONS_3D}
    for job in jobs:
        job.points3d = job.cache in with_3d
    return jobs


def _plan_sections(cfg: BenchConfig) -> list[Job]:
    """The jobs of :func:`plan_jobs` for the sections ``cfg`` switches on."""
    cache = cfg.out / "cache"
    quick = _QUICK_TRAIN if cfg.quick else {}
    first = cfg.presets[0]
    jobs: list[Job] = []

    def add(section: str, kind: str, seed: int, noise: str, preset: str, variant: str = "all", *,
            depth: str = "sensor", pose_noise=(0.0, 0.0), overrides: dict | None = None, **tags) -> None:
        scene = {"kind": kind, "seed": int(seed), "noise": noise, "depth": depth,
                 "pose_noise": [float(pose_noise[0]), float(pose_noise[1])]}
        over = _merge(quick, overrides or {})
        name = f"run_{_scene_name(kind, seed, noise, depth, pose_noise)}_{preset}_{variant}"
        t = {"scene": kind, "noise": noise, "scene_depth": depth, "pose_noise": scene["pose_noise"], "preset": preset,
             "seed": int(seed), "variant": variant, **tags}
        jobs.append(Job(section, t, scene, over, cache / f"{name}.json"))

    if cfg.preset_table:
        for kind in cfg.scenes:
            for inputs in cfg.inputs:
                for noise in cfg.noises:
                    for seed in cfg.seeds:
                        add("runs", kind, seed, noise, first, depth=INPUTS[inputs])
        if "indoor" in cfg.scenes and "rgb+depth" in cfg.inputs:
            for preset in cfg.presets[1:]:
                for noise in cfg.noises:
                    for seed in cfg.seeds:
                        add("runs", "indoor", seed, noise, preset)
    if cfg.curves:
        for noise in cfg.label_noise_levels:
            for seed in cfg.seeds:
                add("label_noise", "indoor", seed, noise, first)
        refinement = [("all", {})] + ([("pose-refinement", cfg.pose_refinement)] if cfg.pose_refinement else [])
        for pose in cfg.pose_noise_levels:
            for variant, over in refinement:
                for seed in cfg.seeds:
                    add("pose_noise", "indoor", seed, "moderate", first, variant, pose_noise=pose, overrides=over)
    if cfg.ablation:
        budget = 2.0 if cfg.quick else float(cfg.ablation_budget)
        modes = {"steps": {"optim": {"steps": _QUICK_TRAIN["optim"]["steps"] if cfg.quick else cfg.ablation_steps}},
                 "time": {"trainer": {"time_budget": budget}, "optim": {"steps": 100000}}}
        for mode, mode_over in modes.items():
            if mode not in cfg.ablation_modes:
                continue
            for variant, over in ABLATION.items():
                if variant not in cfg.ablation_variants:
                    continue
                for seed in cfg.seeds:
                    tags = {"mode": mode}
                    if mode == "time":
                        tags["budget_seconds"] = budget
                    add("ablation", "indoor", seed, "moderate", first, f"{variant}_equal-{mode}",
                        overrides=_merge(_merge(ABLATION_COMMON, over), mode_over), **tags)
                    jobs[-1].tags["variant"] = variant
    if cfg.bounded_check and "outdoor" in cfg.scenes:
        # The preset table's outdoor runs use the contracted (unbounded) field; the same runs with a bounded
        # field (contraction "none": nothing outside the normalised box) show what the contraction buys.
        for seed in cfg.seeds:
            add("parameterisation", "outdoor", seed, "moderate", first, "bounded",
                overrides={"field": {"contraction": "none"}})
            add("parameterisation", "outdoor", seed, "moderate", first)
    if cfg.export:  # the export times the first indoor run
        add("", "indoor", cfg.seeds[0], "moderate", first)
    return jobs


def _estimate_seconds(cfg: BenchConfig, jobs: list[Job]) -> dict[Path, float]:
    """Estimated wall time of each job not yet in the cache: steps × seconds per step + evaluation.

    Seconds per step and per evaluation come from finished runs of the same preset and field kind in this
    cache (their median) when there are any, else from REFERENCE_STEP_SECONDS / REFERENCE_EVAL_SECONDS."""
    per_step: dict[str, list[float]] = {}
    per_eval: dict[tuple[str, bool], list[float]] = {}
    keys: dict[Path, str] = {}
    for job in jobs:
        kind = job.overrides.get("field", {}).get("kind", "grid")
        key = "quick" if cfg.quick else ("mlp" if kind == "mlp" else job.tags["preset"])
        keys[job.cache] = key
        if job.cache.is_file():
            res = json.loads(job.cache.read_text())
            if res.get("steps"):
                per_step.setdefault(key, []).append(res["train_seconds"] / res["steps"])
            m = res.get("metrics") or {}
            if m.get("seconds"):
                ev_key = "quick" if cfg.quick else job.tags["preset"]
                per_eval.setdefault((ev_key, m.get("points3d") is not None), []).append(m["seconds"])
    out = {}
    for job in jobs:
        if job.cache.is_file():
            continue
        key = keys[job.cache]
        step = statistics.median(per_step[key]) if key in per_step else REFERENCE_STEP_SECONDS.get(key, 0.5)
        ev_key = (key if key != "mlp" else job.tags["preset"], job.points3d)
        reference = REFERENCE_EVAL_SECONDS if job.points3d else REFERENCE_EVAL_2D_SECONDS
        ev = statistics.median(per_eval[ev_key]) if ev_key in per_eval else reference.get(ev_key[0], 60.0)
        budget = job.overrides.get("trainer", {}).get("time_budget")
        train = float(budget) if budget else _steps_of(job.tags["preset"], job.overrides) * step
        out[job.cache] = train + ev
    return out


#: How ``--plan`` names the sections a run serves.
_SECTION_NAMES = {"runs": "presets", "label_noise": "label-noise curve", "pose_noise": "pose-noise curve",
                  "parameterisation": "bounded", "export": "export"}


def plan_text(cfg: BenchConfig, jobs: list[Job] | None = None) -> str:
    """``lift3d bench --plan``: every training run with its status and estimated time, the other
    measurements, and the total still to do."""
    jobs = plan_jobs(cfg) if jobs is None else jobs
    est = _estimate_seconds(cfg, jobs)
    lines = [f"lift3d bench plan for {cfg.out} (estimates from this cache's finished runs where there are any, "
             "else from a 2-core CPU with nothing else running)", "",
             f"{'status':<7} {'est. min':>8}  run (sections)"]
    todo_s, n_todo, n_done = 0.0, 0, 0
    sections: dict[Path, list[str]] = {}
    for job in jobs:  # a run several sections share is trained once: listed once, with every section
        sections.setdefault(job.cache, [])
        if (job.section or "export") not in sections[job.cache]:
            sections[job.cache].append(job.section or "export")
    for job in jobs:
        if job.cache not in sections:
            continue
        names = [_SECTION_NAMES.get(n, n) for n in sections.pop(job.cache)]
        done = job.cache.is_file()
        n_done += done
        n_todo += not done
        todo_s += est.get(job.cache, 0.0)
        lines.append(f"{'cached' if done else 'to do':<7} {est.get(job.cache, 0.0) / 60:>8.1f}  {job.name[4:]} "
                     f"({', '.join(names)})")
    extra = {name: REFERENCE_EXTRA_MINUTES[name] * (0.1 if cfg.quick else 1.0)
             for name, on in (("scaling", cfg.scaling), ("export", cfg.export), ("profile", cfg.profile),
                              ("under load", cfg.under_load)) if on}
    extra_s = 60.0 * sum(extra.values())
    lines += ["", f"{n_done + n_todo} training runs: {n_done} cached, {n_todo} to do, about "
                  f"{todo_s / 3600:.1f} h of training and evaluation still to do"
                  + (f"; besides: {', '.join(f'{k} ~{v:.0f} min' for k, v in extra.items())}" if extra else "") + "."]
    lines.append(f"In all about {(todo_s + extra_s) / 3600:.1f} h on one machine, one run at a time (runs are not "
                 "run in parallel: the timings would disturb each other); twice that or more when others share "
                 "the cores.")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------ running
def run_benchmark(cfg: BenchConfig) -> dict:
    """Run (or resume) the benchmark and write every report. Returns the results dict."""
    cfg.check()
    cfg.out.mkdir(parents=True, exist_ok=True)
    cache = cfg.out / "cache"
    quick_over = _QUICK_TRAIN if cfg.quick else {}
    results: dict[str, Any] = {"machine": machine_info(), "created": _dt.datetime.now().isoformat(timespec="seconds"),
                               "quick": cfg.quick, "seeds": list(cfg.seeds), "config": report_config(cfg),
                               "runs": [],
                               "curves": {"label_noise": [], "pose_noise": []}, "ablation": [],
                               "parameterisation": [], "skipped": [], "failed": [], "scaling": [], "export": None,
                               "profile": None, "under_load": None}
    jobs = plan_jobs(cfg)
    done: dict[Path, dict | None] = {}
    failed: dict[Path, dict] = {}  # a failed run's record in results["failed"], by its cache file
    for job in progress_bar(jobs, desc="bench runs", disable=not cfg.progress, unit="run"):
        if job.cache not in done:  # a run several sections share is trained (or skipped) once
            eval_spec = {"num_points": 5_000 if cfg.quick else 200_000, "points3d": job.points3d}
            # What the run trains with (the cache file's name holds the rest: scene, noise, variant).
            identity = {"kind": "train", "preset": job.tags["preset"], "seed": job.scene["seed"],
                        "overrides": job.overrides}
            done[job.cache] = None
            try:
                if job.cache.is_file():  # finished before: its scene is not needed (nor made again)
                    cached = json.loads(job.cache.read_text())
                    _check_cached_spec(job.cache, cached.get("spec"), identity)
                    done[job.cache] = (_reevaluate(job.cache, eval_spec, in_process=cfg.quick)
                                       if cfg.reevaluate and job.section != "ablation" else cached)
                else:
                    try:
                        scene = _scene(cfg, job.scene["kind"], job.scene["seed"], job.scene["noise"],
                                       job.scene["depth"], job.scene["pose_noise"])
                    except InputError as exc:
                        # e.g. a pose noise that would put a written camera inside geometry on this seed: the row
                        # then has one seed less, and the report says so.
                        results["skipped"].append({**job.tags, "section": job.section, "reason": str(exc)})
                        continue
                    except Exception as exc:
                        raise worker.MeasurementFailed("scene synthesis", worker.one_line(exc),
                                                       traceback.format_exc()) from exc
                    spec = {**identity, "scene": str(scene),
                            "output_dir": str(cfg.out / "runs" / (job.section or "runs")),
                            "timing_repeats": 1 if cfg.quick else 10, **eval_spec}
                    done[job.cache] = _worker(spec, job.cache, in_process=cfg.quick)
            except worker.MeasurementFailed as exc:
                # The run becomes a failed row of the report and the benchmark goes on (its row averages over the
                # seeds that finished); nothing is cached, so the next benchmark tries it again.
                failed[job.cache] = failure_record(job.tags, job.section or "export", exc)
                results["failed"].append(failed[job.cache])
                continue
        if done[job.cache] is None:
            if job.cache in failed and (job.section or "export") not in failed[job.cache]["sections"]:
                failed[job.cache]["sections"].append(job.section or "export")
            continue
        rec = _record(done[job.cache], **job.tags)
        if job.section in ("label_noise", "pose_noise"):
            results["curves"][job.section].append(rec)
        elif job.section:
            results[job.section].append(rec)
    results["summary"] = tables.summarize(results)

    # The export times the first indoor run (a job of its own when the preset table is not run).
    first_run = (done.get(cache / f"run_{_scene_name('indoor', cfg.seeds[0], 'moderate')}_{cfg.presets[0]}_all.json")
                 or {}).get("run")
    if cfg.export and first_run:
        spec = {"kind": "export", "run": first_run, "num_points": 20_000 if cfg.quick else 1_000_000}
        # Each repeat in a fresh process (as `lift3d export` runs: nothing warmed up by an earlier export); the
        # median, because the same export here takes 4-7 s from one minute to the next.
        repeats = 1 if cfg.quick else EXPORT_REPEATS
        paths = [cache / f"export_indoor_{cfg.presets[0]}_r{r}.json" for r in range(repeats)]
        if cfg.reevaluate:
            for path in paths:
                path.unlink(missing_ok=True)
        try:
            results["export"] = dict(median_export([_worker(spec, path, in_process=cfg.quick) for path in paths]),
                                     preset=cfg.presets[0])
        except worker.MeasurementFailed as exc:
            results["failed"].append(failure_record(
                {"measurement": f"{spec['num_points']:,}-point export of the indoor seed {cfg.seeds[0]} "
                                f"`{cfg.presets[0]}` run"}, "export", exc))
    if cfg.scaling:
        results["scaling"] = run_scaling(cfg, cache, results["failed"])
    for name, key, title in (("profile", "profile", "profile of a training step and a render"),
                             ("under_load", "under load", "a training step and a render beside a busy neighbour")):
        if not getattr(cfg, name) or "indoor" not in cfg.scenes:
            continue
        try:
            with worker.stage("scene synthesis"):
                scene = _scene(cfg, "indoor", cfg.seeds[0], "moderate")
            if name == "profile":
                spec = {"kind": "profile", "scene": str(scene), "preset": cfg.presets[0], "overrides": quick_over,
                        "output_dir": str(cfg.out / "runs" / "profile"), "warmup": 2 if cfg.quick else 10,
                        "steps": 2 if cfg.quick else 10, "repeats": 2 if cfg.quick else 10}
                results["profile"] = _worker(spec, cache / f"profile_{cfg.presets[0]}.json", in_process=cfg.quick)
            else:  # in a process of its own even with --quick: it measures beside another process
                spec = {"kind": "under_load", "scene": str(scene), "preset": cfg.presets[0], "overrides": quick_over,
                        "output_dir": str(cfg.out / "runs" / "under_load"), "warmup": 1 if cfg.quick else 5,
                        "steps": 1 if cfg.quick else 10, "repeats": 1 if cfg.quick else 10,
                        "rounds": 1 if cfg.quick else 3, "settle_seconds": 0.2 if cfg.quick else 1.0}
                results["under_load"] = _worker(spec, cache / f"under_load_{cfg.presets[0]}.json")
        except worker.MeasurementFailed as exc:
            results["failed"].append(failure_record({"measurement": f"{title} (`{cfg.presets[0]}`)"}, key, exc))
    write_reports(results, cfg)
    return results


def describe_run(tags: dict) -> str:
    """What a benchmark measurement was, in a few words (the failed and skipped rows of the report).

    Examples
    --------
    >>> describe_run({"scene": "outdoor", "seed": 100, "noise": "moderate", "scene_depth": "sensor",
    ...               "pose_noise": [0.0, 0.0], "preset": "fast", "variant": "all"})
    'outdoor seed 100, moderate labels, with depth maps, `fast`'
    >>> describe_run({"scene": "indoor", "seed": 2, "noise": "moderate", "scene_depth": "none", "preset": "fast",
    ...               "variant": "base+S", "mode": "time", "pose_noise": [0.5, 2.0]})
    'indoor seed 2, moderate labels, without depth maps, `fast`, base+S, equal time, pose noise 0.5°/2 cm'
    """
    if "measurement" in tags:
        return str(tags["measurement"])
    parts = [f"{tags['scene']} seed {tags['seed']}", f"{tags['noise']} labels",
             "with depth maps" if tags.get("scene_depth", "sensor") == "sensor" else "without depth maps",
             f"`{tags['preset']}`"]
    if tags.get("variant") not in (None, "all"):
        parts.append(str(tags["variant"]))
    if tags.get("mode"):
        parts.append(f"equal {tags['mode']}")
    pose = tags.get("pose_noise") or (0.0, 0.0)
    if any(pose):
        parts.append(f"pose noise {pose[0]:g}°/{pose[1]:g} cm")
    return ", ".join(parts)


def failure_record(tags: dict, section: str, exc: "worker.MeasurementFailed") -> dict:
    """A failed measurement's row of ``results["failed"]``: what it was, the section(s) it served, the stage it
    stopped in, the one-line reason and where the whole error is."""
    return {**tags, "status": "failed", "section": section, "sections": [section], "run": describe_run(tags),
            "stage": exc.stage, "reason": exc.reason, "log": exc.log}


def run_scaling(cfg: BenchConfig, cache: Path, failed: list[dict] | None = None) -> list[dict]:
    """Step/render time and memory against resolution, views, V and U (one factor at a time). A point whose
    measurement fails is left out of the rows and added to ``failed``."""
    if cfg.quick:
        grid = {"resolution": [32, 48], "views": [8, 16], "instance_channels": [8, 32], "classes": [0, 32]}
        base_views, base_res = 8, 32
    else:
        grid = {"resolution": [64, 128, 256, 512], "views": [20, 50, 100, 200],
                "instance_channels": [8, 32, 64, 128], "classes": [0, 32, 64, 128]}
        base_views, base_res = 20, 128
    rows = []
    todo = [(f, v) for f, vals in grid.items() for v in vals]
    for factor, value in progress_bar(todo, desc="bench scaling", disable=not cfg.progress, unit="point"):
        views, res = base_views, base_res
        over: dict = _merge(_QUICK_TRAIN if cfg.quick else {}, {})
        if factor == "resolution":
            res = value
        elif factor == "views":
            views, res = value, 64 if not cfg.quick else 32
        elif factor == "instance_channels":
            over = _merge(over, {"field": {"num_instance_channels": value}})
        elif factor == "classes" and value:
            over = _merge(over, {"field": {"num_semantic_classes": value}})
        try:
            with worker.stage("scene synthesis"):
                scene = _scene(cfg, "indoor", cfg.seeds[0], "moderate", n_views=views, width=res, height=res)
            spec = {"kind": "scaling", "scene": str(scene), "preset": cfg.presets[0], "overrides": over,
                    "output_dir": str(cfg.out / "runs" / "scaling"), "warmup": 1 if cfg.quick else 5,
                    "steps": 2 if cfg.quick else 12, "repeats": 2 if cfg.quick else 7}
            res_ = _worker(spec, cache / f"scaling_{factor}_{value}.json", in_process=cfg.quick)
        except worker.MeasurementFailed as exc:
            if failed is None:
                raise
            failed.append(failure_record({"measurement": f"scaling point {factor} = {value}"}, "scaling", exc))
            continue
        shown = res_["semantic_classes"] if factor == "classes" else value
        rows.append({"factor": factor, "value": shown, "step_ms": res_["step_ms"], "render_ms": res_["render_ms"],
                     "peak_rss_mb": res_["peak_rss_mb"], "grid_resolution": res_["grid_resolution"],
                     "pixels": res_["pixels"]})
    return rows


def _merge(a: dict, b: dict) -> dict:
    out = json.loads(json.dumps(a))
    for k, v in b.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


# ------------------------------------------------------------------------------------------ reports
def _f(x: Any, nd: int = 3) -> str:
    return "–" if x is None else (f"{x:.{nd}f}" if isinstance(x, float) else str(x))


def write_reports(results: dict, cfg: BenchConfig) -> None:
    write_json_atomic(cfg.out / "results.json", results)
    write_text_atomic(cfg.out / "results.csv", results_csv(results))
    pictures = {}
    if results["runs"]:
        pictures["pareto"] = plot_pareto(results, cfg.out / "pareto.png")
    if any(results.get("curves", {}).values()):
        pictures["noise_curves"] = plot_noise_curves(results, cfg.out / "noise_curves.png")
    if results["scaling"]:
        pictures["scaling"] = plot_scaling(results, cfg.out / "scaling.png")
    md = benchmarks_markdown(results, {k: p.name for k, p in pictures.items()})
    write_text_atomic(cfg.out / "benchmarks.md", md)
    if cfg.docs_dir is not None:
        images = cfg.docs_dir / "images"
        images.mkdir(parents=True, exist_ok=True)
        for key, p in pictures.items():
            (images / f"bench_{key}.png").write_bytes(p.read_bytes())
        md_docs = benchmarks_markdown(results, {k: f"images/bench_{k}.png" for k in pictures})
        page = cfg.docs_dir / "benchmarks.md"
        kept = kept_block(page.read_text(encoding="utf-8")) if page.is_file() else ""
        write_text_atomic(page, with_kept_block(md_docs, kept))


#: Marks the part of docs/benchmarks.md measured outside ``lift3d bench`` (real captures, room shapes; each with
#: the commands that measure it): regenerating the page keeps it, under "How good".
KEPT_BEGIN, KEPT_END = "<!-- measured outside lift3d bench: begin -->", "<!-- measured outside lift3d bench: end -->"


def kept_block(page: str) -> str:
    r"""The marked block of ``page`` (markers included), or "".

    Examples
    --------
    >>> kept_block(f"a\n{KEPT_BEGIN}\nkept\n{KEPT_END}\nb") == f"{KEPT_BEGIN}\nkept\n{KEPT_END}"
    True
    """
    start, end = page.find(KEPT_BEGIN), page.find(KEPT_END)
    return page[start:end + len(KEPT_END)] if 0 <= start < end else ""


def with_kept_block(page: str, block: str) -> str:
    """``page`` with ``block`` at the end of its "How good" section (before "How fast")."""
    if not block:
        return page
    at = page.find("\n" + PAGE_SECTIONS[2])
    return page[:at] + "\n\n" + block + "\n" + page[at:] if at >= 0 else page + "\n" + block + "\n"


#: results.csv: one row per run and section it serves (a shared run is in several sections), per seed.
CSV_COLUMNS = ["section", "scene", "noise", "scene_depth", "inputs", "pose_noise_deg", "pose_noise_cm",
               "pose_refinement", "preset", "variant", "mode", "seed", "steps", "train_seconds", "peak_rss_mb",
               "render_ms_per_2048_rays", "psnr", "miou", "pq_scene", "sq_scene", "rq_scene", "miou_strict",
               "pq_scene_strict", "fscore_3d", "miou_3d", "miou_3d_strict", "objects_found_3d", "gt_objects_3d",
               "instances_exported_3d", "pseudo_miou", "pseudo_pq_scene", "poses_scored_at", "status", "measurement",
               "reason"]


def results_csv(results: dict) -> str:
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(CSV_COLUMNS)
    sections = [("runs", results.get("runs", []))]
    sections += [(f"curves/{k}", v) for k, v in (results.get("curves") or {}).items()]
    sections += [("ablation", results.get("ablation", [])), ("parameterisation", results.get("parameterisation", []))]
    for section, records in sections:
        for r in records:
            p3 = r["points3d"]
            pose = r.get("pose_noise") or [None, None]
            row = dict(r, section=section, fscore_3d=p3.get("fscore"), miou_3d=p3.get("miou"),
                       miou_3d_strict=p3.get("miou_strict"), objects_found_3d=p3.get("instance_recall"),
                       gt_objects_3d=p3.get("n_instances"), instances_exported_3d=p3.get("n_pred_instances"),
                       pseudo_miou=r["pseudo_labels"].get("miou"), pseudo_pq_scene=r["pseudo_labels"].get("pq_scene"),
                       pose_noise_deg=pose[0], pose_noise_cm=pose[1], status="ok")
            w.writerow([row.get(c) for c in CSV_COLUMNS])
    for f in results.get("failed") or []:  # a failed run: one row per section it served, as a finished one
        pose = f.get("pose_noise") or [None, None]
        for section in f.get("sections") or [f["section"]]:
            row = dict(f, section=section, pose_noise_deg=pose[0], pose_noise_cm=pose[1], measurement=f["run"],
                       reason=f"{f['stage']}: {f['reason']}")
            w.writerow([row.get(c) if c in FAILED_CSV_COLUMNS else None for c in CSV_COLUMNS])
    return buf.getvalue()


#: The columns a failed run's row fills in results.csv (what it was, and why it has no numbers).
FAILED_CSV_COLUMNS = ("section", "scene", "noise", "scene_depth", "pose_noise_deg", "pose_noise_cm", "preset",
                      "variant", "mode", "seed", "status", "measurement", "reason")


#: How a user times the render figure on a run of their own, through the public API (docs/api.md).
RENDER_THROUGH_THE_API = [
    "",
    "### Timing the render on a run of your own",
    "",
    "The render figures time 2048 rays of a test view with rgb, depth, semantic and instance, the median of 10 "
    "after 2 warm-up renders (`lift3d eval` reports the same as `render_ms_per_2048_rays`). Through the public "
    "API, on any trained run:",
    "",
    "```python",
    "import time, numpy as np, lift3d",
    "run = lift3d.load_run(\"outputs/<scene>/fast/<YYYY-MM-DD_HHMMSS>\")",
    "scene = run.scene()",
    "cams, i = scene.cameras, int(scene.split(\"test\")[0])",
    "pix = np.linspace(0, cams.width[i] * cams.height[i] - 1, 2048).astype(int)",
    "origins, directions = cams.rays(i, pix % cams.width[i], pix // cams.width[i])",
    "for _ in range(2):",
    "    run.render_rays(origins, directions)            # warm-up",
    "ms = []",
    "for _ in range(10):",
    "    t = time.perf_counter(); run.render_rays(origins, directions); ms.append(1e3 * (time.perf_counter() - t))",
    "print(f\"{np.median(ms):.1f} ms per 2048 rays\")",
    "```",
    "",
    "`render_rays` wraps the same `render_chunked` call with the conversion from and to numpy; on a trained "
    "indoor run its median matched `lift3d eval`'s within the run-to-run spread of either.",
]

#: The top-level sections of the benchmark page in order (docs/benchmarks.md keeps the same; a test checks both).
PAGE_SECTIONS = ("## Which preset to use", "## How good: accuracy over scenes and seeds",
                 "## How fast: training, rendering, export", "## The speed/accuracy trade", "## Reproduce")


def report_config(cfg: BenchConfig) -> dict:
    """What a benchmark run selected (results.json ``config``): the page's reproduce commands are written from it."""
    return {"scenes": list(cfg.scenes), "presets": list(cfg.presets), "seeds": list(cfg.seeds),
            "noises": list(cfg.noises), "inputs": list(cfg.inputs), "ablation_steps": cfg.ablation_steps,
            "ablation_budget": cfg.ablation_budget, "ablation_modes": list(cfg.ablation_modes),
            "ablation_variants": list(cfg.ablation_variants), "quick": cfg.quick}


def bench_command(config: dict | None, only: str | None = None) -> str:
    """The ``lift3d bench`` command that measures what ``config`` selected (:func:`report_config`; None: the
    defaults), narrowed to the sections ``only`` names.

    Examples
    --------
    >>> bench_command(None, "presets")
    'lift3d bench --only presets'
    >>> bench_command({"scenes": ["indoor"], "presets": ["fast"], "seeds": [0, 1, 2], "quick": False}, "curves")
    'lift3d bench --only curves --scenes indoor --presets fast'
    """
    config = config or {}
    defaults = {"scenes": ["indoor", "outdoor"], "presets": ["fast", "balanced"], "seeds": list(REPORT_SEEDS),
                "noises": ["moderate", "view-correlated"], "inputs": ["rgb", "rgb+depth"], "ablation_steps": 1500,
                "ablation_budget": 600.0, "ablation_modes": list(ABLATION_MODES), "ablation_variants": list(ABLATION)}
    if config.get("quick"):
        defaults["seeds"] = list(tables.QUICK_SEEDS)
    words = ["lift3d", "bench"] + (["--only", only] if only else []) + (["--quick"] if config.get("quick") else [])
    ablation = only is None or "ablation" in only.split(",")
    for key, value in config.items():
        if key == "quick" or value is None or value == defaults.get(key):
            continue
        if key.startswith("ablation_") and not ablation:
            continue
        text = ",".join(map(str, value)) if isinstance(value, (list, tuple)) else f"{value:g}"
        words += ["--" + key.replace("_", "-"), text]
    return " ".join(words)


def failed_markdown(results: dict) -> list[str]:
    """The runs that failed (their reason in one line) and the runs that could not be made."""
    lines = []
    failed = results.get("failed") or []
    if failed:
        lines += ["", "## Runs that failed", "",
                  f"{len(failed)} measurement{'s' if len(failed) != 1 else ''} of this benchmark failed: the rows "
                  "below average over the seeds that finished (their n says so), and a table whose every run failed "
                  "is missing. The whole error is in the log file each failure names in `results.json`; `lift3d "
                  "bench` with the same options tries a failed run again (finished ones come from the cache).",
                  "", "| section | run | stage | reason |", "|---|---|---|---|"]
        for f in failed:
            reason = f["reason"].replace("|", "\\|")
            lines.append(f"| {', '.join(f.get('sections') or [f['section']])} | {f['run']} | {f['stage']} | {reason} |")
    if results.get("skipped"):
        lines += ["", "**Runs that could not be made** (their rows average over fewer seeds):", ""]
        lines += [f"- {s.get('section') or 'export'}: {describe_run(s)} — {s['reason']}" for s in results["skipped"]]
    return lines


def benchmarks_markdown(results: dict, pictures: dict[str, str]) -> str:
    """The benchmark page (docs/benchmarks.md): which preset to use, how good, how fast, the trade, and how to
    reproduce each table, written from the results (no number in it is typed by hand)."""
    m = results["machine"]
    config = results.get("config")
    lines = [
        "# Benchmarks",
        "",
        "How accurate and how fast lift3d's presets are on synthetic rooms and streets with noisy 2D labels, "
        "measured in one benchmark run on this machine: "
        f"**{m['cpu']}**, {m['cpus_available']} CPU cores, torch {m['torch']} with "
        f"{m['torch_threads']} threads{', GPU ' + m['cuda'] if m.get('cuda') else ', no GPU'}; "
        f"{results['created']}{' (--quick: tiny scenes, smoke test only)' if results.get('quick') else ''}. "
        f"Regenerated by `{bench_command(config)}` (the tables, pictures and sentences are written from its results; "
        "do not edit by hand). Timings move with the machine and its load: compare them within one run.",
        "",
        tables.seed_note(results.get("seeds") or sorted({r["seed"] for r in results.get("runs", [])})),
    ]
    again = sorted({r["reevaluated"] for r in results["runs"] + results["parameterisation"] if r.get("reevaluated")})
    if again:
        lines += ["", f"The metrics of the preset, curve and bounded runs were computed again from "
                      f"their trained checkpoints on {again[-1][:10]} (`lift3d bench --reevaluate`, after a change to "
                      "the eval or export code); their training time, memory and render timing are from the runs "
                      "themselves."]
    lines += failed_markdown(results)
    lines += tables.preset_choice_markdown(results)
    if results["runs"]:
        lines += tables.presets_markdown(results)
        lines += tables.per_class_markdown(results)
    if any((results.get("curves") or {}).values()):
        lines += tables.curves_markdown(results, pictures.get("noise_curves"))
    if results["ablation"]:
        lines += tables.ablation_markdown(results, PAPER_ABLATION)
    if results.get("parameterisation"):
        lines += tables.parameterisation_markdown(results)
    lines += ["", "## How fast: training, rendering, export", "",
              "Training time (wall time of `lift3d train`), peak memory and the render time of 2048 rays of every "
              "preset row are in the preset table above; below, the labelled export, how cost grows with the work, "
              "where a step and a render spend their time, and what a busy neighbour costs."]
    if results.get("export"):
        lines += export_markdown(results["export"])
    if results["scaling"]:
        lines += scaling_markdown(results["scaling"], pictures.get("scaling"))
    if results.get("profile"):
        lines += profile_markdown(results["profile"])
    if results.get("under_load"):
        lines += under_load_markdown(results["under_load"])
    if results["runs"]:
        lines += tables.preset_trade_markdown(results, pictures.get("pareto"))
    lines += reproduce_markdown(results)
    lines += RENDER_THROUGH_THE_API
    return "\n".join(lines) + "\n"


def reproduce_markdown(results: dict) -> list[str]:
    """How to make each table again: the exact ``lift3d bench`` command per section."""
    config = results.get("config")
    made = [("the preset table, per-class IoU and the trade", "presets", bool(results.get("runs"))),
            ("label and pose noise", "curves", any((results.get("curves") or {}).values())),
            ("the ablation", "ablation", bool(results.get("ablation"))),
            ("unbounded vs bounded", "bounded", bool(results.get("parameterisation"))),
            ("the export", "export", bool(results.get("export"))),
            ("scaling", "scaling", bool(results.get("scaling"))),
            ("where the time goes", "profile", bool(results.get("profile"))),
            ("under load", "under-load", bool(results.get("under_load")))]
    lines = ["", "## Reproduce", "",
             f"Everything on this page: `{bench_command(config)} --out bench_out` (resumable: finished runs are "
             "cached in `bench_out/cache`; `--plan` lists every run with an estimated time and trains nothing; "
             "`lift3d bench --quick` is the smoke test). Each table alone:", ""]
    lines += [f"- {what}: `{bench_command(config, only)}`" for what, only, shown in made if shown]
    lines += ["", "`results.json` and `results.csv` beside the page hold every run's per-seed values; a run that "
                  "fails is a row marked `failed` there with its reason, and `lift3d bench` then exits with 1."]
    return lines


def scaling_markdown(rows: list[dict], picture: str | None) -> list[str]:
    """The scaling section: step and render time and memory against one factor at a time."""
    lines = [
        "",
        "### Scaling: how cost grows with the work",
        "",
        "One factor at a time (indoor scene; step = one training step of the preset's batch; render = 2048 "
        "rays; peak = the measuring process's peak RSS, including the cached training pixels).",
        "",
        "| factor | value | step ms | render ms | peak MB | grid res | pixels |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['factor']} | {r['value']} | {_f(r['step_ms'], 1)} | {_f(r['render_ms'], 1)} | "
                     f"{_f(r['peak_rss_mb'], 0)} | {r['grid_resolution']} | {r['pixels']} |")
    if picture:
        lines += ["", f"![scaling]({picture})"]
    return lines


def profile_markdown(prof: dict) -> list[str]:
    """The "where the time goes" section: stages and top operators of a training step and of a render."""
    b = prof.get("batch", {})
    # Profiles cached before rays_per_step was recorded counted the random rays and the patch only.
    rays = b.get("rays_per_step") or b.get("images_per_batch", 0) * (b.get("patch_size", 0) ** 2
                                                                      + b.get("rays_per_image", 0))
    lines = [
        "",
        "### Where the time goes",
        "",
        f"`torch.profiler` on the indoor scene, preset `{prof['preset']}`, {prof['threads']} "
        f"thread{'s' if prof['threads'] != 1 else ''}: "
        f"{prof['steps']} training steps ({rays} rays each, {b.get('num_samples', '–')} field samples per ray "
        f"after the proposal) and {prof['repeats']} renders of 2048 rays, after warm-up. Unprofiled medians in "
        f"the same process: **{_f(prof['step_ms'], 1)} ms per step**, **{_f(prof['render_ms'], 1)} ms per "
        "render**; the profiler's own overhead makes its totals larger. Stages are our `record_function` labels "
        "(inclusive: `render.*` nests inside `step.forward_and_losses`); operators are ranked by self time "
        "(`aten::` ops; `...Backward` rows are autograd's).",
        "",
        f"**Against the floor.** Counting the arithmetic of this design (2048 rays, 32 final samples, 64-wide "
        f"heads: about 3.2 GFLOP) at the rates measured on a 2-core AVX-512 Xeon of this machine kind (fp32 "
        f"MLP-shaped products 115–150 GFLOP/s, random gathers 30–80 M rows/s) puts a 2048-ray render at "
        f"11–25 ms at best; the render median above is {_f(prof['render_ms'] / 25.0, 1)}–"
        f"{_f(prof['render_ms'] / 11.0, 1)} × that floor. The paper renders 2048 rays in 26.7 ms on an RTX 3090.",
        "",
        "How to time the render figure on a run of your own through the public API: section \"Reproduce\".",
    ]
    for key, title in (("train", "training step"), ("render", "render of 2048 rays")):
        block = prof[key]
        lines += ["", f"**{title}** (profiled total {_f(block['profiled_ms'], 1)} ms)", "",
                  "| stage | ms | calls |", "|---|---|---|"]
        lines += [f"| `{r['name']}` | {_f(r['ms'], 1)} | {_f(r['calls'], 1)} |" for r in block["stages"]]
        lines += ["", "| operator | self ms | share | calls |", "|---|---|---|---|"]
        lines += [f"| `{r['name']}` | {_f(r['self_ms'], 1)} | {_f(r['percent'], 1)} % | {_f(r['calls'], 0)} |"
                  for r in block["ops"]]
    return lines


def _waiting(measured: dict) -> str:
    """How the measured process's OpenMP threads waited (results cached before 2026-11-26 name only the policy)."""
    if "openmp_waiting" in measured:
        return measured["openmp_waiting"]
    return f"OMP_WAIT_POLICY={measured.get('omp_wait_policy') or 'unset'}"


def under_load_markdown(ul: dict) -> list[str]:
    """The "under load" section: a training step and a render alone and beside a busy neighbour."""
    return [
        "",
        "### Under load: one busy neighbour",
        "",
        f"The indoor scene, preset `{ul['preset']}`, {ul['threads']} threads, OpenMP threads waiting with "
        f"`{_waiting(ul)}`: medians of {ul['steps']} training steps and {ul['repeats']} "
        f"renders of 2048 rays per condition in {ul['rounds']} alternating rounds, alone and beside one "
        "process that keeps 2 OpenMP threads busy with matrix products (default wait policy). Target: at most "
        "2.5 × slower.",
        "",
        "| | alone, ms | with a busy neighbour, ms | slowdown |",
        "|---|---|---|---|",
        f"| training step | {_f(ul['step_ms'], 1)} | {_f(ul['loaded_step_ms'], 1)} | {_f(ul['step_slowdown'], 2)} × |",
        f"| render 2048 rays | {_f(ul['render_ms'], 1)} | {_f(ul['loaded_render_ms'], 1)} | "
        f"{_f(ul['render_slowdown'], 2)} × |",
    ]


def median_export(records: list[dict]) -> dict:
    """The repeat of median total time (its stages with it), with every repeat's total and the highest peak
    memory of any repeat.

    Examples
    --------
    >>> median_export([{"seconds": 5.0, "peak_rss_mb": 800}, {"seconds": 4.0, "peak_rss_mb": 820},
    ...                {"seconds": 7.0, "peak_rss_mb": 790}])
    {'seconds': 5.0, 'peak_rss_mb': 820, 'repeats': 3, 'all_seconds': [5.0, 4.0, 7.0]}
    """
    totals = [float(r["seconds"]) for r in records]
    mid = sorted(range(len(records)), key=totals.__getitem__)[(len(records) - 1) // 2]
    return dict(records[mid], peak_rss_mb=max(r["peak_rss_mb"] for r in records), repeats=len(records),
                all_seconds=totals)


def export_markdown(ex: dict) -> list[str]:
    """The export section: one labelled point-cloud export of the indoor run, timed in a fresh process."""
    stages = ", ".join(f"{k} {_f(v, 1)} s" for k, v in ex.get("stages", {}).items())
    repeats = int(ex.get("repeats", 1))
    timed = (f"the median of {repeats} exports, each in a fresh process (all: "
             f"{', '.join(_f(t, 1) for t in ex['all_seconds'])} s;" if repeats > 1 else "in a fresh process (")
    return [
        "",
        "### Export: labelled points",
        "",
        f"`lift3d export --pointcloud` of the indoor `{ex.get('preset', '–')}` run above, {timed} "
        f"{ex['threads']} thread{'s' if ex['threads'] != 1 else ''}): extraction (isosurface, its refinement "
        "onto the rendered surface, visibility, labels from the heads, instances) plus writing `points.ply`. "
        "Loading the checkpoint and importing Open3D/PyVista are not included. Targets for 1M points: 5 s "
        "(the design target), and at most 30 s and 3 GiB peak memory. The stages are the median export's, the peak "
        "memory the highest of any.",
        "",
        "| points | seconds | extract s | write s | peak MB | load s |",
        "|---|---|---|---|---|---|",
        f"| {ex['points']:,} | {_f(ex['seconds'], 1)} | {_f(ex['extract_seconds'], 1)} | "
        f"{_f(ex['write_seconds'], 1)} | {_f(ex['peak_rss_mb'], 0)} | {_f(ex['load_seconds'], 1)} |",
        "",
        f"Extraction stages: {stages or '–'}.",
    ]
