"""Per-image linear assignment of arbitrary 2D instance ids to the field's instance channels.

A 2D segmenter numbers the instances of every frame on its own; the field has ``V`` instance channels that
must mean the same object in every view. Panoptic Lifting (and the paper) solve, per image, the linear
assignment problem with cost ``C[l, k] = −mean_{p ∈ l} P_k(p)`` (the mean predicted probability of channel
``k`` over the pixels of 2D instance ``l``), with ``scipy.optimize.linear_sum_assignment``.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment
from torch import Tensor


def instance_cost_matrix(probs: Tensor, ids: Tensor) -> tuple[Tensor, Tensor]:
    """Cost matrix of one image.

    Parameters
    ----------
    probs : Tensor
        ``[n, V]`` predicted instance probabilities of the image's thing pixels.
    ids : Tensor
        ``[n]`` 2D instance ids (any positive integers).

    Returns
    -------
    cost : Tensor
        ``[K, V]`` ``−mean`` probability per (2D id, channel).
    unique_ids : Tensor
        ``[K]`` the 2D ids, in the row order of ``cost``.
    """
    unique_ids, inv = torch.unique(ids, return_inverse=True)
    sums = torch.zeros(len(unique_ids), probs.shape[1], dtype=probs.dtype, device=probs.device)
    sums.index_add_(0, inv, probs)
    counts = torch.bincount(inv, minlength=len(unique_ids)).to(probs.dtype)
    return -(sums / counts[:, None]), unique_ids


def linear_assign_instances(probs: Tensor, ids: Tensor, image_ids: Tensor | None = None) -> Tensor:
    """Target instance channel for every pixel, by per-image Hungarian matching.

    Parameters
    ----------
    probs : Tensor
        ``[n, V]`` predicted probabilities (constants: no gradient flows through the matching).
    ids : Tensor
        ``[n]`` 2D instance ids (> 0), meaningful only within one image.
    image_ids : Tensor, optional
        ``[n]`` image of every pixel (default: all one image).

    Returns
    -------
    Tensor
        ``[n]`` int64 channel per pixel; ``-1`` where the image has more 2D instances than channels and
        this one was left unmatched.

    Examples
    --------
    >>> import torch
    >>> probs = torch.tensor([[0.1, 0.9], [0.2, 0.8], [0.7, 0.3]])
    >>> linear_assign_instances(probs, torch.tensor([5, 5, 9])).tolist()
    [1, 1, 0]
    """
    probs = probs.detach()
    if image_ids is None:
        image_ids = torch.zeros_like(ids)
    if ids.numel() == 0:
        return torch.full(ids.shape, -1, dtype=torch.long, device=ids.device)
    # Every image's cost matrix at once: rows are (image, 2D id) pairs, sorted by image, then id.
    span = int(ids.max()) + 1
    keys, inv = torch.unique(image_ids.long() * span + ids.long(), return_inverse=True)
    cost, _ = instance_cost_matrix(probs, inv)
    # A diverging field can produce NaN probabilities; the trainer skips such steps, the matching
    # must not crash before it gets the chance.
    cost = torch.nan_to_num(cost.double(), nan=0.0, posinf=0.0, neginf=-1.0).cpu().numpy()
    image_of_row = (keys // span).cpu().numpy()
    starts = np.flatnonzero(np.r_[True, image_of_row[1:] != image_of_row[:-1]])
    lut = np.full(len(keys), -1, dtype=np.int64)
    for a, b in zip(starts, np.r_[starts[1:], len(keys)]):
        rows, cols = linear_sum_assignment(cost[a:b])
        lut[a + rows] = cols
    return torch.from_numpy(lut).to(ids.device)[inv]
