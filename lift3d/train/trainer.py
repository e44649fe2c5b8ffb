"""``lift3d train``: resolve the configuration from the scene, train, checkpoint, evaluate, summarise.

Typical use::

    from lift3d.train.trainer import train
    result = train("scenes/room0", preset="fast", output_dir="outputs")
    print(result.run.path, result.summary["psnr"])
"""

from __future__ import annotations

import os
import random
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.profiler import record_function

from lift3d import __version__
from lift3d.data.scene import Scene, load_scene
from lift3d.errors import InputError, TrainingDiverged
from lift3d.eval.evaluate import compute_2d_metrics, gt_labels, json_safe, pseudo_labels, render_split
from lift3d.eval.frame_metrics import frame_psnrs
from lift3d.eval.metrics import psnr
from lift3d.field import grids
from lift3d.model.config import Config, config_from_dict, load_config, load_yaml, save_config, update_dataclass
from lift3d.model.labels import LabelSpace
from lift3d.model.normalization import (ContentPoints, SceneNormalization, derive_grid_resolution,
                                        infer_normalization, typical_camera_distance)
from lift3d.model.panoptic import PanopticModel, count_parameters
from lift3d.model.perceptual import build_perceptual_prior
from lift3d.model.run import LoadedRun
from lift3d.model.run_folder import RunFolder
from lift3d.render.rays import RayGenerator
from lift3d.render.renderer import RenderOptions, RenderOutputs
from lift3d.train.data import TrainingData
from lift3d.train.image_depth import CACHE_DIR as IMAGE_DEPTH_CACHE
from lift3d.train.image_depth import flat_info, frames_without_depth, image_depth_targets
from lift3d.train.distributed import DistContext, all_ranks_agree, broadcast_object, init_distributed, shutdown
from lift3d.train.observed import observed_cells
from lift3d.train.scene_sizes import instance_capacity, label_resolution
from lift3d.train.profile import choose_profile, refined_profile
from lift3d.train.scene_space import SceneGeometry, box_warnings, check_poses, scene_content
from lift3d.utils.device import available_cpus, resolve_device, set_threads
from lift3d.utils.threads import threads_from_environment
from lift3d.utils.memory import peak_rss_mb
from lift3d.utils.progress import progress_bar


# ------------------------------------------------------------------------------------------ configuration
def resolve_config(scene: Scene, preset: str, overrides: dict | None,
                   content: ContentPoints | None = None) -> tuple[Config, SceneNormalization]:
    """Preset + indoor/outdoor defaults + overrides, then sizes from the scene (except U and V, which need
    the labels: see :func:`resolve_label_sizes`). ``content``: where the scene's surfaces are
    (:func:`lift3d.train.scene_space.scene_content`; default: the depth maps, if any)."""
    norm, why_bounded = infer_normalization(scene, content=content)
    kind = "indoor" if norm.bounded else "outdoor"
    cfg = load_config(preset, kind, overrides)
    if cfg.field.contraction == "auto":
        cfg.field.contraction = "none" if norm.bounded else "linf"
    elif (cfg.field.contraction == "none") != norm.bounded:
        why_bounded += f"; overridden by field.contraction={cfg.field.contraction}"
        norm.bounded = cfg.field.contraction == "none"
    notes = {"bounded": norm.bounded, "why_bounded": why_bounded, "kind_defaults": kind}
    warnings = box_warnings(scene, content)
    if warnings:
        notes["scene_space_warnings"] = warnings
    if clipped_scene_box(scene, norm, cfg) is not None:
        # PanopticModel reads it: no density outside, rays start and stop at it
        if len(frames_without_depth(scene, scene.split("train"))) == 0:
            notes["render_box"] = {"normalized": None, "why": (
                "every training frame has a depth map: rays run to the normalised cube, the scene_box only clips "
                "the observed-cells lattice (with sensor depth the box cost F-score and point mIoU, docs/presets.md)")}
        else:
            aabb = np.asarray(scene.scene_box.aabb, float)
            pad = cfg.field.scene_box_pad * float(np.linalg.norm(aabb[1] - aabb[0]))
            notes["render_box"] = {
                "normalized": clipped_scene_box(scene, norm, cfg, pad).tolist(),
                "why": f"scene_box in transforms.json, grown by {pad:.4g} (field.clip_to_scene_box, "
                       "field.scene_box_pad): training frames without a depth map"}
    notes.update(cfg.field.kind_config.derive_sizes(
        lambda cap, minimum: derive_grid_resolution(scene, norm, cap, minimum)))
    # The categories go into the run too (names and colours for lift3d.load_run without the scene folder).
    cfg.scene = {"data": str(scene.root.resolve()), "name": scene.name, **notes,
                 "normalization": norm.to_json(), "categories": [c.to_json() for c in scene.categories]}
    return cfg, norm


def clipped_scene_box(scene: Scene, norm: SceneNormalization, cfg: Config, pad: float = 0.0) -> np.ndarray | None:
    """``[2, 3]`` the ``scene_box`` of a bounded scene in normalised coordinates, grown by ``pad`` (world units),
    when the field clips to it (``field.clip_to_scene_box``); else None."""
    if not (norm.bounded and scene.scene_box is not None and cfg.field.clip_to_scene_box):
        return None
    aabb = np.asarray(scene.scene_box.aabb, float)
    return np.sort(norm.to_normalized(aabb + [[-pad] * 3, [pad] * 3]), axis=0)


def resolve_label_sizes(cfg: Config, data: TrainingData, norm: SceneNormalization | None = None,
                        scene: Scene | None = None) -> None:
    """U from the categories the labels use (plus void); V from the objects the labels show, with headroom;
    no instance head without thing classes; the understanding grid's finest level from the thing sizes
    (:mod:`lift3d.train.scene_sizes`). Derived values and their reasons go to ``cfg.scene`` (config.yml)."""
    labels = data.labels
    if labels.num_channels < 2:
        raise InputError(cfg.scene.get("data", "--data"),
                         "every training frame's pseudo-label is void: there is no class to learn")
    if cfg.field.num_semantic_classes <= 0:
        cfg.field.num_semantic_classes = labels.num_channels
    elif cfg.field.num_semantic_classes < labels.num_channels:
        raise InputError("--field.num-semantic-classes",
                         f"the labels use {labels.num_channels - 1} categories (+ void = {labels.num_channels}); "
                         f"U={cfg.field.num_semantic_classes} is too few")
    notes: dict[str, Any] = {}
    if not labels.thing_ids:
        cfg.field.num_instance_channels = 0
        notes["why_instance_channels"] = "no thing classes in the labels: no instance head"
    elif cfg.field.num_instance_channels <= 0:
        v, why, numbers = instance_capacity(data.thing_segments, len(data), cfg.data.instance_headroom,
                                            cfg.data.max_instance_channels)
        cfg.field.num_instance_channels = v
        notes.update(why_instance_channels=why, instance_estimate=numbers)
    elif "why_instance_channels" not in cfg.scene:  # (a resumed run keeps the reason it was given)
        notes["why_instance_channels"] = "set by the user"
    if norm is not None and scene is not None:
        fallback = typical_camera_distance(scene, norm) / norm.scale
        extent = 2.0 if norm.bounded else 4.0

        def label_resolution_for(**kw) -> tuple[int, str]:
            res, why, _ = label_resolution(data.thing_segments, scale=norm.scale, fallback_depth=fallback,
                                           extent=extent, **kw)
            return res, why

        notes.update(cfg.field.kind_config.derive_label_sizes(label_resolution_for))
    cfg.scene.update(labels=labels.to_dict(), max_instances_per_frame=int(data.max_instances_per_frame),
                     depth_supervision=data.depth is not None, inputs=input_kind(cfg, data), **notes)


def input_kind(cfg: Config, data: TrainingData) -> str:
    """What supervises geometry besides the colours: ``RGB + depth`` (depth maps), ``RGB + SfM points``
    (depth from the images: triangulated points, plane-sweep depth) or ``RGB``; the benchmark's *inputs*."""
    if data.depth is not None and cfg.losses.depth > 0:
        return "RGB + depth"
    if data.num_targets > 0 and cfg.losses.image_depth > 0:
        return "RGB + SfM points"
    return "RGB"


# ------------------------------------------------------------------------------------------ training
@dataclass
class TrainResult:
    run: RunFolder
    steps: int
    seconds: float
    peak_rss_mb: float
    summary: dict[str, Any] = field(default_factory=dict)


def training_progress(step: int, cfg: Config, elapsed: float = 0.0) -> float:
    """Fraction of training done, in [0, 1]. With a time budget it is whichever is further along, steps or
    wall time, so runs compared at equal wall time all go through their whole schedule (learning rate,
    when L_seg starts, coarse-to-fine levels)."""
    progress = step / max(1, cfg.optim.steps)
    if cfg.trainer.time_budget > 0:
        progress = max(progress, elapsed / cfg.trainer.time_budget)
    return min(1.0, progress)


def _lr_factor(step: int, cfg: Config, elapsed: float = 0.0) -> float:
    """Linear warm-up, then exponential decay to ``lr_final_factor`` at the end of training."""
    warm = min(1.0, (step + 1) / max(1, cfg.optim.warmup_steps))
    return warm * cfg.optim.lr_final_factor ** training_progress(step, cfg, elapsed)


class Trainer:
    """Owns the model, optimiser, data and run folder of one training run."""

    def __init__(self, scene: Scene, cfg: Config, norm: SceneNormalization, run: RunFolder,
                 device: torch.device, progress: bool = True, labels: LabelSpace | None = None,
                 dist_ctx: DistContext | None = None, geometry: SceneGeometry | None = None):
        self.scene, self.cfg, self.norm, self.run, self.device = scene, cfg, norm, run, device
        self.ctx = dist_ctx or DistContext()
        self.progress = progress and self.ctx.is_main
        self.rays = RayGenerator(scene.cameras, norm.c2w_normalized(scene.cameras.c2w), device)
        targets = None
        if cfg.losses.image_depth > 0:
            # A resumed run reads the points it triangulated from its own folder (cached at the first start).
            profile = cfg.scene.get("profile") or {}
            targets = image_depth_targets(scene, scene.split("train"), cfg.image_depth, cache=run.path / IMAGE_DEPTH_CACHE,
                                          progress=self.progress, premises=profile.get("premises"),
                                          profile=profile.get("name"), refine_room=cfg.data.profile == "auto",
                                          sparse=geometry.sparse if geometry else None,
                                          dense=geometry.dense if geometry else None)
            cfg.scene["image_depth"] = json_safe(targets.info)
            if "setup_seconds" in cfg.scene and "seconds" in targets.info:
                cfg.scene["setup_seconds"]["depth_targets"] = targets.info["seconds"]
            if "room_evidence" in targets.info:  # the stuff planes said whether the room is square, fills its box
                cfg.scene["profile"] = refined_profile(profile, targets.info["premises"], targets.info["room_evidence"])
        self.data = TrainingData(scene, scene.split("train"), self.rays, labels, progress=self.progress,
                                 depth_scale=norm.scale if cfg.losses.depth > 0 else None, targets=targets,
                                 target_scale=norm.scale, target_sigma_scale=cfg.image_depth.sigma_scale,
                                 target_min_sigma=cfg.image_depth.min_sigma)
        resolve_label_sizes(cfg, self.data, norm, scene)
        self.model = PanopticModel(cfg, self.data.labels).to(device)
        if cfg.field.observed_resolution > 0:  # (a resumed run loads its own lattice with the checkpoint)
            cams = replace(scene.cameras, c2w=norm.c2w_normalized(scene.cameras.c2w))
            self.model.field.space.observed = observed_cells(
                self.model.field.space, cams, scene.split("train"), cfg.field.observed_resolution,
                near=cfg.sampling.near_plane, box=clipped_scene_box(scene, norm, cfg)).to(device)
        self.model.train()
        # Under DDP gradients must pass through autograd's accumulation hooks (see field.grids).
        grids.ACCUMULATE_GRAD_IN_PLACE = not self.ctx.enabled
        self.forward_model: torch.nn.Module = self.model
        if self.ctx.enabled:
            from torch.nn.parallel import DistributedDataParallel

            self.forward_model = DistributedDataParallel(
                self.model, device_ids=[device.index] if device.type == "cuda" else None)
        # Each rank draws its share of the images of a step.
        self.images_per_rank = max(1, cfg.data.images_per_batch // self.ctx.world_size)
        fused = device.type in ("cpu", "cuda")
        self.optimizer = torch.optim.Adam(
            [
                {"params": self.model.grid_parameters(), "lr": cfg.optim.lr_grid, "base_lr": cfg.optim.lr_grid, "eps": 1e-15},
                {"params": self.model.decoder_parameters(), "lr": cfg.optim.lr_mlp, "base_lr": cfg.optim.lr_mlp, "eps": 1e-15},
            ],
            betas=(0.9, 0.99),
            fused=fused,
        )
        # Every random draw of training (batches, jitter, background, L_tv) comes from this generator; it lives
        # on the training device because torch.rand(..., device=cuda, generator=<cpu generator>) is an error.
        self.generator = torch.Generator(device=device).manual_seed(cfg.trainer.seed + 1000003 * self.ctx.rank)
        self.step = 0
        self.train_seconds = 0.0  # training time before this process (resumed runs)
        self._fit_start: float | None = None
        self._first_loss: float | None = None  # reference for the divergence check
        self.perceptual = None
        if cfg.losses.feature > 0 and cfg.data.patch_size > 0:
            self.perceptual = build_perceptual_prior(cfg.trainer.feature_weights).to(device)
        self.eval_frames = self._pick_eval_frames()

    def _pick_eval_frames(self) -> list[int]:
        val = self.scene.split("val")
        k = min(self.cfg.trainer.eval_images, len(val))
        return [int(val[i]) for i in np.linspace(0, len(val) - 1, k).round().astype(int)] if k else []

    # ---------------------------------------------------------------- checkpoints
    def state(self) -> dict[str, Any]:
        return {
            "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "step": self.step,
            "train_seconds": self.elapsed(),
            "config": self.cfg.to_dict(),
            "labels": self.data.labels.to_dict(),
            "normalization": self.norm.to_json(),
            "rng": {"torch": self.generator.get_state(), "cpu": torch.get_rng_state(),
                    "device": self.generator.device.type},
            "lift3d_version": __version__,
        }

    def save_checkpoint(self) -> Path:
        for p in self.model.parameters():
            if not bool(torch.isfinite(p).all()):
                raise TrainingDiverged(
                    f"parameters became non-finite at step {self.step}; not overwriting the last good checkpoint "
                    f"in {self.run.checkpoint_dir} (lower --optim.lr-grid / --optim.lr-mlp and --resume)"
                )
        return self.run.save_checkpoint(self.step, self.state(), keep=self.cfg.trainer.keep_checkpoints)

    def restore(self, state: dict[str, Any]) -> None:
        try:
            self.model.load_state_dict(state["model"])
            self.optimizer.load_state_dict(state["optimizer"])
        except (RuntimeError, ValueError, KeyError) as exc:  # the same report as load_run's
            raise InputError(state.get("_path", self.run.checkpoint_dir),
                             f"checkpoint does not match this lift3d ({exc})") from None
        self.step = int(state["step"])
        self.train_seconds = float(state.get("train_seconds", 0.0))
        if "rng" in state:
            # A generator's state only fits a generator of the same device type (a run trained on the CPU and
            # resumed on a GPU keeps the freshly seeded stream).
            if state["rng"].get("device", "cpu") == self.generator.device.type:
                self.generator.set_state(state["rng"]["torch"].cpu())
            torch.set_rng_state(state["rng"]["cpu"].cpu())

    # ---------------------------------------------------------------- one step
    def losses(self, batch) -> tuple[dict[str, torch.Tensor], RenderOutputs]:
        """The model's weighted loss terms of one batch and their sum ``total``; and the render they score."""
        progress = training_progress(self.step, self.cfg, self.elapsed())
        self.model.field.set_training_progress(progress)
        anneal_steps = self.cfg.sampling.proposal_anneal_steps
        anneal = min(1.0, self.step / anneal_steps) if anneal_steps > 0 else 1.0
        depth_target = batch.depth if self.cfg.losses.depth > 0 or self.cfg.losses.image_depth > 0 else None
        # Samples around a target from the images span ±2σ of it (DS-NeRF's Gaussian needs them).
        spread = 2.0 * batch.depth_sigma if depth_target is not None and batch.depth_sigma is not None else None
        options = RenderOptions(training=True, with_labels=self.model.trains_labels, proposal_anneal=anneal)
        out = self.forward_model(batch.origins, batch.dirs, options, generator=self.generator,
                                 depth_target=depth_target, depth_spread=spread)
        terms = self.model.get_loss_dict(out, batch, progress=progress, generator=self.generator,
                                         perceptual=self.perceptual)
        terms["total"] = sum(terms.values())
        return terms, out

    def elapsed(self) -> float:
        """Seconds of training so far (including earlier processes of a resumed run)."""
        now = time.perf_counter() - self._fit_start if self._fit_start is not None else 0.0
        return self.train_seconds + now

    def train_step(self) -> dict[str, float] | None:
        """One optimisation step; None when the loss was not finite (the step is skipped)."""
        d = self.cfg.data
        occ = self.cfg.field.occupancy
        if occ.resolution > 0 and self.step >= occ.start and (self.step - occ.start) % max(1, occ.update_every) == 0:
            with record_function("step.occupancy"):
                self.update_occupancy()
        # record_function labels name the phases in `lift3d bench`'s profile (no cost without a profiler).
        with record_function("step.sample_batch"):
            batch = self.data.sample(self.images_per_rank, d.rays_per_image, d.patch_size, self.generator,
                                     target_rays_per_image=self.cfg.image_depth.rays_per_image,
                                     point_share=self.cfg.image_depth.point_share,
                                     segments_per_image=d.segments_per_image, rays_per_segment=d.rays_per_segment,
                                     thing_segment_weight=d.thing_segment_weight)
        factor = _lr_factor(self.step, self.cfg, self.elapsed())
        for group in self.optimizer.param_groups:
            group["lr"] = group["base_lr"] * factor
        # Keep gradient buffers allocated: the grid lookups add into them in place (see field.grids).
        self.optimizer.zero_grad(set_to_none=False)
        with record_function("step.forward_and_losses"):
            terms, out = self.losses(batch)
        total = terms["total"]
        good = bool(torch.isfinite(total))
        factor = self.cfg.optim.divergence_factor
        if good and factor > 0:
            if self._first_loss is None:
                self._first_loss = float(total.detach())
            good = float(total.detach()) <= factor * max(self._first_loss, 1e-8)
        if not all_ranks_agree(good, self.ctx):
            self.optimizer.zero_grad(set_to_none=False)
            return None
        with record_function("step.backward"):
            total.backward()
        with record_function("step.optimizer"):
            self.optimizer.step()
        logged = {k: float(v.detach()) for k, v in terms.items()}
        logged["psnr"] = psnr(out.rgb.detach().cpu().numpy(), batch.rgb.cpu().numpy())
        return logged

    def update_occupancy(self) -> None:
        """One update of the model's occupancy grid. Where in each cell the density is measured follows from
        the seed and the step alone, so every rank of a distributed run keeps the same grid and a resumed
        run the same sequence."""
        gen = torch.Generator(device=self.device).manual_seed(self.cfg.trainer.seed * 1_000_003 + self.step)
        self.model.update_occupancy(gen)

    # ---------------------------------------------------------------- evaluation
    def as_loaded_run(self) -> LoadedRun:
        """The model being trained, as a :class:`~lift3d.model.run.LoadedRun` (what evaluation renders)."""
        return LoadedRun(self.run, self.cfg, self.model, self.norm, self.data.labels, self.step, self.device)

    def evaluate(self, frames: list[int] | None = None) -> dict[str, float]:
        """Quick held-out metrics through :mod:`lift3d.eval`: PSNR, and mIoU / PQ^scene against GT (or the
        pseudo-labels without GT)."""
        frames = self.eval_frames if frames is None else frames
        if not frames:
            return {}
        rendered = render_split(self.as_loaded_run(), self.scene, frames, progress=False)
        use_gt = self.scene.has_gt
        target = gt_labels(self.scene, frames) if use_gt else pseudo_labels(self.scene, frames)
        m = compute_2d_metrics(rendered.labels(), target, self.scene.thing_ids, self.scene.stuff_ids)
        return {"psnr": float(np.mean(frame_psnrs(self.scene, rendered))), "miou": float(m["miou"]),
                "pq_scene": float(m["pq_scene"]), "against": "gt" if use_gt else "pseudo_labels"}

    def replicas_identical(self) -> bool:
        """Every rank holds the same parameters (DDP keeps them in sync; checked once at the end)."""
        import torch.distributed as dist

        checksum = torch.stack([p.detach().double().sum() for p in self.model.parameters()]).cpu()
        gathered = [torch.zeros_like(checksum) for _ in range(self.ctx.world_size)]
        dist.all_gather(gathered, checksum)
        return all(torch.equal(g, gathered[0]) for g in gathered)

    # ---------------------------------------------------------------- the loop
    def fit(self) -> TrainResult:
        cfg = self.cfg
        start = time.perf_counter()
        self._fit_start = start
        bad = 0
        last: dict[str, float] = {}
        summary: dict[str, Any] = {}
        steps_total = cfg.optim.steps
        bar = progress_bar(total=steps_total, desc="train", disable=not self.progress, unit="step")
        bar.update(self.step)
        try:
            while self.step < steps_total:
                terms = self.train_step()
                if terms is None:
                    bad += 1
                    if bad >= cfg.optim.max_bad_steps:
                        raise TrainingDiverged(
                            f"the loss was not finite (or above {cfg.optim.divergence_factor:g} x its first value) for "
                            f"{bad} consecutive steps at step {self.step}; the last good "
                            f"checkpoint in {self.run.checkpoint_dir} is intact (lower the learning rates and --resume)"
                        )
                    continue
                bad = 0
                last = terms
                self.step += 1
                bar.update(1)
                main = self.ctx.is_main
                if main and (self.step % max(1, cfg.trainer.log_every) == 0 or self.step == steps_total):
                    bar.set_postfix(loss=f"{terms['total']:.4f}", psnr=f"{terms['psnr']:.2f}")
                    self.run.append_log({"step": self.step, "time": time.perf_counter() - start, **terms})
                if main and cfg.trainer.eval_every and self.step % cfg.trainer.eval_every == 0 and self.step < steps_total:
                    ev = self.evaluate()
                    self.run.append_log({"step": self.step, "time": time.perf_counter() - start, "eval": ev})
                if main and cfg.trainer.checkpoint_every and self.step % cfg.trainer.checkpoint_every == 0:
                    self.save_checkpoint()
                over_budget = bool(cfg.trainer.time_budget) and self.elapsed() > cfg.trainer.time_budget
                if not all_ranks_agree(not over_budget, self.ctx):  # every rank stops at the same step
                    summary["stopped_by_time_budget"] = True
                    break
        finally:
            bar.close()
        seconds = time.perf_counter() - start
        ev: dict[str, Any] = {}
        if self.ctx.enabled:
            summary["replicas_identical"] = self.replicas_identical()
        if self.cfg.field.occupancy.resolution > 0:
            self.update_occupancy()  # the final checkpoint's grid measures the final field
        if self.ctx.is_main:
            self.save_checkpoint()
            ev = self.evaluate()
            self.run.append_log({"step": self.step, "time": seconds, "eval": ev, "final": True})
        summary.update(steps=self.step, seconds=seconds, last=last, eval=ev, world_size=self.ctx.world_size)
        return TrainResult(self.run, self.step, seconds, peak_rss_mb(), summary)


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def train(
    data: str | Path | None = None,
    preset: str = "fast",
    output_dir: str | Path = "outputs",
    overrides: dict | None = None,
    resume: str | Path | None = None,
    progress: bool = True,
    print_summary: bool = True,
) -> TrainResult:
    """Train a panoptic radiance field on a scene folder (or resume a run).

    Parameters
    ----------
    data : str or Path
        Scene folder (not needed with ``resume``).
    preset : str
        ``fast``, ``balanced``, ``quality`` or a YAML file.
    output_dir : str or Path
        Root of the run folders.
    overrides : dict, optional
        Nested settings, e.g. ``{"optim": {"steps": 500}}``.
    resume : str or Path, optional
        A run folder to continue from its newest checkpoint (its config.yml wins over preset/overrides,
        except ``optim.steps`` and ``trainer`` settings given in ``overrides``).
    """
    ctx, device_name = init_distributed((overrides or {}).get("trainer", {}).get("device", "auto"))
    try:
        return _train(data, preset, output_dir, overrides, resume, progress, print_summary, ctx, device_name)
    finally:
        shutdown(ctx)


def _remove_if_empty(path: Path, keep_below: Path) -> None:
    """Delete a run folder that holds no file yet (only empty subfolders), then its parents up to (not
    including) ``keep_below`` while they are empty."""
    import shutil

    path = Path(path)
    if not path.is_dir() or any(p.is_file() for p in path.rglob("*")):
        return
    shutil.rmtree(path, ignore_errors=True)
    stop = Path(keep_below).resolve()
    parent = path.parent
    while parent.resolve() != stop and stop in parent.resolve().parents:
        try:
            parent.rmdir()  # only succeeds when empty
        except OSError:
            break
        parent = parent.parent


def _labelled_scene(data) -> Scene:
    """The scene folder ``data``, which must have pseudo-labels: they are what training lifts to 3D."""
    scene = load_scene(data)
    if not scene.has_pseudo_labels:
        raise InputError(scene.root, f"no pseudo-labels: run lift3d label --data {scene.root} (a segmenter or "
                                     "imported predictions) before training, or convert with --predictions")
    return scene


def _train(data, preset, output_dir, overrides, resume, progress, print_summary, ctx: DistContext,
           device_name: str) -> TrainResult:
    geometry = None
    if resume is not None:
        run = RunFolder.open(resume)
        cfg = config_from_dict(load_yaml(run.config_path), str(run.config_path))
        if overrides:
            allowed = {k: v for k, v in overrides.items() if k in ("trainer",)}
            if "optim" in overrides and "steps" in overrides["optim"]:
                allowed["optim"] = {"steps": overrides["optim"]["steps"]}
            cfg = update_dataclass(cfg, allowed, "command line")
        scene = _labelled_scene(data or cfg.scene["data"])
        norm = SceneNormalization.from_json(cfg.scene["normalization"])
    else:
        if data is None:
            raise InputError("--data", "a scene folder is required (or --resume RUN)")
        scene = _labelled_scene(data)
        started = time.perf_counter()
        pose_check = check_poses(scene)  # a pose file read with the wrong convention stops here, in one line
        pose_seconds = round(time.perf_counter() - started, 2)
        # The points that say where the surfaces are size the scene space; triangulated ones are the depth
        # targets' starting points too (handed on below, not computed twice).
        geometry = scene_content(scene, load_config(preset, "indoor", overrides), progress and ctx.is_main)
        content = geometry.content
        cfg, norm = resolve_config(scene, preset, overrides, content)
        cfg.scene["pose_check"] = pose_check
        # where the time before the first step goes (depth_targets joins it when the trainer builds them)
        cfg.scene["setup_seconds"] = {"pose_check": pose_seconds, **geometry.seconds}
        # Which priors may run: from what the scene shows (or --profile), with the evidence, in config.yml.
        cfg.scene["profile"] = choose_profile(scene, norm, content, cfg.data.profile).to_json()
        resolve_device(device_name if ctx.enabled else cfg.trainer.device)  # a bad --device leaves no empty run
        # One run folder for the whole job: rank 0 makes it, the others are told where it is.
        run_path = RunFolder.create(output_dir, scene.name, cfg.preset).path if ctx.is_main else None
        run = RunFolder(Path(broadcast_object(str(run_path) if run_path else None, ctx)))
    if ctx.enabled:
        cfg.trainer.device = device_name
    # Ranks sharing a machine split its CPUs, unless the user chose (trainer.threads, LIFT3D_THREADS or
    # OMP_NUM_THREADS).
    share = ctx.enabled and threads_from_environment() is None
    set_threads(cfg.trainer.threads or (max(1, _cpu_share(ctx)) if share else None))
    seed_everything(cfg.trainer.seed)
    device = resolve_device(device_name if ctx.enabled else cfg.trainer.device)
    labels = LabelSpace.from_dict(cfg.scene["labels"]) if resume is not None and "labels" in cfg.scene else None
    try:
        trainer = Trainer(scene, cfg, norm, run, device, progress=progress, labels=labels, dist_ctx=ctx,
                          geometry=geometry)
    except BaseException:
        if resume is None and ctx.is_main:
            _remove_if_empty(run.path, keep_below=Path(output_dir))  # e.g. a corrupt frame: no empty run left
        raise
    if resume is not None:
        trainer.restore(run.load_latest_checkpoint(map_location=device))
    elif ctx.is_main:
        save_config(cfg, run.config_path)
        norm.save(run.transform_path)
    result = trainer.fit()
    if ctx.is_main:
        save_config(cfg, run.config_path)
    result.summary["parameters"] = count_parameters(trainer.model)
    result.summary["finest_resolution"] = trainer.model.field.finest_resolution
    result.summary["depth_supervision"] = trainer.data.depth is not None
    result.summary["inputs"] = cfg.scene.get("inputs", "RGB")
    if "image_depth" in cfg.scene:
        result.summary["image_depth"] = cfg.scene["image_depth"]
    if print_summary and ctx.is_main:
        print(format_summary(result, cfg))
    return result


def _cpu_share(ctx: DistContext) -> int:
    """CPU threads per rank when several ranks share one machine (avoid oversubscription)."""
    local_world = int(os.environ.get("LOCAL_WORLD_SIZE", ctx.world_size))
    return max(1, available_cpus() // max(1, local_world))


def _finest(resolution: int) -> str:
    return f", grid {resolution}^3" if resolution else ""


def image_depth_lines(info: dict | None) -> list[str]:
    """Summary lines about depth from the images: source, points, median error, coverage, warnings."""
    info = flat_info(info)  # the steps' counts where the lines below read them
    if not info or str(info.get("source", "")).startswith("none (every"):
        return []  # every training frame has its own depth map
    if not info.get("targets"):
        text = f"  depth targets  none from the images ({info.get('source')})"
    else:
        text = (f"  depth targets  {info['targets']} from the images ({info['source']}: {info.get('points', 0)} points "
                f"from {info.get('points_from')}, median reprojection error {info.get('median_error_px')} px, "
                f"{info.get('observations', 0)} observations")
        if "dense_coverage" in info:
            text += f", plane sweep {100 * info['dense_coverage']:.1f} % of pixels"
        planes = info.get("planes")
        if isinstance(planes, dict) and planes.get("planes"):
            text += (f", {planes['planes']} stuff planes giving {planes.get('targets', 0)} targets"
                     + (f" ({planes['floor_boundary_points']} wall points from the labels' floor line)"
                        if planes.get("floor_boundary_points") else "")
                     + (f" ({planes['floor_line_walls']} far walls where the views' floor lines agree)"
                        if planes.get("floor_line_walls") else "")
                     + (f" ({planes['floor_line_moved']} walls moved to where the floor lines put them)"
                        if planes.get("floor_line_moved") else "")
                     + (f" ({planes['refuted_by_other_views']} refuted by other views' labels)"
                        if planes.get("refuted_by_other_views") else "")
                     + (f" ({planes['ceiling_extended']} textured ceilings grown over their pixels)"
                        if planes.get("ceiling_extended") else "")
                     + (f" ({planes['enclosed']} on segments a plane surrounds)" if planes.get("enclosed") else "")
                     + (f" ({planes['standing']} on {planes['standing_faces']} upright faces of things on the floor)"
                        if planes.get("standing") else ""))
        if info.get("dense_on_things"):
            text += f", {info['dense_on_things']} plane-sweep depths on objects"
            if info.get("dense_on_things_one_source"):
                text += f" ({info['dense_on_things_one_source']} confirmed by one source view)"
        text += f"; {info.get('seconds', 0):.0f} s)"
    return [text] + [f"  warning        {w}" for w in info.get("warnings", [])]


def format_summary(result: TrainResult, cfg: Config) -> str:
    ev = result.summary.get("eval", {})
    lines = [
        "",
        f"lift3d train: {result.steps} steps in {result.seconds:.0f} s "
        f"({result.steps / max(result.seconds, 1e-9):.1f} steps/s), peak memory {result.peak_rss_mb:.0f} MB",
        f"  run folder     {result.run.path}",
        f"  model          {cfg.field.kind}{_finest(result.summary.get('finest_resolution', 0))}, "
        f"U={cfg.field.num_semantic_classes}, V={cfg.field.num_instance_channels}, "
        f"{'bounded' if cfg.field.contraction == 'none' else 'unbounded (' + cfg.field.contraction + ')'}"
        f"{', depth-supervised' if cfg.scene.get('depth_supervision') else ''}",
    ]
    lines.append(f"  scene space    {cfg.scene.get('why_bounded', '')}")
    if cfg.scene.get("profile"):
        lines.append(f"  profile        {cfg.scene['profile']['name']} ({cfg.scene['profile']['why']})")
    lines += [f"  warning        {w}" for w in cfg.scene.get("scene_space_warnings", [])]
    if cfg.scene.get("pose_check", {}).get("warning"):
        lines.append(f"  warning        {cfg.scene['pose_check']['warning']}")
    lines += image_depth_lines(cfg.scene.get("image_depth"))
    if ev:
        lines.append(f"  held-out views PSNR {ev['psnr']:.2f} dB, mIoU {ev['miou']:.3f}, PQ^scene {ev['pq_scene']:.3f} "
                     f"(against {ev['against'].replace('_', '-')}, the instance head's ids; run `lift3d eval --run "
                     f"{result.run.path}` for all metrics)")
    return "\n".join(lines)
