"""Volume rendering as small pure functions (the paper's rendering equations).

For a ray with samples ``i = 1..N`` at distances ``t_i`` and interval lengths ``Δt_i``::

    w_i = exp(-Σ_{j<i} σ_j Δt_j) · (1 - exp(-σ_i Δt_i))
    C = Σ w_i c_i,   U = softmax(Σ w_i u_i),   V = softmax(Σ w_i v_i),   depth = Σ w_i t_i

Numerics: optical depths ``τ = σ Δt`` are accumulated in log space (an exclusive cumulative sum, then one
``exp``), ``1 - exp(-τ)`` uses ``expm1``; non-finite or negative ``τ`` is sanitised, so σ from 0 to 1e6,
``Δt → 0``, rays that hit nothing and far planes at 1e4 all give finite weights with ``Σ w ≤ 1``.
"""

from __future__ import annotations

import torch
from torch import Tensor

# Optical depth beyond which transmittance is exactly 0 in float32 (exp(-104) underflows); clamping keeps
# `inf - inf` out of the cumulative sum.
_TAU_MAX = 1e4


def optical_depth(sigma: Tensor, deltas: Tensor) -> Tensor:
    """``τ = σ Δt`` made safe: NaN → 0, negatives → 0, +inf → a large finite value.

    ``sigma``, ``deltas``: ``[n_rays, n_samples]`` → ``[n_rays, n_samples]``.
    """
    tau = sigma * deltas
    return torch.nan_to_num(tau, nan=0.0, posinf=_TAU_MAX).clamp(0.0, _TAU_MAX)


def render_weights(sigma: Tensor, deltas: Tensor) -> tuple[Tensor, Tensor]:
    """Rendering weights and transmittance.

    Parameters
    ----------
    sigma : Tensor
        ``[n_rays, n_samples]`` densities (≥ 0).
    deltas : Tensor
        ``[n_rays, n_samples]`` interval lengths ``Δt`` (≥ 0).

    Returns
    -------
    weights : Tensor
        ``[n_rays, n_samples]`` ``w_i`` ≥ 0 with ``Σ_i w_i ≤ 1``.
    transmittance : Tensor
        ``[n_rays, n_samples]`` ``T_i = exp(-Σ_{j<i} τ_j)`` (non-increasing along the ray).

    Examples
    --------
    >>> import torch
    >>> w, T = render_weights(torch.tensor([[0.0, 1e6, 5.0]]), torch.tensor([[1.0, 1.0, 1.0]]))
    >>> w.tolist(), T.tolist()
    ([[0.0, 1.0, 0.0]], [[1.0, 1.0, 0.0]])
    """
    tau = optical_depth(sigma, deltas)
    # Exclusive cumulative sum in log space: log T_i = -Σ_{j<i} τ_j.
    cum = torch.cumsum(tau, dim=-1)
    log_t = -torch.cat([torch.zeros_like(cum[..., :1]), cum[..., :-1]], dim=-1)
    transmittance = torch.exp(log_t)
    alpha = -torch.expm1(-tau)  # 1 - exp(-τ), accurate for tiny τ
    return transmittance * alpha, transmittance


def render_weights_reference(sigma: Tensor, deltas: Tensor) -> Tensor:
    """Plain loop version of :func:`render_weights` (float64-friendly; used in tests)."""
    n_rays, n_samples = sigma.shape
    w = torch.zeros_like(sigma)
    for r in range(n_rays):
        trans = torch.ones((), dtype=sigma.dtype)
        for i in range(n_samples):
            a = 1 - torch.exp(-sigma[r, i] * deltas[r, i])
            w[r, i] = trans * a
            trans = trans * (1 - a)
    return w


def composite(weights: Tensor, values: Tensor) -> Tensor:
    """Weighted sum along the ray: ``weights`` ``[R, S]``, ``values`` ``[R, S, C]`` → ``[R, C]`` (a batched
    matrix product, which is much faster on CPU than a broadcast multiply + sum)."""
    return torch.bmm(weights.unsqueeze(1), values).squeeze(1)


def render_depth(weights: Tensor, t_mid: Tensor, normalize: bool = False) -> Tensor:
    """Expected depth ``Σ w_i t_i`` ``[R]``; with ``normalize`` divided by the opacity (depth of the surface
    the ray sees, ignoring how opaque it is)."""
    depth = (weights * t_mid).sum(-1)
    if normalize:
        depth = depth / weights.sum(-1).clamp_min(1e-8)
    return depth


def opacity_crossing_interval(sigma: Tensor, deltas: Tensor, level: float = 0.5) -> tuple[Tensor, Tensor, Tensor]:
    """In which interval, and how far into it, each ray's accumulated opacity first reaches ``level``.

    The density is taken as constant over each interval (the quadrature :func:`render_weights` uses), so
    inside the crossing interval ``k`` the position is exact: ``T_k exp(-σ_k Δt_k f) = 1 - level``.

    Parameters
    ----------
    sigma, deltas : Tensor
        ``[n_rays, n_samples]`` densities and interval lengths, intervals in ray order.
    level : float
        Opacity in ``(0, 1)``.

    Returns
    -------
    interval : Tensor
        ``[n_rays]`` int64 index ``k`` of the crossing interval (the last one where it is never reached).
    fraction : Tensor
        ``[n_rays]`` in ``[0, 1]``: the crossing's position inside interval ``k``.
    reached : Tensor
        ``[n_rays]`` bool, whether the ray reaches ``level`` at all.
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"opacity_crossing: level must be in (0, 1), got {level}")
    weights, transmittance = render_weights(sigma, deltas)
    opacity = weights.cumsum(-1)
    reached = opacity[:, -1] >= level
    k = (opacity < level).sum(-1).clamp(max=sigma.shape[-1] - 1)
    rows = torch.arange(sigma.shape[0], device=sigma.device)
    tau_k = optical_depth(sigma[rows, k], deltas[rows, k])
    # T_k exp(-τ_k f) = 1 - level  →  f = ln(T_k / (1 - level)) / τ_k.
    fraction = (torch.log(transmittance[rows, k] / (1.0 - level)) / tau_k.clamp_min(1e-12)).clamp(0.0, 1.0)
    return k, fraction, reached


def opacity_crossing(sigma: Tensor, deltas: Tensor, level: float = 0.5) -> tuple[Tensor, Tensor]:
    """Where along each ray the accumulated opacity first reaches ``level`` (the median depth at 0.5).

    Exact for density constant over each interval; parameters as :func:`opacity_crossing_interval`.

    Returns
    -------
    distance : Tensor
        ``[n_rays]`` distance from the start of the first interval (units of ``deltas``); 0 where the ray
        never reaches ``level``.
    reached : Tensor
        ``[n_rays]`` bool, whether the ray reaches ``level`` at all.

    Examples
    --------
    >>> import torch
    >>> sigma = torch.tensor([[0.0, 1e9], [1.3862944, 0.0], [0.0, 0.0]])  # a wall; σ = 2 ln 2; nothing
    >>> d, ok = opacity_crossing(sigma, torch.ones(3, 2))
    >>> [round(v, 3) for v in d.tolist()], ok.tolist()
    ([1.0, 0.5, 0.0], [True, True, False])
    """
    k, fraction, reached = opacity_crossing_interval(sigma, deltas, level)
    rows = torch.arange(sigma.shape[0], device=sigma.device)
    start = torch.cumsum(deltas, -1) - deltas
    distance = start[rows, k] + fraction * deltas[rows, k]
    return torch.where(reached, distance, torch.zeros_like(distance)), reached


def median_depth(weights: Tensor, t_mid: Tensor, deltas: Tensor, level: float = 0.5) -> tuple[Tensor, Tensor]:
    """Distance along each ray where its accumulated opacity first reaches ``level`` (the median depth at 0.5),
    from the rendering weights alone.

    :func:`opacity_crossing_interval` (density constant over each interval) for callers that hold the weights of
    a render rather than its densities: interval ``k``'s transmittance is ``T_k = 1 - Σ_{i<k} w_i`` and its optical
    depth ``τ_k = ln(T_k / T_{k+1})``. Unlike the expected depth ``Σ w_i t_i``, it does not
    move with faint density far behind the surface (the fog of an unbounded scene's background pulls the
    expected depth of a street's road from 3 m to 20 m), and it is where the export's isosurface lies.

    Parameters
    ----------
    weights, t_mid, deltas : Tensor
        ``[n_rays, n_samples]`` rendering weights, interval midpoints and lengths, intervals in ray order.
    level : float
        Opacity in ``(0, 1)``.

    Returns
    -------
    distance : Tensor
        ``[n_rays]`` distance along the ray (units of ``t_mid``); 0 where the ray never reaches ``level``.
    reached : Tensor
        ``[n_rays]`` bool.

    Examples
    --------
    >>> import torch
    >>> sigma, deltas = torch.tensor([[0.0, 1.3862944, 0.0]]), torch.ones(1, 3)   # σ = 2 ln 2 over [1, 2]
    >>> w, _ = render_weights(sigma, deltas)
    >>> d, ok = median_depth(w, torch.tensor([[0.5, 1.5, 2.5]]), deltas)
    >>> round(d.item(), 3), ok.item()
    (1.5, True)
    """
    # Each interval's optical depth from the weights (a saturated one: as opaque as representable), then the
    # crossing exactly as from densities.
    tiny = torch.finfo(weights.dtype).tiny
    after = 1.0 - weights.cumsum(-1)  # transmittance out of each interval
    tau = torch.log((after + weights).clamp_min(tiny)) - torch.log(after.clamp_min(tiny))
    k, fraction, reached = opacity_crossing_interval(tau, torch.ones_like(tau), level)
    k = k[:, None]
    delta_k = deltas.gather(-1, k).squeeze(-1)
    distance = t_mid.gather(-1, k).squeeze(-1) - 0.5 * delta_k + fraction * delta_k
    return torch.where(reached, distance, torch.zeros_like(distance)), reached


def render_opacity(weights: Tensor) -> Tensor:
    """Accumulated opacity ``Σ w_i`` ``[R]`` in ``[0, 1]``."""
    return weights.sum(-1)


def interval_midpoints(edges: Tensor) -> tuple[Tensor, Tensor]:
    """``edges`` ``[R, S+1]`` (sorted sample boundaries) → midpoints ``[R, S]``, lengths ``Δt`` ``[R, S]``."""
    return 0.5 * (edges[..., 1:] + edges[..., :-1]), (edges[..., 1:] - edges[..., :-1]).clamp_min(0.0)
