"""Render whole frames of a trained model into numpy images (rgb, depth, panoptic labels)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy import ndimage

from lift3d.errors import InputError
from lift3d.render.rays import RayGenerator

#: Thing segments (category, instance) covering less than this fraction of a rendered frame take the labels of
#: the pixels around them (:func:`merge_small_segments`): 16 pixels of a 128 × 128 frame. Chosen on the
#: tuning runs (rooms 5 and 6, `fast`, with and without depth maps), see docs/notes/2026-11-29-benchmark-history.md,
#: "Small thing segments in renders".
MIN_SEGMENT_FRACTION = 0.001


def check_min_segment_fraction(value: float) -> float:
    """``value`` if it is a valid ``--min-segment-fraction`` (in [0, 1)), else a one-line :class:`InputError`."""
    if not 0.0 <= value < 1.0:
        raise InputError("--min-segment-fraction", f"must be in [0, 1), got {value}")
    return value


def surface_depth(depth: np.ndarray, median_depth: np.ndarray | None) -> np.ndarray:
    """The z-depth of the surface each pixel sees: the median depth (where the opacity reaches 0.5) where the
    ray reaches it, else the expected depth; the expected depth everywhere when ``median_depth`` is None.

    The export's isosurface lies at the median depth, so pixels lifted by it land on the exported points; the
    expected depth ``Σ w_i t_i`` follows faint density behind the surface (an unbounded scene's background fog).

    Examples
    --------
    >>> surface_depth(np.array([[4.0, 2.0]]), np.array([[3.0, 0.0]])).tolist()
    [[3.0, 2.0]]
    """
    if median_depth is None:
        return depth
    return np.where(median_depth > 0, median_depth, depth)


@dataclass
class FrameRender:
    """One rendered frame. ``semantic`` holds category ids, ``instance`` ids ``1..V`` on things, 0 on stuff."""

    rgb: np.ndarray  # [H, W, 3] float32 in [0, 1]
    depth: np.ndarray  # [H, W] float32 z-depth in world units (distance along the optical axis)
    opacity: np.ndarray  # [H, W] float32
    semantic: np.ndarray | None  # [H, W] int64 category ids
    instance: np.ndarray | None  # [H, W] int64
    confidence: np.ndarray | None  # [H, W] float32 probability of the chosen class
    #: [H, W] float32 z-depth where the ray's opacity reaches 0.5 (the median depth: where the export's
    #: isosurface lies), world units; 0 where it never does. None when not rendered (frames without labels).
    median_depth: np.ndarray | None = None

    @property
    def surface_depth(self) -> np.ndarray:
        """``[H, W]`` z-depth of the surface each pixel sees (:func:`surface_depth`)."""
        return surface_depth(self.depth, self.median_depth)


def merge_small_segments(semantic: np.ndarray, instance: np.ndarray,
                         min_pixels: float) -> tuple[np.ndarray, np.ndarray]:
    """Relabel the thing segments of one frame that cover fewer than ``min_pixels`` pixels.

    A thing segment is every pixel of the frame with one (category, instance id), instance > 0. Where the
    argmax of the semantic or instance channels flips near a boundary, the render holds segments of a few
    pixels whose (category, instance) pair belongs to no object: each counts as a false positive in PQ and
    shows as speckle in the panoptic image. Their pixels take the labels of the nearest pixel outside every
    such segment (stuff or another thing), as a panoptic post-process drops small segments.

    Parameters
    ----------
    semantic, instance : np.ndarray
        ``[H, W]`` integer category ids and instance ids (0 on stuff).
    min_pixels : float
        Segments with fewer pixels are merged; 0 keeps every segment.

    Returns
    -------
    (np.ndarray, np.ndarray)
        New semantic and instance maps (the inputs are not modified).

    Examples
    --------
    >>> sem = np.array([[1, 1, 1, 1], [1, 3, 3, 1], [1, 3, 4, 1]])
    >>> inst = np.array([[0, 0, 0, 0], [0, 2, 2, 0], [0, 2, 5, 0]])
    >>> s, i = merge_small_segments(sem, inst, 2)  # the one-pixel (4, 5) segment joins its neighbour
    >>> s.tolist(), i.tolist()
    ([[1, 1, 1, 1], [1, 3, 3, 1], [1, 3, 3, 1]], [[0, 0, 0, 0], [0, 2, 2, 0], [0, 2, 2, 0]])
    """
    semantic, instance = np.array(semantic), np.array(instance)
    thing = instance > 0
    if min_pixels <= 0 or not thing.any():
        return semantic, instance
    # One int64 key per (category, instance) pair: a 1-D unique is several times faster than unique rows.
    key = semantic[thing].astype(np.int64) * (int(instance.max()) + 1) + instance[thing]
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    small = np.zeros(semantic.shape, bool)
    small[thing] = counts[inverse.ravel()] < min_pixels
    if not small.any() or small.all():
        return semantic, instance
    # Index of the nearest pixel that is not in a small segment, for every pixel.
    _, (iy, ix) = ndimage.distance_transform_edt(small, return_indices=True)
    semantic[small] = semantic[iy[small], ix[small]]
    instance[small] = instance[iy[small], ix[small]]
    return semantic, instance


def render_frame(model, rays: RayGenerator, i: int, world_scale: float, *, downscale: int = 1,
                 with_labels: bool = True, chunk_size: int | None = None, progress: bool = False,
                 min_segment_fraction: float = MIN_SEGMENT_FRACTION) -> FrameRender:
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
    with_labels : bool
        Also the labels, and the median depth that places labelled pixels in 3D (``median_depth``).
    min_segment_fraction : float
        Thing segments under this fraction of the frame's pixels take their surroundings' labels
        (:func:`merge_small_segments`; 0 keeps the raw argmax labels).
    """
    was_training = model.training
    model.eval()
    o, d, cos, (h, w) = rays.image_rays(i, downscale)
    out = model.render_chunked(o, d, with_labels=with_labels, with_median_depth=with_labels, chunk_size=chunk_size,
                               progress=progress)
    if was_training:
        model.train()
    opacity = out["opacity"]
    # Distance to what the ray sees (normalised by opacity), projected on the optical axis, in world units.
    depth = out["depth"] / opacity.clamp_min(1e-6) * cos / world_scale
    sem = inst = conf = median = None
    if with_labels:
        median = (out["median_depth"] * cos / world_scale).view(h, w).cpu().numpy().astype(np.float32)
    if with_labels and "semantic" in out:
        c, k, p = model.panoptic_from_probs(out["semantic"], out.get("instance"))
        sem, inst, conf = (x.view(h, w).cpu().numpy() for x in (c, k, p))
        conf = conf.astype(np.float32)
        sem, inst = merge_small_segments(sem, inst, min_segment_fraction * h * w)
    return FrameRender(
        rgb=out["rgb"].clamp(0, 1).view(h, w, 3).cpu().numpy().astype(np.float32),
        depth=torch.where(opacity > 1e-4, depth, torch.zeros_like(depth)).view(h, w).cpu().numpy().astype(np.float32),
        opacity=opacity.view(h, w).cpu().numpy().astype(np.float32),
        semantic=sem, instance=inst, confidence=conf,
        median_depth=median,
    )
