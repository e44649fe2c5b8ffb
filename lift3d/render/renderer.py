"""How rays combine points: proposal sampling, the field at the final samples, compositing.

:func:`render_rays` renders one batch (training) and :func:`render_rays_chunked` any number of rays
without gradients (evaluation, export). The field is a :class:`lift3d.field.base.Field` (its ``space``,
``geometry``, ``color`` and ``labels``).

Speed on CPU: density is needed at every sample, but the colour, semantic and instance
decoders only matter where a sample has weight; they run only on samples with ``w > head_weight_threshold``
(exact up to that threshold; no deferred decoding).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn
from torch.profiler import record_function

from lift3d.field.base import Field
from lift3d.render.samplers import interlevel_loss, ray_aabb, sample_pdf, spacing_fn, spacing_fn_inv, uniform_edges
from lift3d.render.volume import composite, interval_midpoints, render_weights
from lift3d.utils.progress import progress_bar


@dataclass
class SamplingConfig:
    """How rays are sampled and composited."""

    near_plane: float = 0.05
    """Closest distance rendered (normalised scene units)."""
    far_plane: float = 1000.0
    """Farthest distance for unbounded scenes (normalised units; the contracted grid reaches infinity)."""
    proposal_resolutions: tuple[int, ...] = (64,)
    """Resolution of each proposal density grid (coarse to fine); empty = no proposal sampling."""
    proposal_samples: tuple[int, ...] = (64,)
    """Uniform samples fed to each proposal level."""
    num_samples: int = 32
    """Samples per ray at which the full field is evaluated."""
    proposal_anneal_steps: int = 300
    """Steps over which proposal weights are annealed from flat (w^0) to sharp (w^1) before resampling:
    an untrained proposal grid front-loads its weights and would otherwise lock samples (and the fog they
    create) near the cameras."""
    head_weight_threshold: float = 1e-4
    """Colour/label decoders run only on samples whose weight exceeds this (0 = all samples)."""
    label_max_samples: int = 8
    """Semantic/instance decoders run on at most this many highest-weight samples per ray (0 = no cap).
    Once geometry has formed, a ray's weight sits on a few samples; before that, the cap keeps the wide
    label decoders from running on every sample."""
    near_gradient_distance: float = 0.5
    """Gradients of density and colour at a sample at distance ``t`` from its camera are scaled by
    ``min(1, (t / d)^2)`` (Philip & Deschaintre 2023, "Floaters No More"): space close to a camera is
    sampled far more densely per volume than the scene, so it over-learns and grows floaters that fog nearby
    novel views. Normalised units; 0 disables."""
    depth_guide_samples: int = 5
    """Training rays with a measured depth get this many extra samples spread over ±``depth_guide_spread``
    around it (depth-guided sampling, as in Roessle et al. 2022, "Dense Depth Priors for NeRF"). Without
    them, a surface that first forms in the wrong place captures every proposal sample and depth
    supervision can no longer reach the true one. 0 disables."""
    depth_guide_spread: float = 0.03
    """Half-width of the depth-guided samples (normalised units)."""
    background: str = "black"
    """Colour behind the last sample: ``black``, ``white`` or ``random`` (training only; black at test)."""
    chunk_size: int = 4096
    """Rays per chunk when rendering without gradients."""


@dataclass
class RenderOutputs:
    """What :func:`render_rays` returns (per ray unless noted)."""

    rgb: Tensor  # [R, 3]
    depth: Tensor  # [R] expected distance along the (unit) ray, normalised units
    opacity: Tensor  # [R]
    semantic: Tensor | None  # [R, U] composited logits (weights detached)
    instance: Tensor | None  # [R, V] composited logits (weights detached)
    weights: Tensor  # [R, S]
    t_mid: Tensor  # [R, S]
    s_edges: Tensor  # [R, S+1] sample edges in the ray coordinate normalised to [0, 1] between near and far
    distill: Tensor  # scalar: Σ over proposal levels of the inter-level loss (0 without proposals)


def near_far(origins: Tensor, dirs: Tensor, cfg: SamplingConfig, bounded: bool) -> tuple[Tensor, Tensor]:
    """Per-ray ``near``/``far``: the box ``[-1, 1]^3`` for bounded scenes, the near/far planes otherwise.
    Rays that miss a bounded box get ``far == near`` (nothing rendered)."""
    if bounded:
        t0, t1 = ray_aabb(origins, dirs)
        near = t0.clamp_min(cfg.near_plane)
        far = torch.maximum(t1, near)
        return near, far
    near = torch.full_like(origins[:, 0], cfg.near_plane)
    return near, torch.full_like(near, cfg.far_plane)


def render_rays(
    field: Field,
    proposals: nn.ModuleList,
    origins: Tensor,
    dirs: Tensor,
    cfg: SamplingConfig,
    *,
    bounded: bool,
    training: bool = False,
    with_labels: bool = True,
    background: Tensor | None = None,
    generator: torch.Generator | None = None,
    proposal_anneal: float = 1.0,
    depth_target: Tensor | None = None,
) -> RenderOutputs:
    """Render a batch of rays.

    Parameters
    ----------
    field : Field
        The field (any kind).
    proposals : nn.ModuleList
        :class:`~lift3d.field.layers.ProposalGrid` per proposal level (may be empty).
    origins, dirs : Tensor
        ``[R, 3]`` ray origins and unit directions, normalised scene coordinates.
    cfg : SamplingConfig
    bounded : bool
        Scene inside ``[-1, 1]^3`` (linear spacing) or unbounded (contracted, lin/disparity spacing).
    training : bool
        Jittered samples; random background if configured.
    with_labels : bool
        Also composite semantic and instance logits.
    background : Tensor, optional
        ``[R, 3]`` or ``[3]`` colour behind the ray (overrides ``cfg.background``).
    proposal_anneal : float
        Exponent in ``[0, 1]`` applied to proposal weights before resampling (1 = no annealing).
    depth_target : Tensor, optional
        ``[R]`` measured distance along each ray (normalised units, 0 = unknown): adds
        ``cfg.depth_guide_samples`` samples around it when training.
    """
    n_rays = origins.shape[0]
    spacing = "linear" if bounded else "lindisp"
    near, far = near_far(origins, dirs, cfg, bounded)
    space = field.space

    def points(s_edges: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        t_edges = spacing_fn_inv(s_edges, spacing)
        t_mid, deltas = interval_midpoints(t_edges)
        x = origins[:, None, :] + dirs[:, None, :] * t_mid[..., None]
        return x.reshape(-1, 3), t_mid, deltas

    # record_function labels name the stages in `lift3d bench`'s profile (no cost without a profiler).
    prop_levels: list[tuple[Tensor, Tensor]] = []
    if len(proposals):
        s_edges = uniform_edges(near, far, cfg.proposal_samples[0], spacing, training, generator)
        with record_function("render.proposal"):
            for level, prop in enumerate(proposals):
                x, _, deltas = points(s_edges)
                u, valid = space(x)
                sigma = prop(u, valid).view(n_rays, -1)
                w, _ = render_weights(sigma, deltas)
                prop_levels.append((s_edges, w))
                n_next = cfg.proposal_samples[level + 1] if level + 1 < len(proposals) else cfg.num_samples
                w_resample = w if proposal_anneal >= 1.0 else w.detach().clamp_min(0) ** proposal_anneal
                s_edges = sample_pdf(s_edges, w_resample, n_next, training, generator=generator)
    else:
        s_edges = uniform_edges(near, far, cfg.num_samples, spacing, training, generator)
    if training and depth_target is not None and cfg.depth_guide_samples > 0:
        s_edges = add_depth_guided_edges(s_edges, depth_target, near, far, cfg.depth_guide_samples,
                                         cfg.depth_guide_spread, spacing)

    x, t_mid, deltas = points(s_edges)
    n_samples = t_mid.shape[1]
    with record_function("render.field_geometry"):
        sigma, geo, u = field.geometry(x)
    if training and cfg.near_gradient_distance > 0:
        near_scale = (t_mid.detach() / cfg.near_gradient_distance).square().clamp(max=1.0).reshape(-1)
        sigma = scale_gradient(sigma, near_scale)
        geo = scale_gradient(geo, near_scale[:, None])
    weights, _ = render_weights(sigma.view(n_rays, n_samples), deltas)

    # Decoders only where the sample matters (weights are constants for this choice).
    keep = (weights.detach() > cfg.head_weight_threshold).reshape(-1)
    idx = keep.nonzero().squeeze(1)
    dirs_s = dirs[:, None, :].expand(n_rays, n_samples, 3).reshape(-1, 3)
    rgb_s = geo.new_zeros(n_rays * n_samples, 3)
    with record_function("render.field_color"):
        rgb_s = rgb_s.index_copy(0, idx, field.color(geo.index_select(0, idx), dirs_s.index_select(0, idx)))
    rgb = composite(weights, rgb_s.view(n_rays, n_samples, 3))
    opacity = weights.sum(-1)

    if background is None:
        if cfg.background == "white":
            background = torch.ones(3, device=rgb.device, dtype=rgb.dtype)
        elif cfg.background == "random" and training:
            background = torch.rand(n_rays, 3, device=rgb.device, dtype=rgb.dtype, generator=generator)
        else:
            background = None
    if background is not None:
        rgb = rgb + (1.0 - opacity)[:, None] * background

    semantic = instance = None
    if with_labels:
        w_det = weights.detach()  # labels must not carve geometry
        lidx = _label_samples(w_det, cfg) if 0 < cfg.label_max_samples < n_samples else idx
        with record_function("render.field_labels"):
            sem_s, inst_s = field.labels(u.index_select(0, lidx), geo.index_select(0, lidx))
        semantic = composite(w_det, _scatter_rows(sem_s, lidx, n_rays * n_samples).view(n_rays, n_samples, -1))
        if inst_s is not None:
            instance = composite(w_det, _scatter_rows(inst_s, lidx, n_rays * n_samples).view(n_rays, n_samples, -1))

    distill = weights.new_zeros(())
    if training and prop_levels:
        for prop_edges, prop_w in prop_levels:
            distill = distill + interlevel_loss(s_edges, weights, prop_edges, prop_w)

    depth = (weights * t_mid).sum(-1)
    s_near, s_far = spacing_fn(near, spacing)[:, None], spacing_fn(far, spacing)[:, None]
    s_unit = (s_edges - s_near) / (s_far - s_near).clamp_min(1e-9)
    return RenderOutputs(rgb=rgb, depth=depth, opacity=opacity, semantic=semantic, instance=instance,
                         weights=weights, t_mid=t_mid, s_edges=s_unit, distill=distill)


def add_depth_guided_edges(s_edges: Tensor, depth: Tensor, near: Tensor, far: Tensor, n: int, spread: float,
                           spacing: str) -> Tensor:
    """Merge ``n`` edges evenly spread over ``depth ± spread`` into each ray's sorted edges.

    ``s_edges``: ``[R, S+1]`` (spacing coordinate); ``depth``, ``near``, ``far``: ``[R]`` distances (depth 0 =
    unknown). Returns ``[R, S+1+n]`` sorted edges. Rays without a depth get copies of their last edge:
    zero-length intervals, which carry no weight.
    """
    offsets = torch.linspace(-spread, spread, n, device=depth.device, dtype=depth.dtype)
    t = (depth[:, None] + offsets[None, :]).clamp(min=near[:, None], max=far[:, None])
    extra = spacing_fn(t, spacing)
    extra = torch.where((depth > 0)[:, None], extra, s_edges[:, -1:].expand_as(extra))
    return torch.sort(torch.cat([s_edges, extra], -1), -1).values


class _ScaleGradient(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x: Tensor, scale: Tensor) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(scale)
        return x.view_as(x)

    @staticmethod
    def backward(ctx, grad: Tensor):  # type: ignore[override]
        (scale,) = ctx.saved_tensors
        return grad * scale, None


def scale_gradient(x: Tensor, scale: Tensor) -> Tensor:
    """``x`` unchanged in the forward pass; its gradient multiplied by ``scale`` (broadcastable to ``x``).

    Examples
    --------
    >>> x = torch.ones(3, requires_grad=True)
    >>> scale_gradient(x, torch.tensor([0.0, 0.5, 1.0])).sum().backward()
    >>> x.grad.tolist()
    [0.0, 0.5, 1.0]
    """
    return _ScaleGradient.apply(x, scale)


def _label_samples(weights: Tensor, cfg: SamplingConfig) -> Tensor:
    """Flat indices of the ``label_max_samples`` highest-weight samples of every ray that also pass the
    weight threshold. ``weights`` ``[R, S]`` → ``[K]``."""
    n_rays, n_samples = weights.shape
    top_w, top_i = weights.topk(cfg.label_max_samples, dim=1)
    flat = top_i + torch.arange(n_rays, device=weights.device)[:, None] * n_samples
    return flat[top_w > cfg.head_weight_threshold]


def _scatter_rows(values: Tensor, idx: Tensor, n: int) -> Tensor:
    """Rows ``values`` ``[K, C]`` placed at ``idx`` in a zero ``[n, C]`` tensor (differentiable)."""
    return values.new_zeros(n, values.shape[1]).index_copy(0, idx, values)


@torch.no_grad()
def render_rays_chunked(
    field: Field,
    proposals: nn.ModuleList,
    origins: Tensor,
    dirs: Tensor,
    cfg: SamplingConfig,
    *,
    bounded: bool,
    with_labels: bool = True,
    chunk_size: int | None = None,
    progress: bool = False,
) -> dict[str, Tensor]:
    """Render any number of rays in chunks without gradients.

    Returns
    -------
    dict
        ``rgb`` ``[R, 3]``, ``depth`` ``[R]``, ``opacity`` ``[R]`` and with labels ``semantic`` ``[R, U]``
        and ``instance`` ``[R, V]`` *probabilities* (softmax of the composited logits).
    """
    chunk = chunk_size or cfg.chunk_size
    outs: dict[str, list[Tensor]] = {}
    starts = range(0, origins.shape[0], chunk)
    for s in progress_bar(starts, desc="render", disable=not progress, leave=False, unit="chunk"):
        r = render_rays(field, proposals, origins[s:s + chunk], dirs[s:s + chunk], cfg, bounded=bounded,
                        training=False, with_labels=with_labels)
        parts = {"rgb": r.rgb, "depth": r.depth, "opacity": r.opacity}
        if r.semantic is not None:
            parts["semantic"] = torch.softmax(r.semantic, -1)
        if r.instance is not None:
            parts["instance"] = torch.softmax(r.instance, -1)
        for k, v in parts.items():
            outs.setdefault(k, []).append(v)
    return {k: torch.cat(v) for k, v in outs.items()}
