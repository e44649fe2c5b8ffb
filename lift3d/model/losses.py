"""Every loss of the paper as a pure function.

``L = L_color + 1.2 ΣL_distill + 0.1 L_sem + 0.1 L_ins + 0.12 L_seg + 0.2 L_feat + 0.001 (L_tv + L_disp)``;
the weights and which terms a training step uses are :mod:`lift3d.model.loss_terms`.

Label tensors use *channel* space: semantic target ``k ≥ 1`` is a channel of the semantic head (0 = void,
never a target; ``-1`` = ignore), instance ids are per-image compact 2D ids (0 = not a thing pixel).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from lift3d.model.assignment import linear_assign_instances


def charbonnier_loss(pred: Tensor, target: Tensor, eps: float = 1e-4) -> Tensor:
    """``mean(sqrt((C − Ĉ)² + ε²))``; ``pred``, ``target``: ``[R, 3]``.

    Examples
    --------
    >>> import torch
    >>> round(charbonnier_loss(torch.zeros(1, 3), torch.full((1, 3), 0.5)).item(), 6)
    0.5
    """
    return torch.sqrt((pred - target) ** 2 + eps * eps).mean()


def weighted_cross_entropy(logits: Tensor, target: Tensor, weight: Tensor | None = None) -> Tensor:
    """``−1/|P| Σ_p λ_p log softmax(logits_p)[target_p]`` over rays with ``target ≥ 0``.

    Parameters
    ----------
    logits : Tensor
        ``[R, C]`` composited logits.
    target : Tensor
        ``[R]`` int64 channel index; ``< 0`` = ignored.
    weight : Tensor, optional
        ``[R]`` confidence λ_p in ``[0, 1]``.

    Returns
    -------
    Tensor
        Scalar (0 when no ray has a target).
    """
    valid = target >= 0
    if not bool(valid.any()):
        return logits.sum() * 0.0
    logp = F.log_softmax(logits[valid], dim=-1)
    nll = -logp.gather(1, target[valid, None]).squeeze(1)
    if weight is not None:
        nll = nll * weight[valid]
    return nll.mean()


def semantic_loss(sem_logits: Tensor, sem_target: Tensor, confidence: Tensor | None) -> Tensor:
    """L_sem: void (channel 0) pixels are ignored. ``sem_target`` ``[R]`` channel ids (0 = void)."""
    target = torch.where(sem_target > 0, sem_target, torch.full_like(sem_target, -1))
    return weighted_cross_entropy(sem_logits, target, confidence)


def instance_loss(inst_logits: Tensor, inst_ids: Tensor, image_ids: Tensor, confidence: Tensor | None) -> Tensor:
    """L_ins: per image, match its 2D instance ids to instance channels (Hungarian, cost = −mean predicted
    probability), then cross-entropy to the matched channel. Only thing pixels (``inst_ids > 0``) enter.

    Parameters
    ----------
    inst_logits : Tensor
        ``[R, V]`` composited instance logits.
    inst_ids : Tensor
        ``[R]`` per-image 2D instance ids (0 = stuff/void/none).
    image_ids : Tensor
        ``[R]`` which image each ray comes from.
    confidence : Tensor, optional
        ``[R]`` λ_p.
    """
    things = inst_ids > 0
    if not bool(things.any()):
        return inst_logits.sum() * 0.0
    logits = inst_logits[things]
    probs = torch.softmax(logits.detach(), dim=-1)
    target = linear_assign_instances(probs, inst_ids[things], image_ids[things])
    return weighted_cross_entropy(logits, target, confidence[things] if confidence is not None else None)


def segment_groups(image_ids: Tensor, segment_ids: Tensor, min_rays: int) -> Tensor:
    """Group id per ray for rays that share (image, 2D segment) with at least ``min_rays`` others in the batch;
    ``-1`` for void and for too-small groups. ``[R]`` → ``[R]`` int64 (groups numbered 0..G-1)."""
    key = image_ids.long() * 65536 + segment_ids.long()
    _, inv, counts = torch.unique(key, return_inverse=True, return_counts=True)
    ok = (segment_ids > 0) & (counts[inv] >= min_rays)
    # Renumber the surviving groups densely.
    kept = torch.zeros_like(counts, dtype=torch.bool)
    kept[inv[ok]] = True
    new_id = torch.cumsum(kept.long(), 0) - 1
    return torch.where(ok, new_id[inv], torch.full_like(inv, -1))


def segment_consistency_loss(sem_logits: Tensor, groups: Tensor, confidence: Tensor | None) -> Tensor:
    """L_seg: in every ray group sharing one 2D segment, the dominant predicted class (argmax of the summed
    predicted probabilities) becomes a one-hot target ũ for every ray of the group.

    ``sem_logits`` ``[R, U]``, ``groups`` ``[R]`` from :func:`segment_groups`.
    """
    valid = groups >= 0
    if not bool(valid.any()):
        return sem_logits.sum() * 0.0
    g = groups[valid]
    logits = sem_logits[valid].detach()
    probs = torch.softmax(logits, dim=-1)
    probs[:, 0] = 0.0  # void is never a target
    # A ray whose void logit leads by more than ~104 has every other probability underflow to 0 in float32;
    # it then votes with the distribution over the non-void classes alone (identical argmax, never all-zero).
    dead = probs.sum(-1) <= 0
    if bool(dead.any()):
        probs[dead, 1:] = torch.softmax(logits[dead, 1:], dim=-1)
    n_groups = int(g.max()) + 1
    summed = torch.zeros(n_groups, probs.shape[1], dtype=probs.dtype, device=probs.device).index_add_(0, g, probs)
    dominant = summed.argmax(-1)
    target = torch.full_like(groups, -1)
    target[valid] = dominant[g]
    return weighted_cross_entropy(sem_logits, target, confidence)


def disparity_loss(weights: Tensor, t_mid: Tensor) -> Tensor:
    """L_disp = ``1/|P| Σ_p Σ_i w_i / t_i`` (discourages floaters near the cameras).
    ``weights``, ``t_mid``: ``[R, S]``."""
    return (weights / t_mid.clamp_min(1e-3)).sum(-1).mean()


def distortion_loss(weights: Tensor, s_edges: Tensor) -> Tensor:
    """L_dist = mean over rays of ``Σ_i Σ_j w_i w_j |m_i − m_j| + 1/3 Σ_i w_i² (s_{i+1} − s_i)``
    (mip-NeRF 360, eq. 15), computed in O(S) with cumulative sums.

    ``weights``: ``[R, S]``; ``s_edges``: ``[R, S+1]`` sample edges in the normalised ray coordinate
    ``s ∈ [0, 1]``; ``m_i`` are interval midpoints. Reference: :func:`distortion_loss_reference`.
    """
    mids = 0.5 * (s_edges[:, 1:] + s_edges[:, :-1])
    widths = s_edges[:, 1:] - s_edges[:, :-1]
    # Σ_{i,j} w_i w_j |m_i − m_j| = 2 Σ_i w_i (m_i Σ_{j<i} w_j − Σ_{j<i} w_j m_j) for sorted m.
    w_before = torch.cumsum(weights, -1) - weights
    wm_before = torch.cumsum(weights * mids, -1) - weights * mids
    pairwise = 2.0 * (weights * (mids * w_before - wm_before)).sum(-1)
    own = (weights.square() * widths).sum(-1) / 3.0
    return (pairwise + own).mean()


def distortion_loss_reference(weights: Tensor, s_edges: Tensor) -> Tensor:
    """Plain double sum of :func:`distortion_loss` (tests only)."""
    mids = 0.5 * (s_edges[:, 1:] + s_edges[:, :-1])
    widths = s_edges[:, 1:] - s_edges[:, :-1]
    pairwise = (weights[:, :, None] * weights[:, None, :] * (mids[:, :, None] - mids[:, None, :]).abs()).sum((1, 2))
    return (pairwise + (weights ** 2 * widths).sum(-1) / 3.0).mean()


def depth_loss(weights: Tensor, t_mid: Tensor, target: Tensor, margin: float | Tensor) -> Tensor:
    """L_depth = mean over rays with a measured depth ``d`` of ``|Σ_i w_i t_i − d| + (1 − Σ_{|t_i − d| ≤ m} w_i)``.

    The first term is the usual expected-depth L1 (as in depth-supervised NeRFs); the second, a
    line-of-sight term in the spirit of Urban Radiance Fields, asks the ray to *end* in the band around the
    surface: it puts a price on any weight away from the surface (so a fog whose mean happens to sit at
    ``d`` is not a solution) and on the transmittance left after the band. Without the latter a ray whose
    weight sits in a fog in front of the wall (not yet opaque, the rest falling through to the background)
    pays only for the fog's weight, and the colour loss, which wants the ray opaque, adds density wherever
    the ray already has some - in front of the wall; with it, the cheapest way to opacity is density at ``d``.

    ``weights``, ``t_mid``: ``[R, S]``; ``target``: ``[R]`` distance along the ray (0 = unknown, ignored);
    ``margin``: a number, or ``[R]`` per ray (e.g. from each measurement's standard deviation).

    Examples
    --------
    >>> w = torch.tensor([[0.5, 0.5, 0.0], [0.0, 0.6, 0.0]]); t = torch.tensor([[1.0, 2.0, 3.0]] * 2)
    >>> round(float(depth_loss(w, t, torch.tensor([2.0, 2.0]), 0.1)), 4)  # (|1.5-2| + 0.5 + |1.2-2| + 0.4) / 2
    1.1
    """
    known = target > 0
    if not bool(known.any()):
        return weights.sum() * 0.0
    w, t, d = weights[known], t_mid[known], target[known][:, None]
    m = margin[known][:, None] if isinstance(margin, Tensor) else margin
    expected = (w * t).sum(-1)
    in_band = (w * ((t - d).abs() <= m)).sum(-1)
    return ((expected - d[:, 0]).abs() + (1.0 - in_band)).mean()


def ds_depth_loss(weights: Tensor, t_mid: Tensor, deltas: Tensor, target: Tensor, sigma: Tensor,
                  eps: float = 1e-3) -> Tensor:
    """DS-NeRF's depth loss (Deng et al., CVPR 2022): the cross-entropy ``−Σ_i g_i log((w_i + ε) / (1 + ε))`` between the
    ray's termination weights and the measurement's Gaussian ``g_i = N(t_i; d, σ²) Δt_i``, averaged over the
    rays with a measured depth.

    It is smallest when the weights follow ``g`` (it is then the entropy of ``g``, 0 when one interval holds
    it all). Since ``Σ_i w_i ≤ 1``, raising the weight inside ``d ± 2σ`` lowers it everywhere else: fog in
    front of the point and a second surface behind it both cost. ``ε`` caps what one ray can cost (a wrong match
    whose depth the views contradict adds at most ``−log ε`` ≈ 6.9) — docs/sfm.md measures a few percent of
    such matches. ``g`` needs samples within ``σ`` of ``d``: the renderer's depth-guided samples provide them.

    Parameters
    ----------
    weights, t_mid, deltas : Tensor
        ``[R, S]`` rendering weights, interval midpoints and lengths.
    target : Tensor
        ``[R]`` distance along the ray (0 = unknown, ignored).
    sigma : Tensor
        ``[R]`` its standard deviation (> 0 where ``target`` is known).

    Examples
    --------
    All weight in the interval at the measured depth (σ much smaller than the interval) costs nothing:

    >>> import torch
    >>> t = torch.linspace(0.05, 1.95, 20)[None]
    >>> w = torch.zeros(1, 20); w[0, 10] = 1.0
    >>> dt = torch.full((1, 20), 0.1)
    >>> round(float(ds_depth_loss(w, t, dt, t[:, 10], torch.tensor([0.02]))), 3)
    0.0
    """
    known = target > 0
    if not bool(known.any()):
        return weights.sum() * 0.0
    w, t, dt = weights[known], t_mid[known], deltas[known]
    d, s = target[known][:, None], sigma[known][:, None].clamp_min(1e-6)
    g = torch.exp(-0.5 * ((t - d) / s).square()) * dt / (s * math.sqrt(2.0 * math.pi))
    # The discrete Gaussian of a ray sums to ~1 when samples cover d ± 2σ finely; normalising it keeps the
    # loss scale independent of how finely they do.
    g = g / g.sum(-1, keepdim=True).clamp_min(1e-6)
    return -(g * torch.log((w + eps) / (1.0 + eps))).sum(-1).mean()


def planar_segment_loss(inv_depth: Tensor, segment: Tensor, valid: Tensor) -> Tensor:
    """Second differences of rendered inverse depth inside 2D segments: mean ``|q_{i-1} − 2 q_i + q_{i+1}|``
    over every row and column triple of a patch whose three pixels are valid and share one segment.

    The inverse z-depth of a plane is affine in the pixel coordinates, so its second differences vanish:
    walls, floors and ceilings seen through one stuff segment are pulled towards planes. The L1 penalty lets a
    segment hold a few creases (two walls meeting in a corner).

    Parameters
    ----------
    inv_depth : Tensor
        ``[P, s, s]`` inverse z-depth of ``P`` square patches.
    segment : Tensor
        ``[P, s, s]`` int segment ids (compared for equality only).
    valid : Tensor
        ``[P, s, s]`` bool: pixels the prior applies to (e.g. stuff classes).

    Examples
    --------
    >>> import torch
    >>> u, v = torch.meshgrid(torch.arange(4.0), torch.arange(4.0), indexing="ij")
    >>> plane = (0.3 + 0.02 * u - 0.01 * v)[None]
    >>> seg, ok = torch.ones(1, 4, 4), torch.ones(1, 4, 4, dtype=torch.bool)
    >>> float(planar_segment_loss(plane, seg, ok)) < 1e-6
    True
    """
    terms = []
    for dim in (1, 2):
        n = inv_depth.shape[dim]
        a, b, c = (inv_depth.narrow(dim, k, n - 2) for k in range(3))
        sa, sb, sc = (segment.narrow(dim, k, n - 2) for k in range(3))
        va, vb, vc = (valid.narrow(dim, k, n - 2) for k in range(3))
        ok = va & vb & vc & (sa == sb) & (sb == sc)
        terms.append(((a - 2 * b + c).abs() * ok, ok))
    num = sum(t.sum() for t, _ in terms)
    den = sum(ok.sum() for _, ok in terms)
    return num / den.clamp_min(1)


def feature_loss(features_pred: list[Tensor], features_obs: list[Tensor]) -> Tensor:
    """L_feat = mean over feature locations of ``‖F(C_P) − F(Ĉ_P)‖₂``, averaged over the extractor's layers.
    Each list holds ``[P, C, h, w]`` maps."""
    terms = [torch.sqrt(((a - b) ** 2).sum(1) + 1e-12).mean() for a, b in zip(features_pred, features_obs)]
    return torch.stack(terms).mean()


def finite_or_none(x: Tensor) -> float | None:
    v = float(x.detach())
    return v if np.isfinite(v) else None
