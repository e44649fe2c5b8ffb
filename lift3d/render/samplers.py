"""Where along a ray to evaluate the field: near/far, uniform and proposal (PDF) sampling, and the
inter-level distillation loss that trains the proposal grids.

Samples are described by their *edges* in a normalised ray coordinate ``s ∈ [0, 1]``. Bounded scenes use
``s`` linear in distance; unbounded scenes use mip-NeRF 360's piecewise linear/disparity spacing
``g(t) = t/2`` for ``t < 1`` and ``1 - 1/(2t)`` beyond, so that samples are uniform in contracted space.
"""

from __future__ import annotations

import torch
from torch import Tensor


def spacing_fn(t: Tensor, kind: str) -> Tensor:
    """Distance ``t`` → spacing coordinate (``linear``: identity; ``lindisp``: ``g`` above)."""
    if kind == "linear":
        return t
    return torch.where(t < 1.0, 0.5 * t, 1.0 - 0.5 / t.clamp_min(1.0))


def spacing_fn_inv(s: Tensor, kind: str) -> Tensor:
    """Inverse of :func:`spacing_fn`."""
    if kind == "linear":
        return s
    return torch.where(s < 0.5, 2.0 * s, 0.5 / (1.0 - s).clamp_min(1e-7))


def ray_aabb(origins: Tensor, dirs: Tensor, lo: float | Tensor = -1.0, hi: float | Tensor = 1.0) -> tuple[Tensor, Tensor]:
    """Entry and exit distances of rays through the axis-aligned box ``[lo, hi]^3`` (``lo``, ``hi``: floats, or
    ``[3]`` tensors for a box that is not a cube).

    ``origins``, ``dirs``: ``[R, 3]`` → ``t_near``, ``t_far``: ``[R]`` (``t_far <= t_near`` when the ray
    misses the box).
    """
    inv = 1.0 / torch.where(dirs.abs() < 1e-12, torch.full_like(dirs, 1e-12), dirs)
    t0 = (lo - origins) * inv
    t1 = (hi - origins) * inv
    t_near = torch.minimum(t0, t1).amax(-1)
    t_far = torch.maximum(t0, t1).amin(-1)
    return t_near, t_far


def uniform_edges(near: Tensor, far: Tensor, n: int, spacing: str, jitter: bool,
                  generator: torch.Generator | None = None) -> Tensor:
    """``n`` intervals uniform in spacing coordinate between ``near`` and ``far`` (``[R]`` each).

    Returns ``s`` edges ``[R, n+1]`` with a per-interval random shift when ``jitter`` (training).
    """
    s0, s1 = spacing_fn(near, spacing), spacing_fn(far, spacing)
    base = torch.linspace(0.0, 1.0, n + 1, device=near.device, dtype=near.dtype)
    if jitter:
        # Stratified: move the interior edges inside their strata, keep the endpoints.
        noise = torch.rand(near.shape[0], n + 1, device=near.device, dtype=near.dtype, generator=generator)
        base = base + (noise - 0.5) / n
        base[:, 0], base[:, -1] = 0.0, 1.0
        base = base.clamp(0, 1)
    return s0[:, None] + (s1 - s0)[:, None] * base


def sample_pdf(edges: Tensor, weights: Tensor, n: int, jitter: bool, padding: float = 0.01,
               generator: torch.Generator | None = None) -> Tensor:
    """Inverse-CDF resampling of ``n`` intervals where ``weights`` are high.

    Parameters
    ----------
    edges : Tensor
        ``[R, S+1]`` sorted interval edges (spacing coordinate).
    weights : Tensor
        ``[R, S]`` rendering weights of those intervals (treated as constants).
    n : int
        Number of new intervals.
    jitter : bool
        Random stratified positions (training) instead of the deterministic midpoints.
    padding : float
        Added to every weight so empty stretches keep a few samples.

    Returns
    -------
    Tensor
        ``[R, n+1]`` sorted new edges within ``[edges[:, 0], edges[:, -1]]``.
    """
    w = weights.detach() + padding / weights.shape[-1]
    pdf = w / w.sum(-1, keepdim=True)
    cdf = torch.cumsum(pdf, -1).clamp(max=1.0)
    cdf = torch.cat([torch.zeros_like(cdf[:, :1]), cdf], -1)
    cdf[:, -1] = 1.0
    r = edges.shape[0]
    if jitter:
        u = (torch.arange(n + 1, device=edges.device, dtype=edges.dtype)
             + torch.rand(r, n + 1, device=edges.device, dtype=edges.dtype, generator=generator)) / (n + 1)
        u = torch.sort(u, dim=-1).values
    else:
        u = torch.linspace(0.0, 1.0, n + 1, device=edges.device, dtype=edges.dtype).expand(r, n + 1)
    u = u.contiguous()
    idx = torch.searchsorted(cdf.contiguous(), u, right=True)
    below = (idx - 1).clamp(0, cdf.shape[-1] - 1)
    above = idx.clamp(0, cdf.shape[-1] - 1)
    c0, c1 = cdf.gather(-1, below), cdf.gather(-1, above)
    b0, b1 = edges.gather(-1, below), edges.gather(-1, above)
    frac = torch.nan_to_num((u - c0) / (c1 - c0), nan=0.0, posinf=0.0, neginf=0.0).clamp(0.0, 1.0)
    return (b0 + frac * (b1 - b0)).detach()


def outer_bound(edges: Tensor, edges_env: Tensor, weights_env: Tensor) -> Tensor:
    """Sum of the envelope's weights over the envelope intervals that overlap each interval of ``edges``.

    ``edges`` ``[R, S+1]``, ``edges_env`` ``[R, P+1]``, ``weights_env`` ``[R, P]`` → ``[R, S]``.
    """
    cum = torch.cat([torch.zeros_like(weights_env[:, :1]), torch.cumsum(weights_env, -1)], -1)  # [R, P+1]
    p = edges_env.shape[-1] - 1
    lo = (torch.searchsorted(edges_env.contiguous(), edges[:, :-1].contiguous(), right=True) - 1).clamp(0, p)
    hi = torch.searchsorted(edges_env.contiguous(), edges[:, 1:].contiguous(), right=False).clamp(0, p)
    return cum.gather(-1, hi) - cum.gather(-1, lo)


def interlevel_loss(fine_edges: Tensor, fine_weights: Tensor, prop_edges: Tensor, prop_weights: Tensor,
                    eps: float = 1e-7) -> Tensor:
    """mip-NeRF 360's proposal loss (L_distill): the proposal's weights must bound the fine weights.

    ``Σ_i max(0, w_i − bound_i)² / (w_i + eps)``, averaged over rays; ``fine_*`` are treated as constants so
    only the proposal learns from it.
    """
    w = fine_weights.detach()
    bound = outer_bound(fine_edges.detach(), prop_edges.detach(), prop_weights)
    return ((w - bound).clamp_min(0.0) ** 2 / (w + eps)).sum(-1).mean()
