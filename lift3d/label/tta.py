"""Test-time augmentation (TTA) for mask-classification segmenters, and how its passes are combined.

A *pass* runs the segmenter once on an augmented image (horizontally flipped and/or at another inference
resolution) and is mapped back onto the original pixel grid as a :class:`PassMaps`: the kept queries
(their class probabilities, class and score) and, per pixel, the query that wins the pixel (the argmax of
score × mask probability, as Mask2Former's panoptic inference assigns pixels) with its mask probability.

Panoptic Lifting's preprocessing consumes, per frame, a class-probability map and a confidence map built
from such passes; here they are defined as

* class probabilities ``P̄(x) = mean_a P_a(x)``, where ``P_a(x)`` is the class distribution of the query
  that wins ``x`` in pass ``a`` (void first: ``P[0]`` is "no object" plus every unmapped class; a pixel no
  query wins is void with probability 1);
* confidence ``C̄(x) = mean_a score_a(x) · m_a(x)`` (the winning query's class score times its mask
  probability, Panoptic Lifting's ``confidence``).

The written labels take the segments of the un-augmented pass (instance grouping needs one partition, and
averaging partitions is not defined) and let the passes vote on everything else (:func:`relabel_segments`,
:func:`pixel_confidence`):

* each segment's class is ``argmax_k Σ_{x ∈ segment} P̄(x)[k]`` over real classes (void excluded), and its
  score is the mean of ``P̄(x)[class]`` over the segment; stuff segments that end up with the same class
  are fused (one segment per stuff class and frame);
* the per-pixel confidence (which :class:`~lift3d.data.scene.Scene` multiplies by the segment score) is
  ``c(x) = mean_a m_a(x) · [class_a(x) = class(x)]``: the mask probability, counted only in the passes that
  agree with the pixel's final class.

With a single pass these reduce to the segmenter's own output: the query's class, its score, and its mask
probability as pixel confidence (so score × confidence is Panoptic Lifting's no-TTA confidence).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np
import torch
from torch import Tensor


@dataclass(frozen=True)
class Augmentation:
    """One TTA pass: inference resolution ``scale`` (× the model's own) and an optional horizontal flip."""

    scale: float = 1.0
    flip: bool = False

    @property
    def is_identity(self) -> bool:
        return self.scale == 1.0 and not self.flip

    def __str__(self) -> str:
        return f"x{self.scale:g}" + (" flip" if self.flip else "")


def augmentations(scales: Sequence[float] = (1.0,), flip: bool = False) -> list[Augmentation]:
    """Every (scale, flip) combination, the identity pass first (its segments become the labels).

    Examples
    --------
    >>> [str(a) for a in augmentations((0.75, 1.0), flip=True)]
    ['x1', 'x1 flip', 'x0.75', 'x0.75 flip']
    """
    if any(not np.isfinite(s) or s <= 0 for s in scales):
        raise ValueError(f"TTA scales must be positive (got {list(scales)})")
    ordered = [1.0] + [float(s) for s in scales if float(s) != 1.0]
    out: list[Augmentation] = []
    for s in dict.fromkeys(ordered):
        out.append(Augmentation(s, False))
        if flip:
            out.append(Augmentation(s, True))
    return out


def flip_image(image: np.ndarray) -> np.ndarray:
    """Mirror ``[H, W, ...]`` left-right (a contiguous copy, as image processors expect)."""
    return np.ascontiguousarray(image[:, ::-1])


@dataclass
class PassMaps:
    """One pass, on the original image's pixel grid.

    Attributes
    ----------
    query_probs : Tensor
        ``float [N, C]`` class distribution of each kept query; column 0 is void ("no object" plus the
        unmapped classes), column ``k ≥ 1`` is class ``k``. Rows sum to 1.
    query_class : Tensor
        ``long [N]`` each query's predicted class (0 when its best class is an unmapped one).
    query_score : Tensor
        ``float [N]`` each query's class probability (its segment score).
    winner : Tensor
        ``long [H, W]`` index of the query that wins each pixel, -1 where none does.
    mask_prob : Tensor
        ``float [H, W]`` the winning query's mask probability (0 where none wins).
    """

    query_probs: Tensor
    query_class: Tensor
    query_score: Tensor
    winner: Tensor
    mask_prob: Tensor

    @property
    def num_classes(self) -> int:
        """``C``: void plus the real classes."""
        return int(self.query_probs.shape[1])

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.winner.shape)  # type: ignore[return-value]

    def flip(self) -> "PassMaps":
        """The same pass mirrored left-right (undoes the flip of a flipped input)."""
        return replace(self, winner=self.winner.flip(-1), mask_prob=self.mask_prob.flip(-1))

    def probabilities(self) -> Tensor:
        """``float [C, H, W]`` per-pixel class distribution ``P_a(x)`` (void one-hot where no query wins)."""
        c = self.num_classes
        table = torch.cat([torch.eye(c, dtype=self.query_probs.dtype, device=self.query_probs.device)[:1],
                           self.query_probs], 0)  # row 0 = "no query": void with probability 1
        return table[self.winner + 1].permute(2, 0, 1)

    def classes(self) -> Tensor:
        """``long [H, W]`` the winning query's class (0 where none wins)."""
        table = torch.cat([self.query_class.new_zeros(1), self.query_class])
        return table[self.winner + 1]

    def confidence(self) -> Tensor:
        """``float [H, W]`` score × mask probability of the winning query (0 where none wins)."""
        table = torch.cat([self.query_score.new_zeros(1), self.query_score])
        return table[self.winner + 1] * self.mask_prob


def run_tta(images: Sequence[np.ndarray], predict: Callable[[list[np.ndarray], Augmentation], list[PassMaps]],
            augs: Sequence[Augmentation]) -> list[list[PassMaps]]:
    """Run every pass on a batch of images and map the results back onto the original images.

    Parameters
    ----------
    images : sequence of np.ndarray
        ``uint8 [H, W, 3]`` RGB images.
    predict : callable
        ``predict(images, aug)`` returns one :class:`PassMaps` per image on the grid of the images it was
        given (already flipped when ``aug.flip``); it applies ``aug.scale`` itself (a segmenter resizes
        internally, so the scale is an inference resolution, not a resampling of the image).
    augs : sequence of Augmentation
        The passes (:func:`augmentations`).

    Returns
    -------
    list of list of PassMaps
        ``out[i][a]``: image ``i``, pass ``a``, on image ``i``'s own grid.
    """
    out: list[list[PassMaps]] = [[] for _ in images]
    for aug in augs:
        batch = [flip_image(im) for im in images] if aug.flip else list(images)
        maps = predict(batch, aug)
        for i, m in enumerate(maps):
            out[i].append(m.flip() if aug.flip else m)
    return out


def mean_probabilities(passes: Sequence[PassMaps]) -> Tensor:
    """``P̄``: ``float [C, H, W]`` class probabilities averaged over the passes."""
    total = passes[0].probabilities().clone()
    for p in passes[1:]:
        total += p.probabilities()
    return total / len(passes)


def mean_confidence(passes: Sequence[PassMaps]) -> Tensor:
    """``C̄``: ``float [H, W]`` score × mask probability averaged over the passes."""
    return torch.stack([p.confidence() for p in passes]).mean(0)


def segment_class_mass(passes: Sequence[PassMaps], segment_index: Tensor, n_segments: int) -> Tensor:
    """``Σ_{x ∈ segment} P̄(x)`` for every segment, without building ``P̄`` (``C`` maps of ``H × W``).

    Parameters
    ----------
    passes : sequence of PassMaps
    segment_index : Tensor
        ``long [H, W]`` segment number ``0..n_segments-1`` per pixel, -1 for pixels to ignore.
    n_segments : int

    Returns
    -------
    Tensor
        ``float [n_segments, C]``.
    """
    c = passes[0].num_classes
    dtype = passes[0].query_probs.dtype
    mass = torch.zeros(n_segments, c, dtype=dtype, device=segment_index.device)
    seg = segment_index.reshape(-1)
    valid = seg >= 0
    for p in passes:
        n = p.query_probs.shape[0]
        # Count pixels per (segment, winning query); column 0 is "no query wins" (void with probability 1).
        win = p.winner.reshape(-1)[valid] + 1
        counts = torch.bincount(seg[valid] * (n + 1) + win, minlength=n_segments * (n + 1))
        counts = counts.reshape(n_segments, n + 1).to(dtype)
        table = torch.cat([torch.eye(c, dtype=dtype, device=mass.device)[:1], p.query_probs.to(mass.device)], 0)
        mass += counts @ table
    return mass / len(passes)


@dataclass
class LabelledSegment:
    """A segment after the passes voted: its id in the segment map, class (≥ 1) and score in [0, 1]."""

    id: int
    cls: int
    score: float


def relabel_segments(segment_map: Tensor, segment_classes: dict[int, int], passes: Sequence[PassMaps],
                     stuff_classes: set[int]) -> tuple[Tensor, list[LabelledSegment]]:
    """Class and score of each segment from the passes' averaged probabilities; fuse stuff per class.

    Parameters
    ----------
    segment_map : Tensor
        ``long [H, W]`` segment ids of the identity pass, 0 = void.
    segment_classes : dict
        Segment id → class the identity pass gave it (used to break exact ties only).
    passes : sequence of PassMaps
    stuff_classes : set of int
        Classes that are stuff: their segments are fused into one per class.

    Returns
    -------
    (Tensor, list of LabelledSegment)
        The segment map after fusion (a fused stuff segment keeps its lowest id) and the segments in
        increasing id order.
    """
    ids = sorted(segment_classes)
    if not ids:
        return segment_map.clone(), []
    id_tensor = torch.as_tensor(ids, dtype=segment_map.dtype, device=segment_map.device)
    pos = torch.searchsorted(id_tensor, segment_map.clamp_min(0))
    pos = pos.clamp_max(len(ids) - 1)
    index = torch.where((segment_map > 0) & (id_tensor[pos] == segment_map), pos, torch.full_like(pos, -1))
    mass = segment_class_mass(passes, index, len(ids))
    area = torch.bincount(index[index >= 0], minlength=len(ids)).to(mass.dtype)

    real = mass[:, 1:].clone()
    # Prefer the identity pass's class on an exact tie, so a single pass never changes a segment's class.
    for k, sid in enumerate(ids):
        if segment_classes[sid] >= 1:
            real[k, segment_classes[sid] - 1] += 1e-6 * float(area[k].clamp_min(1))
    cls = (real.argmax(1) + 1).tolist()

    out_map = segment_map.clone()
    fused_into: dict[int, int] = {}  # stuff class -> position of the segment that keeps its id
    members: dict[int, list[int]] = {}
    for k, sid in enumerate(ids):
        if area[k] == 0:
            continue  # listed but covers no pixel: drop it
        c = cls[k]
        if c in stuff_classes and c in fused_into:
            keep = fused_into[c]
            out_map[segment_map == sid] = ids[keep]
            members[keep].append(k)
        else:
            if c in stuff_classes:
                fused_into[c] = k
            members[k] = [k]
    segments = []
    for keep, group in sorted(members.items()):
        c = cls[keep]
        grp = torch.as_tensor(group)
        score = float(mass[grp, c].sum() / area[grp].sum())
        segments.append(LabelledSegment(ids[keep], c, min(max(score, 0.0), 1.0)))
    return out_map, segments


def pixel_confidence(passes: Sequence[PassMaps], classes: Tensor) -> Tensor:
    """``c(x) = mean_a m_a(x) · [class_a(x) = classes(x)]``: ``float [H, W]`` in [0, 1] (0 on void).

    Parameters
    ----------
    passes : sequence of PassMaps
    classes : Tensor
        ``long [H, W]`` each pixel's final class, 0 = void.
    """
    total = torch.zeros(classes.shape, dtype=passes[0].mask_prob.dtype, device=classes.device)
    for p in passes:
        total += p.mask_prob * (p.classes() == classes)
    return torch.where(classes > 0, total / len(passes), torch.zeros_like(total)).clamp(0.0, 1.0)
