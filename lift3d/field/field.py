"""What is at a point: the panoptic radiance field ``(x, d) → (σ, rgb, semantic logits, instance logits)``.

:class:`PanopticField` is the paper's model S: multi-resolution voxel feature grids over the (contracted)
scene feed a density decoder and a view-dependent colour decoder (spherical harmonics of the direction);
a separate small *understanding grid* feeds a semantic and an instance decoder. Labels never shape
geometry: the geometry features the label decoders may read are detached.

:class:`MLPField` is the plain NeRF/Semantic-NeRF field used as the ablation's Base.

Positions enter in normalised scene coordinates (the foreground box is ``[-1, 1]^3``, see
:class:`lift3d.train.normalization.SceneNormalization`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lift3d.field.encodings import (contract, positional_encoding, positional_encoding_dim, spherical_harmonics,
                                    uncontract)
from lift3d.field.grids import DenseGrid, default_resolutions


@dataclass
class FieldConfig:
    """The field's architecture. Zero-valued sizes are derived from the scene (written to config.yml)."""

    kind: str = "grid"
    """``grid``: the paper's model S (voxel grids); ``mlp``: a plain NeRF MLP (the ablation's Base)."""
    grid_levels: int = 3
    """Resolution levels of the geometry/appearance grid."""
    grid_min_resolution: int = 32
    """Nodes per axis of the coarsest level."""
    grid_max_resolution: int = 0
    """Nodes per axis of the finest level; 0 = from scene extent and image size (capped by the preset)."""
    grid_resolution_cap: int = 128
    """Upper bound for the derived finest resolution (CPU grids beyond ~10 M parameters get slow)."""
    grid_channels: int = 4
    """Features per node and level."""
    coarse_to_fine: float = 0.0
    """Fraction of the training steps over which the finer grid levels are switched on one by one (0 = all
    from the start). Coarse voxels are seen by many views, so geometry forms consistently before fine
    levels can fit per-view fog near the cameras."""
    position_frequencies: int = 2
    """Low-frequency positional encoding of the contracted position added to the grid features."""
    geo_feat_dim: int = 15
    """Geometry features passed from the density decoder to the colour decoder."""
    density_hidden_dim: int = 64
    """Width of the density (geometry) decoder."""
    color_hidden_dim: int = 64
    """Width of the colour (appearance) decoder."""
    color_layers: int = 2
    """Hidden layers of the colour decoder."""
    sh_degree: int = 3
    """Spherical-harmonic degree of the view-direction encoding (0–3)."""
    understanding_resolutions: tuple[int, ...] = (16,)
    """Resolutions of the understanding grid (paper: a single 16³ level)."""
    understanding_channels: int = 1
    """Features per node of the understanding grid (paper: 1)."""
    head_hidden_dim: int = 256
    """Width of the semantic and instance decoders (paper: 256)."""
    head_layers: int = 2
    """Hidden layers of the semantic and instance decoders."""
    head_position_frequencies: int = 4
    """Positional-encoding frequencies of the contracted position fed to the label decoders."""
    head_uses_geometry: bool = True
    """Feed the (detached) geometry features to the label decoders: sharp label boundaries at object edges
    without letting labels carve geometry."""
    num_semantic_classes: int = 0
    """U: semantic channels including void (0 = from the categories the labels use)."""
    num_instance_channels: int = 0
    """V: instance channels (0 = from the pseudo-labels, with headroom; no head without thing classes)."""
    contraction: str = "auto"
    """``none`` (bounded), ``linf``/``l2`` (unbounded), or ``auto`` (from the scene)."""
    density_bias: float = 2.0
    """Shift before the exponential density activation. Space starts *opaque* (σ ≈ e² per unit) and free
    space is carved out: starting transparent with a black background, the colour decoder saturates
    towards white to explain bright pixels through thin fog and gets stuck there (measured: 16 dB)."""
    observed_resolution: int = 64
    """Cells of an R³ lattice over the grid's space that no training camera sees get zero density (as
    instant-NGP marks untrained cells): space behind every camera gets no gradient, keeps its opaque initial
    density and would fog novel views and the export. 0 disables."""
    clip_to_scene_box: bool = True
    """Bounded scenes with a ``scene_box`` in transforms.json: the lattice also zeroes space outside that
    box (the normalised cube is padded and cubic). Turn off when the declared box is too tight."""
    mlp_width: int = 256
    """Base (``kind=mlp``): trunk width."""
    mlp_depth: int = 6
    """Base (``kind=mlp``): trunk depth."""
    mlp_frequencies: int = 8
    """Base (``kind=mlp``): positional-encoding frequencies of the position."""


class _TruncExp(torch.autograd.Function):
    """``exp(x)`` whose backward clamps ``x`` at 15: densities must grow by orders of magnitude within a few
    hundred steps (a softplus grows only linearly), without one large input making gradients explode."""

    @staticmethod
    def forward(ctx, x: Tensor) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(x)
        return torch.exp(x.clamp(max=20.0))

    @staticmethod
    def backward(ctx, grad: Tensor) -> Tensor:  # type: ignore[override]
        (x,) = ctx.saved_tensors
        return grad * torch.exp(x.clamp(-15.0, 15.0))


def density_activation(raw: Tensor) -> Tensor:
    """σ = exp(raw) (truncated, see :class:`_TruncExp`): σ ≥ 0, reaches 1e3–1e6 from raw ≈ 7–14."""
    return _TruncExp.apply(raw)


def make_mlp(in_dim: int, hidden: int, out_dim: int, layers: int) -> nn.Sequential:
    """``layers`` hidden ReLU layers of width ``hidden`` and a linear output."""
    mods: list[nn.Module] = []
    d = in_dim
    for _ in range(layers):
        mods += [nn.Linear(d, hidden), nn.ReLU(inplace=True)]
        d = hidden
    mods.append(nn.Linear(d, out_dim))
    return nn.Sequential(*mods)


class SceneSpace(nn.Module):
    """Maps normalised scene points to grid coordinates ``[0, 1]^3`` (contracting unbounded space).

    Bounded scenes use the box ``[-1, 1]^3``; points outside it are flagged invalid (zero density).
    Unbounded scenes contract all of space into ``[-2, 2]^3``; every finite point is valid.
    """

    def __init__(self, contraction: str):
        super().__init__()
        self.contraction = contraction
        self.extent = 1.0 if contraction == "none" else 2.0
        # [R, R, R] bool over grid coordinates (index order x, y, z); empty = every cell observed.
        self.register_buffer("observed", torch.ones(0, 0, 0, dtype=torch.bool))

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """``x``: ``[N, 3]`` → ``u`` ``[N, 3]`` in ``[0, 1]``, ``valid`` ``[N]`` bool."""
        c = contract(x, self.contraction)
        u = (c / self.extent + 1.0) * 0.5
        if self.contraction == "none":
            valid = (u >= 0).all(-1) & (u <= 1).all(-1)
        else:
            valid = torch.isfinite(u).all(-1)
        u = torch.nan_to_num(u, nan=0.5).clamp(0.0, 1.0)
        if self.observed.numel():
            r = self.observed.shape[0]
            idx = (u * r).long().clamp_(0, r - 1)
            valid = valid & self.observed[idx[:, 0], idx[:, 1], idx[:, 2]]
        return u, valid

    def cell_centers(self, resolution: int) -> Tensor:
        """``[R, R, R, 3]`` normalised scene points at the centres of an R³ lattice of grid space
        (uncontracted; ``inf`` for cells the contraction never reaches, the cube's corners with ``l2``)."""
        g = (torch.arange(resolution, dtype=torch.float64) + 0.5) / resolution * 2.0 - 1.0
        c = torch.stack(torch.meshgrid(g, g, g, indexing="ij"), -1) * self.extent
        return torch.from_numpy(uncontract(c.numpy(), self.contraction))

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # The lattice's size is data, not architecture: take the checkpoint's (older checkpoints have none).
        key = prefix + "observed"
        if key in state_dict:
            self.observed = state_dict[key].to(torch.bool).clone()
        else:
            state_dict[key] = self.observed
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)


class ProposalGrid(nn.Module):
    """A density-only dense grid for proposal sampling (trained by the inter-level distillation loss)."""

    def __init__(self, resolution: int, density_bias: float = -1.0):
        super().__init__()
        self.grid = DenseGrid((resolution,), channels=1, init_std=0.1)
        self.density_bias = density_bias

    def forward(self, u: Tensor, valid: Tensor) -> Tensor:
        """``u``: ``[N, 3]`` in ``[0, 1]`` → σ ``[N]``."""
        raw = self.grid(u)[:, 0]
        return density_activation(raw + self.density_bias) * valid


class PanopticField(nn.Module):
    """The paper's model S.

    Parameters
    ----------
    cfg : FieldConfig
        With ``num_semantic_classes``, ``grid_max_resolution`` and ``contraction`` already resolved.

    Examples
    --------
    >>> import torch
    >>> cfg = FieldConfig(grid_max_resolution=32, grid_min_resolution=8, num_semantic_classes=4,
    ...                   num_instance_channels=3, contraction="none", head_hidden_dim=16)
    >>> field = PanopticField(cfg)
    >>> sigma, geo, u = field.geometry(torch.zeros(5, 3))
    >>> sem, inst = field.labels(u, geo)
    >>> sigma.shape, field.color(geo, torch.nn.functional.normalize(torch.ones(5, 3))).shape, sem.shape, inst.shape
    (torch.Size([5]), torch.Size([5, 3]), torch.Size([5, 4]), torch.Size([5, 3]))
    """

    def __init__(self, cfg: FieldConfig):
        super().__init__()
        if cfg.num_semantic_classes < 2:
            raise ValueError("num_semantic_classes must be resolved (>= 2, void included) before building the field")
        self.cfg = cfg
        self.space = SceneSpace(cfg.contraction)
        res = default_resolutions(cfg.grid_max_resolution, cfg.grid_levels, min(cfg.grid_min_resolution, cfg.grid_max_resolution))
        self.grid = DenseGrid(res, cfg.grid_channels)
        geo_in = self.grid.out_dim + positional_encoding_dim(3, cfg.position_frequencies, include_input=True)
        self.density_mlp = make_mlp(geo_in, cfg.density_hidden_dim, 1 + cfg.geo_feat_dim, 1)
        self.color_mlp = make_mlp(cfg.geo_feat_dim + (cfg.sh_degree + 1) ** 2, cfg.color_hidden_dim, 3, cfg.color_layers)
        self.understanding_grid = DenseGrid(tuple(cfg.understanding_resolutions), cfg.understanding_channels, init_std=0.1)
        head_in = (
            self.understanding_grid.out_dim
            + positional_encoding_dim(3, cfg.head_position_frequencies, include_input=True)
            + (cfg.geo_feat_dim if cfg.head_uses_geometry else 0)
        )
        self.semantic_mlp = make_mlp(head_in, cfg.head_hidden_dim, cfg.num_semantic_classes, cfg.head_layers)
        self.instance_mlp = (
            make_mlp(head_in, cfg.head_hidden_dim, cfg.num_instance_channels, cfg.head_layers)
            if cfg.num_instance_channels > 0
            else None
        )

    @property
    def grids(self) -> list[DenseGrid]:
        """The voxel grids regularised by L_tv."""
        return [self.grid, self.understanding_grid]

    def geometry(self, x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Density and geometry features.

        Parameters
        ----------
        x : Tensor
            ``[N, 3]`` normalised scene points.

        Returns
        -------
        sigma : Tensor
            ``[N]`` density (≥ 0; 0 outside a bounded scene).
        geo_feat : Tensor
            ``[N, geo_feat_dim]`` features for the colour (and label) decoders.
        u : Tensor
            ``[N, 3]`` grid coordinates in ``[0, 1]`` (reused by :meth:`labels`).
        """
        u, valid = self.space(x)
        feats = self.grid(u)
        h = torch.cat([feats, positional_encoding(u * 2 - 1, self.cfg.position_frequencies)], dim=-1)
        out = self.density_mlp(h)
        # The first channel of every grid level adds to the raw density directly (as a DVGO/Plenoxels
        # density grid would): surfaces form within a few hundred steps instead of waiting for the
        # decoder's output layer to grow.
        direct = feats[:, :: self.cfg.grid_channels].sum(-1)
        sigma = density_activation(out[:, 0] + direct + self.cfg.density_bias) * valid
        return sigma, out[:, 1:], u

    def color(self, geo_feat: Tensor, dirs: Tensor) -> Tensor:
        """``geo_feat`` ``[N, F]``, unit ``dirs`` ``[N, 3]`` → rgb ``[N, 3]`` in ``[0, 1]``."""
        h = torch.cat([geo_feat, spherical_harmonics(dirs, self.cfg.sh_degree)], dim=-1)
        return torch.sigmoid(self.color_mlp(h))

    def labels(self, u: Tensor, geo_feat: Tensor) -> tuple[Tensor, Tensor | None]:
        """Semantic logits ``[N, U]`` and instance logits ``[N, V]`` (None without thing classes)."""
        parts = [self.understanding_grid(u), positional_encoding(u * 2 - 1, self.cfg.head_position_frequencies)]
        if self.cfg.head_uses_geometry:
            parts.append(geo_feat.detach())
        h = torch.cat(parts, dim=-1)
        inst = self.instance_mlp(h) if self.instance_mlp is not None else None
        return self.semantic_mlp(h), inst


class MLPField(nn.Module):
    """A plain NeRF MLP with semantic and instance branches (Semantic-NeRF style): the ablation's Base.

    Same interface as :class:`PanopticField`.
    """

    def __init__(self, cfg: FieldConfig):
        super().__init__()
        self.cfg = cfg
        self.space = SceneSpace(cfg.contraction)
        pe = positional_encoding_dim(3, cfg.mlp_frequencies)
        self.trunk = make_mlp(pe, cfg.mlp_width, cfg.mlp_width, cfg.mlp_depth - 1)
        self.sigma_out = nn.Linear(cfg.mlp_width, 1 + cfg.geo_feat_dim)
        self.color_mlp = make_mlp(cfg.geo_feat_dim + (cfg.sh_degree + 1) ** 2, cfg.mlp_width // 2, 3, 1)
        self.semantic_mlp = make_mlp(cfg.mlp_width, cfg.mlp_width // 2, cfg.num_semantic_classes, 1)
        self.instance_mlp = (
            make_mlp(cfg.mlp_width, cfg.mlp_width // 2, cfg.num_instance_channels, 1)
            if cfg.num_instance_channels > 0 else None
        )

    @property
    def grids(self) -> list[DenseGrid]:
        return []

    def geometry(self, x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        u, valid = self.space(x)
        h = F.relu(self.trunk(positional_encoding(u * 2 - 1, self.cfg.mlp_frequencies)))
        out = self.sigma_out(h)
        sigma = density_activation(out[:, 0] + self.cfg.density_bias) * valid
        return sigma, out[:, 1:], u

    def color(self, geo_feat: Tensor, dirs: Tensor) -> Tensor:
        h = torch.cat([geo_feat, spherical_harmonics(dirs, self.cfg.sh_degree)], dim=-1)
        return torch.sigmoid(self.color_mlp(h))

    def labels(self, u: Tensor, geo_feat: Tensor) -> tuple[Tensor, Tensor | None]:
        # The label branches read the trunk at these points (the renderer calls labels on a subset of the
        # samples); without gradient, because labels must not shape geometry.
        with torch.no_grad():
            h = F.relu(self.trunk(positional_encoding(u * 2 - 1, self.cfg.mlp_frequencies)))
        inst = self.instance_mlp(h) if self.instance_mlp is not None else None
        return self.semantic_mlp(h), inst


def build_field(cfg: FieldConfig) -> nn.Module:
    """The field named by ``cfg.kind``."""
    if cfg.kind == "grid":
        return PanopticField(cfg)
    if cfg.kind == "mlp":
        return MLPField(cfg)
    raise ValueError(f"unknown field kind {cfg.kind!r} (grid or mlp)")
