"""Render whole frames of a trained model into numpy images (rgb, depth, panoptic labels)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from lift3d.render.rays import RayGenerator


@dataclass
class FrameRender:
    """One rendered frame. ``semantic`` holds category ids, ``instance`` ids ``1..V`` on things, 0 on stuff."""

    rgb: np.ndarray  # [H, W, 3] float32 in [0, 1]
    depth: np.ndarray  # [H, W] float32 z-depth in world units (distance along the optical axis)
    opacity: np.ndarray  # [H, W] float32
    semantic: np.ndarray | None  # [H, W] int64 category ids
    instance: np.ndarray | None  # [H, W] int64
    confidence: np.ndarray | None  # [H, W] float32 probability of the chosen class


def render_frame(model, rays: RayGenerator, i: int, world_scale: float, *, downscale: int = 1,
                 with_labels: bool = True, chunk_size: int | None = None, progress: bool = False) -> FrameRender:
    """Render frame ``i`` of ``rays``.

    Parameters
    ----------
    model : PanopticModel
    rays : RayGenerator
        Cameras in normalised coordinates.
    i : int
        Frame index into ``rays``.
    world_scale : float
        Normalisation scale (normalised units per world unit) to report depth in world units.
    downscale : int
        Render every ``downscale``-th pixel block (faster previews).
    """
    was_training = model.training
    model.eval()
    o, d, cos, (h, w) = rays.image_rays(i, downscale)
    out = model.render_chunked(o, d, with_labels=with_labels, chunk_size=chunk_size, progress=progress)
    if was_training:
        model.train()
    opacity = out["opacity"]
    # Distance to what the ray sees (normalised by opacity), projected on the optical axis, in world units.
    depth = out["depth"] / opacity.clamp_min(1e-6) * cos / world_scale
    sem = inst = conf = None
    if with_labels and "semantic" in out:
        c, k, p = model.panoptic_from_probs(out["semantic"], out.get("instance"))
        sem, inst, conf = (x.view(h, w).cpu().numpy() for x in (c, k, p))
        conf = conf.astype(np.float32)
    return FrameRender(
        rgb=out["rgb"].clamp(0, 1).view(h, w, 3).cpu().numpy().astype(np.float32),
        depth=torch.where(opacity > 1e-4, depth, torch.zeros_like(depth)).view(h, w).cpu().numpy().astype(np.float32),
        opacity=opacity.view(h, w).cpu().numpy().astype(np.float32),
        semantic=sem, instance=inst, confidence=conf,
    )
