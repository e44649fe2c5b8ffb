"""How rays combine points: proposal sampling, the field at the final samples, compositing.

:func:`render_rays` renders one batch (training) and :func:`render_rays_chunked` any number of rays
without gradients (evaluation, export). The field is a :class:`lift3d.field.base.Field` (its ``space``,
``geometry``, ``color`` and ``labels``).

Speed on CPU: the field's geometry runs only where it can matter — not in cells the
field gives zero density (outside the scene, unobserved, or empty in the occupancy grid: exact), and not
behind the point where a ray's transmittance has dropped below ``termination_transmittance`` (early ray
termination, checked every ``termination_block`` samples). The colour, semantic and instance decoders only
matter where a sample has weight; they run only on samples with ``w > head_weight_threshold`` (exact up to
that threshold; no deferred decoding).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn
from torch.profiler import record_function

from lift3d.field import native
from lift3d.field.base import Field
from lift3d.field.layers import ProposalGrid
from lift3d.render.samplers import interlevel_loss, ray_aabb, sample_pdf, spacing_fn, spacing_fn_inv, uniform_edges
from lift3d.render.volume import interval_midpoints, median_depth, render_weights
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
    termination_transmittance: float = 1e-4
    """Early ray termination: the field is not evaluated at samples behind the point where a ray's
    transmittance has dropped below this (their weight could be at most this); 0 = evaluate every sample."""
    termination_block: int = 8
    """Samples per ray evaluated together between two early-termination checks."""
    termination_in_training: bool = False
    """Training renders terminate rays early too (the skipped samples' weights are below
    ``termination_transmittance``). Off: on an indoor room with sensor depth (`fast`, one run each) steps were no
    faster (352 against 336 ms after step 300: the block-wise passes cost what the skipped samples save)."""
    head_weight_threshold: float = 1e-4
    """Colour/label decoders run only on samples whose weight exceeds this (0 = all samples)."""
    label_max_samples: int = 8
    """Semantic/instance decoders run on at most this many highest-weight samples per ray (0 = no cap).
    Once geometry has formed, a ray's weight sits on a few samples; before that, the cap keeps the wide
    label decoders from running on every sample."""
    render_label_coverage: float = 0.9
    """Renders outside training (evaluation, rendered images and videos, ``LoadedRun.render_rays``): of a
    ray's ``label_max_samples`` highest-weight samples, the semantic/instance decoders run only on the
    fewest that hold this fraction of their weight, scaled up to the weight of all of them (0 = all of them,
    as in training; in [0, 1]). Training and the point-cloud export (labels per point) are unaffected.
    Chosen on four tuning runs (`fast`, rooms 5 and 6, with and without depth maps): 0.9 decodes 4.0-4.9
    samples per ray instead of 7.4-7.7 where sensor depth made surfaces sharp (7.7 of 8 without depth maps,
    whose weight spreads), test-view mIoU moved by at most 0.0008 and PQ^scene by at most 0.0014; on the
    benchmark's reporting runs mIoU by at most 0.001 and PQ^scene by -0.023 to +0.039 (instance matches at
    IoU 0.5 flip on small label changes)."""
    train_label_coverage: float = 0.0
    """Training renders: of a ray's ``label_max_samples`` highest-weight samples, the semantic/instance
    decoders run (and learn) only on the fewest that hold this fraction of their weight, scaled up to the
    weight of all of them, as ``render_label_coverage`` does outside training (0 = all of them; in [0, 1]).
    0.9 made `fast` steps 11 % faster (indoor seed 0) but cost room 6 of the tuning rooms 0.07 PQ^scene and
    0.014 point mIoU (room 5: no change), so it is off (docs/notes/2026-11-29-benchmark-history.md, "Where the
    time goes")."""
    render_color_coverage: float = 0.0
    """Renders outside training: the colour decoder runs only on the fewest of a ray's samples (above
    ``head_weight_threshold``) that hold this fraction of their weight, scaled up to the weight of all of them
    (0 or 1 = every such sample, as in training). The point-cloud export (colour per point) is unaffected.
    Measured on the `fast` runs of rooms 0-2 with sensor depth: 0.99 decodes a third fewer colour samples
    (7.6-11.3 per ray instead of 11.6-16.6) at -0.01 dB PSNR, but the 2048-ray render was no faster (medians
    29.2/28.1/28.0 ms against 28.2/28.6/27.2 ms, alternating in one process): the per-ray sort costs what the
    skipped decodes save. Off by default."""
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


@dataclass(frozen=True)
class RenderOptions:
    """How one :func:`render_rays` call renders its batch, beside the run's :class:`SamplingConfig`.

    Attributes
    ----------
    training : bool
        A training render: jittered samples, the random background if configured, the training-only sampling
        settings (``train_label_coverage``, depth-guided samples, near-camera gradient scaling).
    with_labels : bool
        Also composite semantic and instance logits.
    background : Tensor, optional
        ``[R, 3]`` or ``[3]`` colour behind the ray (overrides ``cfg.background``).
    proposal_anneal : float
        Exponent in ``[0, 1]`` applied to proposal weights before resampling (1 = no annealing).
    """

    training: bool = False
    with_labels: bool = True
    background: Tensor | None = None
    proposal_anneal: float = 1.0


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
    deltas: Tensor | None = None  # [R, S] interval lengths Δt (normalised units)


def near_far(origins: Tensor, dirs: Tensor, cfg: SamplingConfig, bounded: bool,
             box: tuple = (-1.0, 1.0)) -> tuple[Tensor, Tensor]:
    """Per-ray ``near``/``far``: for bounded scenes where the rays enter and leave ``box`` (``(lower, upper)``,
    floats or ``[3]`` tensors; the field space's :meth:`~lift3d.field.space.SceneSpace.ray_bounds`, by default
    the cube ``[-1, 1]^3``), the near/far planes otherwise. Rays that miss a bounded box get ``far == near``
    (nothing rendered)."""
    if bounded:
        t0, t1 = ray_aabb(origins, dirs, *box)
        near = t0.clamp_min(cfg.near_plane)
        far = torch.maximum(t1, near)
        return near, far
    near = torch.full_like(origins[:, 0], cfg.near_plane)
    return near, torch.full_like(near, cfg.far_plane)



def _composite(n_rays: int, ray: Tensor, weighted: Tensor) -> Tensor:
    """Sum weighted sample values per ray: ``weighted`` [K, C] with ray index ``ray`` [K] -> [n_rays, C].

    The sum is kept in ``weighted``'s dtype: under autocast a decoder's bfloat16 output times float32
    weights is float32, and ``index_add`` needs both sides alike.
    """
    return weighted.new_zeros(n_rays, weighted.shape[1]).index_add(0, ray, weighted)

def ray_starts(ray: Tensor, n_rays: int) -> Tensor:
    """Where each ray's entries begin in a list sorted by ray: ``ray`` ``[K]`` non-decreasing ray index →
    ``[n_rays + 1]`` int64, ray ``r``'s entries at ``[start[r], start[r + 1])``.

    Examples
    --------
    >>> ray_starts(torch.tensor([0, 0, 2, 2, 2]), 4).tolist()
    [0, 2, 2, 5, 5]
    """
    return torch.searchsorted(ray, torch.arange(n_rays + 1, device=ray.device, dtype=ray.dtype))


def render_rays(
    field: Field,
    proposals: nn.ModuleList,
    origins: Tensor,
    dirs: Tensor,
    cfg: SamplingConfig,
    options: RenderOptions | None = None,
    *,
    bounded: bool,
    generator: torch.Generator | None = None,
    depth_target: Tensor | None = None,
    depth_spread: Tensor | None = None,
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
    options : RenderOptions, optional
        Training or not, labels or not, the background, proposal annealing (default: :class:`RenderOptions`'s,
        a render outside training with labels).
    bounded : bool
        Scene inside ``[-1, 1]^3`` (linear spacing) or unbounded (contracted, lin/disparity spacing).
    generator : torch.Generator, optional
        Randomness of a training render's jitter and random background.
    depth_target : Tensor, optional
        ``[R]`` measured distance along each ray (normalised units, 0 = unknown): adds
        ``cfg.depth_guide_samples`` samples around it when training.
    depth_spread : Tensor, optional
        ``[R]`` half-width of those samples per ray (e.g. twice a measurement's standard deviation);
        ``cfg.depth_guide_spread`` where it is 0 or not given.
    """
    options = RenderOptions() if options is None else options
    training, with_labels, background, proposal_anneal = (options.training, options.with_labels, options.background,
                                                          options.proposal_anneal)
    n_rays = origins.shape[0]
    spacing = "linear" if bounded else "lindisp"
    space = field.space
    near, far = near_far(origins, dirs, cfg, bounded, space.ray_bounds())

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
            ext = None
            if not (training or torch.is_grad_enabled() or proposal_anneal < 1.0) and \
                    all(_is_plain_proposal(p) for p in proposals):
                ext = native.usable(origins, dirs, s_edges)
            if ext is not None:
                s_edges = _proposals_native(ext, field, proposals, origins, dirs, s_edges, cfg, spacing)
            for level, prop in enumerate(proposals if ext is None else ()):
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
        spread = cfg.depth_guide_spread
        if depth_spread is not None:
            spread = torch.where(depth_spread > 0, depth_spread, torch.full_like(depth_spread, spread))
        s_edges = add_depth_guided_edges(s_edges, depth_target, near, far, cfg.depth_guide_samples, spread, spacing)

    x, t_mid, deltas = points(s_edges)
    n_samples = t_mid.shape[1]
    with record_function("render.field_geometry"):
        u, valid = space(x)
        eps = cfg.termination_transmittance if (cfg.termination_in_training or not training) else 0.0
        sigma, geo, geo_row, evaluated = geometry_where_needed(field, x, u, valid.view(n_rays, n_samples), deltas,
                                                               eps, cfg.termination_block)
    if training and cfg.near_gradient_distance > 0:
        near_scale = (t_mid.detach() / cfg.near_gradient_distance).square().clamp(max=1.0)
        sigma = scale_gradient(sigma, near_scale)
        geo_scale = near_scale.reshape(-1, 1) if evaluated is None else near_scale.reshape(-1, 1)[evaluated]
        geo = scale_gradient(geo, geo_scale)
    weights, _ = render_weights(sigma, deltas)
    w_flat = weights.reshape(-1)

    # Decoders only where the sample matters (weights are constants for this choice); composited with an
    # index_add per ray over the chosen samples (no [rays x samples x channels] temporaries).
    color_coverage = 0.0 if training else cfg.render_color_coverage
    with torch.no_grad():
        if 0 < color_coverage < 1:
            cidx, cscale = _decoder_samples(weights.detach(), 0, cfg.head_weight_threshold, color_coverage)
        else:
            cidx, cscale = (w_flat > cfg.head_weight_threshold).nonzero().squeeze(1), None
        cray = torch.div(cidx, n_samples, rounding_mode="floor")
        crows = cidx if geo_row is None else geo_row.index_select(0, cidx)
    cw = w_flat.index_select(0, cidx)
    if cscale is not None:
        cw = cw * cscale
    # Without gradients, and with a row of features per sample, a field may decode and sum in one pass.
    fused = geo_row is None and not torch.is_grad_enabled()
    with record_function("render.field_color"):
        rgb = field.composite_color(geo, dirs, cidx, ray_starts(cray, n_rays), cw) if fused else None
        if rgb is None:
            rgb_k = field.color(geo.index_select(0, crows), dirs.index_select(0, cray))
            rgb = _composite(n_rays, cray, cw[:, None] * rgb_k)
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
        coverage = cfg.train_label_coverage if training else cfg.render_label_coverage
        if 0 < cfg.label_max_samples < n_samples or coverage > 0:
            with torch.no_grad():
                lidx, lscale = _decoder_samples(w_det, cfg.label_max_samples, cfg.head_weight_threshold, coverage)
                lray = torch.div(lidx, n_samples, rounding_mode="floor")
                lrows = lidx if geo_row is None else geo_row.index_select(0, lidx)
        else:
            lidx, lray, lrows, lscale = cidx, cray, crows, None
            if cscale is not None:  # the colour took fewer samples: the labels take every one above the threshold
                with torch.no_grad():
                    lidx = (w_flat > cfg.head_weight_threshold).nonzero().squeeze(1)
                    lray = torch.div(lidx, n_samples, rounding_mode="floor")
                    lrows = lidx if geo_row is None else geo_row.index_select(0, lidx)
        lw = w_det.reshape(-1).index_select(0, lidx)
        if lscale is not None:
            lw = lw * lscale
        with record_function("render.field_labels"):
            labels = field.composite_labels(u, geo, lidx, ray_starts(lray, n_rays), lw) if fused else None
            if labels is not None:
                semantic, instance = labels
            else:
                sem_s, inst_s = field.labels(u.index_select(0, lidx), geo.index_select(0, lrows))
                semantic = _composite(n_rays, lray, lw[:, None] * sem_s)
                if inst_s is not None:
                    instance = _composite(n_rays, lray, lw[:, None] * inst_s)

    distill = weights.new_zeros(())
    if training and prop_levels:
        for prop_edges, prop_w in prop_levels:
            distill = distill + interlevel_loss(s_edges, weights, prop_edges, prop_w)

    depth = (weights * t_mid).sum(-1)
    s_near, s_far = spacing_fn(near, spacing)[:, None], spacing_fn(far, spacing)[:, None]
    s_unit = (s_edges - s_near) / (s_far - s_near).clamp_min(1e-9)
    return RenderOutputs(rgb=rgb, depth=depth, opacity=opacity, semantic=semantic, instance=instance,
                         weights=weights, t_mid=t_mid, s_edges=s_unit, distill=distill, deltas=deltas)


def _is_plain_proposal(prop: nn.Module) -> bool:
    """A :class:`ProposalGrid` of one 1-channel level (what the C++ proposal pass handles)."""
    return isinstance(prop, ProposalGrid) and len(prop.grid.resolutions) == 1 and prop.grid.channels == 1


def _proposals_native(ext, field: Field, proposals: nn.ModuleList, origins: Tensor, dirs: Tensor, s_edges: Tensor,
                      cfg: SamplingConfig, spacing: str) -> Tensor:
    """Every proposal level without gradients in one C++ pass per level (lift3d.field.native): the same
    densities, weights and deterministic resampling as the torch loop of :func:`render_rays`."""
    space = field.space
    observed, occupied = space.masks()
    origins, dirs = origins.contiguous(), dirs.contiguous()
    for level, prop in enumerate(proposals):
        n_next = cfg.proposal_samples[level + 1] if level + 1 < len(proposals) else cfg.num_samples
        grid = prop.grid
        new = s_edges.new_empty(s_edges.shape[0], n_next + 1)
        ext.proposal_resample(origins, dirs, s_edges.contiguous(), spacing == "lindisp", grid.tables[0].detach(),
                              grid.resolutions[0], float(prop.density_bias), space.CONTRACTION_CODES[space.contraction],
                              space.extent, observed, occupied, 0.01, new)
        s_edges = new
    return s_edges


def geometry_where_needed(field: Field, x: Tensor, u: Tensor, valid: Tensor, deltas: Tensor, eps: float,
                          block: int) -> tuple[Tensor, Tensor, Tensor | None, Tensor | None]:
    """The field's density and geometry features at the samples of a batch of rays, evaluated only where
    they can matter.

    Samples that are not ``valid`` (the field's density is zero there by definition: outside the scene,
    unobserved, empty in the occupancy grid) are skipped exactly. With ``eps > 0`` the samples are taken
    ``block`` at a time along the rays, and a ray stops once its transmittance is below ``eps``: every
    later sample's weight would be smaller than that (early ray termination). Skipped samples get σ = 0.
    Without gradients a field's fused :meth:`~lift3d.field.base.Field.march` does the same in one pass when it
    has one (the grid field on the CPU: then ``geo`` has a row per sample, zeros where not evaluated).

    Parameters
    ----------
    field : Field
    x, u : Tensor
        ``[R·S, 3]`` sample positions (ray-major) and their grid coordinates (``field.space(x)``).
    valid : Tensor
        ``[R, S]`` bool, the field may have density there.
    deltas : Tensor
        ``[R, S]`` interval lengths.
    eps : float
        Transmittance below which a ray terminates (0 = never).
    block : int
        Samples per ray between termination checks.

    Returns
    -------
    sigma : Tensor
        ``[R, S]`` (0 where not evaluated).
    geo : Tensor
        ``[K, F]`` features of the evaluated samples.
    geo_row : Tensor or None
        ``[R·S]`` int64 row of ``geo`` of each sample (-1 where not evaluated); None when every sample was
        evaluated in order (row = sample).
    evaluated : Tensor or None
        ``[K]`` the flat sample index of each row of ``geo`` (None as for ``geo_row``).
    """
    n_rays, n_samples = valid.shape
    if not torch.is_grad_enabled():
        fused = field.march(u, valid, deltas, -math.log(eps) if eps > 0 else math.inf)
        if fused is not None:
            return fused[0], fused[1], None, None
    if eps <= 0 or block >= n_samples:
        if bool(valid.all()):
            sigma, geo, _ = field.geometry(x, space=(u, valid.reshape(-1)))
            return sigma.view(n_rays, n_samples), geo, None, None
        block, eps = n_samples, 0.0
    max_depth = -math.log(eps) if eps > 0 else math.inf
    optical = torch.zeros(n_rays, device=x.device, dtype=x.dtype)  # Σ σΔ so far (detached)
    alive = torch.ones(n_rays, device=x.device, dtype=torch.bool)
    ones = torch.ones(1, device=x.device, dtype=torch.bool).expand(x.shape[0])
    flat_parts, sigma_parts, geo_parts = [], [], []
    for start in range(0, n_samples, block):
        stop = min(start + block, n_samples)
        take = valid[:, start:stop] & alive[:, None]
        pos = take.nonzero()  # [K, 2] (ray, sample within the block)
        if len(pos) == 0 and flat_parts:
            continue
        ray = pos[:, 0]
        flat = ray * n_samples + pos[:, 1] + start
        sigma, geo, _ = field.geometry(x.index_select(0, flat), space=(u.index_select(0, flat), ones[: len(flat)]))
        flat_parts.append(flat)
        sigma_parts.append(sigma)
        geo_parts.append(geo)
        if stop < n_samples and max_depth < math.inf:
            tau = sigma.detach() * deltas.reshape(-1).index_select(0, flat)
            optical.index_add_(0, ray, torch.nan_to_num(tau, nan=0.0, posinf=max_depth))
            alive = optical < max_depth
            if not bool(alive.any()):
                break
    flat = torch.cat(flat_parts) if len(flat_parts) > 1 else flat_parts[0]
    sigma = torch.cat(sigma_parts) if len(sigma_parts) > 1 else sigma_parts[0]
    geo = torch.cat(geo_parts) if len(geo_parts) > 1 else geo_parts[0]
    n = n_rays * n_samples
    if len(flat_parts) == 1 and len(flat) == n:  # every sample evaluated, in order
        return sigma.view(n_rays, n_samples), geo, None, None
    sigma_all = sigma.new_zeros(n).index_copy(0, flat, sigma)
    geo_row = torch.full((n,), -1, dtype=torch.long, device=x.device)
    geo_row[flat] = torch.arange(len(flat), device=x.device)
    return sigma_all.view(n_rays, n_samples), geo, geo_row, flat


def add_depth_guided_edges(s_edges: Tensor, depth: Tensor, near: Tensor, far: Tensor, n: int,
                           spread: float | Tensor, spacing: str) -> Tensor:
    """Merge ``n`` edges evenly spread over ``depth ± spread`` into each ray's sorted edges.

    ``s_edges``: ``[R, S+1]`` (spacing coordinate); ``depth``, ``near``, ``far``: ``[R]`` distances (depth 0 =
    unknown); ``spread``: a number or ``[R]``. Returns ``[R, S+1+n]`` sorted edges. Rays without a depth get
    copies of their last edge: zero-length intervals, which carry no weight.
    """
    unit = torch.linspace(-1.0, 1.0, n, device=depth.device, dtype=depth.dtype)[None, :]
    offsets = unit * (spread[:, None] if isinstance(spread, Tensor) else spread)
    t = (depth[:, None] + offsets).clamp(min=near[:, None], max=far[:, None])
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


def _decoder_samples(weights: Tensor, cap: int, threshold: float,
                     coverage: float = 0.0) -> tuple[Tensor, Tensor | None]:
    """The samples a decoder runs on (labels: ``cap`` = ``label_max_samples``; colour outside training: no
    cap): the ``cap`` (0: all) highest-weight samples of every ray that pass the weight ``threshold``; with
    ``coverage`` > 0 only the fewest of them that hold that fraction of their weight. ``weights`` ``[R, S]``
    → flat indices ``[K]`` and, with ``coverage``, a factor ``[K]`` per sample that scales its ray's kept
    weight up to that of all ``cap`` samples (so composited logits, and the confidence read from them, keep
    their scale); else None.

    Examples
    --------
    >>> w = torch.tensor([[0.0, 0.9, 0.05, 0.03, 0.02], [0.1, 0.3, 0.2, 0.25, 0.0]])
    >>> _decoder_samples(w, 3, 1e-4)[0].tolist(), _decoder_samples(w, 3, 1e-4, coverage=0.6)[0].tolist()
    ([1, 2, 3, 6, 8, 7], [1, 6, 8])
    >>> [round(x, 3) for x in _decoder_samples(w, 3, 1e-4, coverage=0.6)[1].tolist()]  # 0.98 / 0.9, 0.75 / 0.55
    [1.089, 1.364, 1.364]
    """
    n_rays, n_samples = weights.shape
    cap = n_samples if cap <= 0 else min(cap, n_samples)
    top_w, top_i = weights.topk(cap, dim=1)
    keep = top_w > threshold
    flat = top_i + torch.arange(n_rays, device=weights.device)[:, None] * n_samples
    if coverage <= 0:
        return flat[keep], None
    # A sample is needed while the heavier samples before it hold less than `coverage` of the ray's weight.
    total = (top_w * keep).sum(1, keepdim=True)
    keep &= (top_w.cumsum(1) - top_w) < coverage * total
    kept = (top_w * keep).sum(1, keepdim=True)
    scale = (total / kept.clamp_min(1e-12)).expand_as(top_w)
    return flat[keep], scale[keep]


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
    with_median_depth: bool = False,
    chunk_size: int | None = None,
    progress: bool = False,
) -> dict[str, Tensor]:
    """Render any number of rays in chunks without gradients.

    Returns
    -------
    dict
        ``rgb`` ``[R, 3]``, ``depth`` ``[R]`` (expected distance ``Σ w_i t_i``), ``opacity`` ``[R]``; with labels
        ``semantic`` ``[R, U]`` and ``instance`` ``[R, V]`` *probabilities* (softmax of the composited logits);
        with ``with_median_depth`` ``median_depth`` ``[R]`` (where the opacity reaches 0.5,
        :func:`lift3d.render.volume.median_depth`; 0 where it never does).
    """
    chunk = chunk_size or cfg.chunk_size
    outs: dict[str, list[Tensor]] = {}
    starts = range(0, origins.shape[0], chunk)
    for s in progress_bar(starts, desc="render", disable=not progress, leave=False, unit="chunk"):
        r = render_rays(field, proposals, origins[s:s + chunk], dirs[s:s + chunk], cfg,
                        RenderOptions(training=False, with_labels=with_labels), bounded=bounded)
        parts = {"rgb": r.rgb, "depth": r.depth, "opacity": r.opacity}
        if with_median_depth:
            parts["median_depth"] = median_depth(r.weights, r.t_mid, r.deltas)[0]
        if r.semantic is not None:
            parts["semantic"] = torch.softmax(r.semantic, -1)
        if r.instance is not None:
            parts["instance"] = torch.softmax(r.instance, -1)
        for k, v in parts.items():
            outs.setdefault(k, []).append(v)
    return {k: torch.cat(v) for k, v in outs.items()}
