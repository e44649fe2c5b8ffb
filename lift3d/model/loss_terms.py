"""The loss of a training step: a registry of weighted loss terms (the paper's losses, :mod:`lift3d.model.losses`).

Every term is a function registered with :func:`loss_term` that reads the step's :class:`LossInputs` and
returns its *weighted* value (the weight is applied where the term is computed), or None when it does not
apply to this step (weight 0, or the batch lacks what it needs).
:meth:`lift3d.model.panoptic.PanopticModel.get_loss_dict` calls the terms in registration order and the
trainer sums what it gets, so ``log.jsonl`` records every term with its weight applied.

Adding a loss term: its weight (and any knob) in :class:`LossConfig` and one function below with its
``@loss_term`` registration; the pure math goes to :mod:`lift3d.model.losses`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch
from torch import Tensor, nn

from lift3d.errors import InputError
from lift3d.field.base import Field
from lift3d.model.losses import (
    charbonnier_loss,
    depth_loss,
    disparity_loss,
    distortion_loss,
    ds_depth_loss,
    feature_loss,
    instance_loss,
    segment_consistency_loss,
    planar_segment_loss,
    segment_groups,
    semantic_loss,
)
from lift3d.render.renderer import RenderOutputs


@dataclass
class LossConfig:
    """Loss weights (paper defaults) and switches for ablations. A weight of 0 turns a loss off."""

    color: float = 1.0
    """L_color: Charbonnier photometric loss."""
    charbonnier_eps: float = 1e-4
    """ε of the Charbonnier loss."""
    distill: float = 1.2
    """L_distill: inter-level (proposal) distillation."""
    semantic: float = 0.1
    """L_sem: confidence-weighted semantic cross-entropy."""
    instance: float = 0.1
    """L_ins: instance cross-entropy after per-image linear assignment."""
    segment: float = 0.12
    """L_seg: segment-consistency loss over rays sharing a 2D segment."""
    segment_min_rays: int = 4
    """Smallest ray group (same image, same 2D segment) that L_seg uses."""
    segment_start: float = 0.3
    """Fraction of the training steps before L_seg starts: its target is the field's own dominant class, so
    switched on from step 0 it locks in whatever class the untrained field happens to favour."""
    feature: float = 0.2
    """L_feat: perceptual-prior feature loss on rendered vs observed patches."""
    regularization: float = 0.001
    """Weight of L_tv + L_disp."""
    distortion: float = 0.0
    """L_dist (mip-NeRF 360's distortion loss; not in the paper, so 0 by default): pulls each ray's weight
    into one compact interval. Textureless walls otherwise stay a metre-deep fog whose colour matches from
    every view, which renders fine but puts the exported surface in the wrong place."""
    depth: float = 0.0
    """L_depth (not in the paper): supervision from the scene's depth maps (``depth_file_path``, e.g. an
    RGB-D sensor) where they exist; 0 = RGB only. See :func:`depth_loss`."""
    depth_margin: float = 0.02
    """Half-width (normalised units) of the band around the measured depth in which L_depth lets weight
    sit; about 7 cm in a 7 m room."""
    image_depth: float = 0.0
    """Weight of the depth loss on targets from the images (triangulated points, plane-sweep depth; see
    ``image_depth.*``) in frames without a depth map; 0 = off."""
    planarity: float = 0.0
    """Weight of the planarity prior (:func:`planar_segment_loss`): inside every stuff segment of the
    training patches, second differences of rendered inverse depth are pulled to 0 (exact for planes:
    walls, floors, ceilings), needing no depth. 0 = off."""
    image_depth_loss: str = "ds"
    """``ds``: DS-NeRF's cross-entropy between each ray's weights and N(d, σ²) (:func:`ds_depth_loss`);
    ``margin``: L_depth with a band of ``max(depth_margin, 2σ)`` per ray (:func:`depth_loss`)."""
    tv_samples: int = 4096
    """Grid nodes per level and axis sampled for L_tv each step."""
    use_confidence: bool = True
    """Weight label losses by the pseudo-label confidence λ_p (segment score × pixel confidence)."""


@dataclass
class RayBatch:
    """One training step's rays and their targets (drawn by :class:`lift3d.train.data.TrainingData`). The
    first ``n_patch_rays`` rays are patches, image by image, row-major."""

    origins: Tensor  # [R, 3]
    dirs: Tensor  # [R, 3]
    rgb: Tensor  # [R, 3] float in [0, 1]
    semantic: Tensor  # [R] int64 channel, 0 = void
    instance: Tensor  # [R] int64 per-image 2D instance id, 0 = none
    segment: Tensor  # [R] int64 per-image 2D segment id, 0 = void
    confidence: Tensor | None  # [R] float
    image: Tensor  # [R] int64 frame index
    depth: Tensor | None  # [R] float distance along the ray to the surface (normalised units), 0 = unknown
    n_patch_rays: int
    patch_size: int
    cos: Tensor | None = None
    """[R] cosine between each ray and its camera's optical axis (ray distance × cos = z-depth)."""
    depth_sigma: Tensor | None = None
    """[R] standard deviation (normalised units, along the ray) of depth targets from the images; 0 where
    the depth is a sensor's (or unknown). The rays with a target from the images come last."""


@dataclass
class LossInputs:
    """Everything a loss term may read."""

    outputs: RenderOutputs
    batch: RayBatch
    cfg: LossConfig
    field: Field
    has_proposals: bool
    progress: float
    """Fraction of training done, in [0, 1]."""
    generator: torch.Generator | None = None
    perceptual: nn.Module | None = None
    """The frozen feature extractor of L_feat (:mod:`lift3d.model.perceptual`), when it is on."""

    @property
    def confidence(self) -> Tensor | None:
        """Per-ray weight λ_p of the label losses (None when ``use_confidence`` is off)."""
        return self.batch.confidence if self.cfg.use_confidence else None


LossTerm = Callable[[LossInputs], "Tensor | None"]
#: Registered loss terms, in the order they are computed and summed.
LOSS_TERMS: dict[str, LossTerm] = {}


def loss_term(name: str) -> Callable[[LossTerm], LossTerm]:
    """Register a loss term under ``name`` (its key in the loss dict and in ``log.jsonl``)."""

    def register(fn: LossTerm) -> LossTerm:
        if name in LOSS_TERMS:
            raise ValueError(f"loss term {name!r} is registered twice")
        LOSS_TERMS[name] = fn
        return fn

    return register


def needs_labels(cfg: LossConfig) -> bool:
    """A label loss is on, so training renders must composite semantic / instance logits."""
    return cfg.semantic > 0 or cfg.instance > 0 or cfg.segment > 0


def compute_loss_terms(inputs: LossInputs) -> dict[str, Tensor]:
    """Every registered term that applies to this step, weighted, in registration order."""
    terms = {}
    for name, term in LOSS_TERMS.items():
        value = term(inputs)
        if value is not None:
            terms[name] = value
    return terms


# ------------------------------------------------------------------------------------------ the terms
@loss_term("color")
def _color(x: LossInputs) -> Tensor:
    return x.cfg.color * charbonnier_loss(x.outputs.rgb, x.batch.rgb, x.cfg.charbonnier_eps)


@loss_term("distill")
def _distill(x: LossInputs) -> Tensor | None:
    return x.cfg.distill * x.outputs.distill if x.has_proposals else None


@loss_term("semantic")
def _semantic(x: LossInputs) -> Tensor | None:
    if x.cfg.semantic <= 0:
        return None
    return x.cfg.semantic * semantic_loss(x.outputs.semantic, x.batch.semantic, x.confidence)


@loss_term("instance")
def _instance(x: LossInputs) -> Tensor | None:
    if x.cfg.instance <= 0 or x.outputs.instance is None:
        return None
    return x.cfg.instance * instance_loss(x.outputs.instance, x.batch.instance, x.batch.image, x.confidence)


@loss_term("segment")
def _segment(x: LossInputs) -> Tensor | None:
    if x.cfg.segment <= 0 or x.progress < x.cfg.segment_start:
        return None
    groups = segment_groups(x.batch.image, x.batch.segment, x.cfg.segment_min_rays)
    return x.cfg.segment * segment_consistency_loss(x.outputs.semantic, groups, x.confidence)


@loss_term("feature")
def _feature(x: LossInputs) -> Tensor | None:
    b = x.batch
    if x.perceptual is None or x.cfg.feature <= 0 or b.n_patch_rays <= 0:
        return None
    ps = b.patch_size
    pred = x.outputs.rgb[: b.n_patch_rays].view(-1, ps, ps, 3).permute(0, 3, 1, 2)
    obs = b.rgb[: b.n_patch_rays].view(-1, ps, ps, 3).permute(0, 3, 1, 2)
    with torch.no_grad():
        f_obs = x.perceptual(obs)
    return x.cfg.feature * feature_loss(x.perceptual(pred), f_obs)


@loss_term("tv")
def _tv(x: LossInputs) -> Tensor | None:
    grids = x.field.tv_grids
    if x.cfg.regularization <= 0 or not grids:
        return None
    return x.cfg.regularization * torch.stack([g.total_variation(x.cfg.tv_samples, x.generator) for g in grids]).mean()


@loss_term("disparity")
def _disparity(x: LossInputs) -> Tensor | None:
    if x.cfg.regularization <= 0:
        return None
    return x.cfg.regularization * disparity_loss(x.outputs.weights, x.outputs.t_mid)


@loss_term("depth")
def _depth(x: LossInputs) -> Tensor | None:
    if x.cfg.depth <= 0 or x.batch.depth is None:
        return None
    target = x.batch.depth
    if x.batch.depth_sigma is not None:  # targets from the images have their own term
        target = torch.where(x.batch.depth_sigma > 0, torch.zeros_like(target), target)
    return x.cfg.depth * depth_loss(x.outputs.weights, x.outputs.t_mid, target, x.cfg.depth_margin)


@loss_term("image_depth")
def _image_depth(x: LossInputs) -> Tensor | None:
    b = x.batch
    if x.cfg.image_depth <= 0 or b.depth is None or b.depth_sigma is None:
        return None
    target = torch.where(b.depth_sigma > 0, b.depth, torch.zeros_like(b.depth))
    if x.cfg.image_depth_loss not in ("ds", "margin"):
        raise InputError("--losses.image-depth-loss", f"unknown loss {x.cfg.image_depth_loss!r} (ds or margin)")
    if x.cfg.image_depth_loss == "margin":
        margin = torch.clamp_min(2.0 * b.depth_sigma, x.cfg.depth_margin)
        value = depth_loss(x.outputs.weights, x.outputs.t_mid, target, margin)
    else:
        value = ds_depth_loss(x.outputs.weights, x.outputs.t_mid, x.outputs.deltas, target, b.depth_sigma)
    return x.cfg.image_depth * value


@loss_term("distortion")
def _distortion(x: LossInputs) -> Tensor | None:
    if x.cfg.distortion <= 0:
        return None
    return x.cfg.distortion * distortion_loss(x.outputs.weights, x.outputs.s_edges)


@loss_term("planarity")
def _planarity(x: LossInputs) -> Tensor | None:
    b = x.batch
    if x.cfg.planarity <= 0 or b.n_patch_rays <= 0 or b.cos is None:
        return None
    n, ps = b.n_patch_rays, b.patch_size
    z = x.outputs.depth[:n] * b.cos[:n]
    inv = (1.0 / z.clamp_min(1e-3)).view(-1, ps, ps)
    stuff = ((b.semantic[:n] > 0) & (b.instance[:n] == 0)).view(-1, ps, ps)
    return x.cfg.planarity * planar_segment_loss(inv, b.segment[:n].view(-1, ps, ps), stuff)
