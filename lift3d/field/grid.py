"""Field kind ``grid``: the paper's model S.

Multi-resolution voxel feature grids over the (contracted) scene feed a density decoder and a
view-dependent colour decoder (spherical harmonics of the direction); a separate small *understanding
grid* feeds a semantic and an instance decoder. Labels never shape geometry: the geometry features the
label decoders may read are detached. Settings: ``field.grid.*`` (:class:`GridFieldConfig`) besides the
shared ``field.*`` ones (:class:`lift3d.field.registry.FieldConfig`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import torch
from torch import Tensor

from lift3d.field import native
from lift3d.field.base import Field
from lift3d.field.encodings import positional_encoding_dim, spherical_harmonics
from lift3d.field.grids import DenseGrid, default_resolutions
from lift3d.field.layers import density_activation, make_mlp, run_mlp

if TYPE_CHECKING:  # the registry imports this module
    from lift3d.field.registry import FieldConfig


@dataclass
class GridFieldConfig:
    """Voxel grids and decoders of the ``grid`` field (the paper's model S)."""

    levels: int = 3
    """Resolution levels of the geometry/appearance grid."""
    min_resolution: int = 32
    """Nodes per axis of the coarsest level."""
    max_resolution: int = 0
    """Nodes per axis of the finest level; 0 = from scene extent and image size (capped by the preset)."""
    resolution_cap: int = 128
    """Upper bound for the derived finest resolution (CPU grids beyond ~10 M parameters get slow)."""
    channels: int = 4
    """Features per node and level."""
    coarse_to_fine: float = 0.0
    """Fraction of the training steps over which the finer grid levels are switched on one by one (0 = all
    from the start). Coarse voxels are seen by many views, so geometry forms consistently before fine
    levels can fit per-view fog near the cameras."""
    position_frequencies: int = 2
    """Low-frequency positional encoding of the contracted position added to the grid features."""
    density_hidden_dim: int = 64
    """Width of the density (geometry) decoder."""
    color_hidden_dim: int = 64
    """Width of the colour (appearance) decoder."""
    color_layers: int = 2
    """Hidden layers of the colour decoder."""
    understanding_resolutions: tuple[int, ...] = (16,)
    """Resolutions of the understanding grid (paper: a single 16³ level)."""
    understanding_channels: int = 1
    """Features per node of the understanding grid (paper: 1)."""
    understanding_fine_resolution: int = 0
    """A finer last level of the understanding grid, added after ``understanding_resolutions`` when finer
    than them: 0 = from the sizes of the thing segments the labels show (``understanding_cells_per_thing``
    cells across the small things, capped by ``understanding_memory_mb``); -1 = none (only the listed
    levels, as the paper's single 16³ level)."""
    understanding_cells_per_thing: float = 2.0
    """Cells of the derived finest understanding level across a small thing (the 10th percentile of the
    thing segments' sizes)."""
    understanding_memory_mb: float = 4.0
    """Parameter memory (MiB) the derived finest understanding level may take (Adam keeps three more
    copies); caps its resolution (4 MiB: 64³ × 4 channels). Every million grid parameters costs training
    time in the optimiser and the gradient buffers: see docs/presets.md."""
    head_hidden_dim: int = 256
    """Width of the semantic and instance decoders (paper: 256)."""
    head_layers: int = 2
    """Hidden layers of the semantic and instance decoders."""
    head_position_frequencies: int = 4
    """Positional-encoding frequencies of the contracted position fed to the label decoders."""
    head_uses_geometry: bool = True
    """Feed the (detached) geometry features to the label decoders: sharp label boundaries at object edges
    without letting labels carve geometry."""

    def derive_sizes(self, resolution_for: Callable[[int, int], tuple[int, str]]) -> dict[str, str]:
        """Fill ``max_resolution`` from the scene when it is 0.

        ``resolution_for(cap, minimum)`` is the resolution the scene's pixel footprint asks for and why
        (:func:`lift3d.model.normalization.derive_grid_resolution`). Returns the reason for config.yml.
        """
        if self.max_resolution > 0:
            return {}
        self.max_resolution, why = resolution_for(self.resolution_cap, self.min_resolution)
        return {"why_grid_resolution": why}

    @property
    def understanding_levels(self) -> tuple[int, ...]:
        """The understanding grid's levels: the listed ones, then the finest when it is finer."""
        levels = tuple(int(r) for r in self.understanding_resolutions)
        if self.understanding_fine_resolution > max(levels, default=0):
            levels += (int(self.understanding_fine_resolution),)
        return levels

    def derive_label_sizes(self, label_resolution_for: Callable[..., tuple[int, str]]) -> dict[str, str]:
        """Fill ``understanding_fine_resolution`` from the labels when it is 0.

        ``label_resolution_for(channels=, budget_mb=, cells_per_thing=, minimum=)`` is the resolution the
        thing segments ask for and why (:func:`lift3d.train.scene_sizes.label_resolution`). Returns the
        reason for config.yml.
        """
        if self.understanding_fine_resolution != 0:
            return {}
        res, why = label_resolution_for(channels=self.understanding_channels, budget_mb=self.understanding_memory_mb,
                                        cells_per_thing=self.understanding_cells_per_thing,
                                        minimum=max(self.understanding_resolutions, default=1))
        self.understanding_fine_resolution = res
        return {"why_label_resolution": why}


class GridField(Field):
    """The paper's model S (field kind ``grid``).

    Parameters
    ----------
    cfg : FieldConfig
        With ``num_semantic_classes``, ``grid.max_resolution`` and ``contraction`` already resolved.

    Examples
    --------
    >>> import torch
    >>> from lift3d.field.registry import FieldConfig
    >>> cfg = FieldConfig(num_semantic_classes=4, num_instance_channels=3, contraction="none",
    ...                   grid=GridFieldConfig(max_resolution=32, min_resolution=8, head_hidden_dim=16))
    >>> field = GridField(cfg)
    >>> sigma, geo, u = field.geometry(torch.zeros(5, 3))
    >>> sem, inst = field.labels(u, geo)
    >>> sigma.shape, field.color(geo, torch.nn.functional.normalize(torch.ones(5, 3))).shape, sem.shape, inst.shape
    (torch.Size([5]), torch.Size([5, 3]), torch.Size([5, 4]), torch.Size([5, 3]))
    """

    def __init__(self, cfg: FieldConfig):
        super().__init__(cfg.contraction)
        if cfg.num_semantic_classes < 2:
            raise ValueError("num_semantic_classes must be resolved (>= 2, void included) before building the field")
        g = cfg.grid
        self.cfg = cfg
        res = default_resolutions(g.max_resolution, g.levels, min(g.min_resolution, g.max_resolution))
        self.grid = DenseGrid(res, g.channels)
        geo_in = self.grid.out_dim + positional_encoding_dim(3, g.position_frequencies, include_input=True)
        self.density_mlp = make_mlp(geo_in, g.density_hidden_dim, 1 + cfg.geo_feat_dim, 1)
        direct = torch.zeros(geo_in)
        direct[: self.grid.out_dim : g.channels] = 1.0
        self.register_buffer("direct_columns", direct, persistent=False)
        self.color_mlp = make_mlp(cfg.geo_feat_dim + (cfg.sh_degree + 1) ** 2, g.color_hidden_dim, 3, g.color_layers)
        self.understanding_grid = DenseGrid(g.understanding_levels, g.understanding_channels, init_std=0.1)
        head_in = (
            self.understanding_grid.out_dim
            + positional_encoding_dim(3, g.head_position_frequencies, include_input=True)
            + (cfg.geo_feat_dim if g.head_uses_geometry else 0)
        )
        self.semantic_mlp = make_mlp(head_in, g.head_hidden_dim, cfg.num_semantic_classes, g.head_layers)
        self.instance_mlp = (
            make_mlp(head_in, g.head_hidden_dim, cfg.num_instance_channels, g.head_layers)
            if cfg.num_instance_channels > 0
            else None
        )

    @property
    def has_instances(self) -> bool:
        return self.instance_mlp is not None

    @property
    def tv_grids(self) -> list[DenseGrid]:
        return [self.grid, self.understanding_grid]

    @property
    def finest_resolution(self) -> int:
        return int(self.grid.resolutions[-1])

    def set_training_progress(self, progress: float) -> None:
        """Coarse-to-fine: level ``l`` switches on at ``l/(L-1)`` of the first ``grid.coarse_to_fine`` of
        training."""
        levels = len(self.grid.resolutions)
        frac = self.cfg.grid.coarse_to_fine
        if frac <= 0 or levels == 1:
            self.grid.active_levels = levels
            return
        self.grid.active_levels = int(min(levels, 1 + math.floor(progress / frac * (levels - 1))))

    def geometry(self, x: Tensor, space: tuple[Tensor, Tensor] | None = None) -> tuple[Tensor, Tensor, Tensor]:
        u, valid = self.space(x) if space is None else space
        # [grid features | positional encoding]: the density decoder's input in one matrix.
        h = self.grid.encode(u, self.cfg.grid.position_frequencies)
        out = run_mlp(self.density_mlp, h, grad_columns=self.grid.out_dim)  # (no gradient for the encoding)
        # The first channel of every grid level adds to the raw density directly (as a DVGO/Plenoxels
        # density grid would): surfaces form within a few hundred steps instead of waiting for the
        # decoder's output layer to grow.
        direct = h @ self.direct_columns  # Σ over levels of channel 0 (a strided .sum() is several times slower)
        sigma = density_activation(out[:, 0] + direct + self.cfg.density_bias) * valid
        return sigma, out[:, 1:], u

    def _computes(self, *methods: str) -> bool:
        """These methods are GridField's own (not replaced on the instance or in a subclass): only then do the
        fused paths below compute what they would."""
        return all(m not in self.__dict__ and getattr(type(self), m) is getattr(GridField, m) for m in methods)

    def march(self, u: Tensor, valid: Tensor, deltas: Tensor, max_depth: float) -> tuple[Tensor, Tensor] | None:
        """:meth:`Field.march` by the C++ kernels (CPU, float32, no gradients, :meth:`geometry` not replaced;
        None otherwise)."""
        tables = list(self.grid.tables[: self.grid.active_levels])
        if torch.is_grad_enabled() or not tables or not self._computes("geometry"):
            return None
        ext = native.usable(u, deltas, tables[0])
        if ext is None:
            return None
        linear = [m for m in self.density_mlp if isinstance(m, torch.nn.Linear)]
        sigma = torch.empty_like(deltas)
        geo = u.new_empty(u.shape[0], linear[-1].out_features - 1)
        ext.march_density(u.contiguous(), valid.contiguous(), deltas.contiguous(), [t.detach() for t in tables],
                          list(self.grid.resolutions[: len(tables)]), len(self.grid.resolutions),
                          self.cfg.grid.position_frequencies, [m.weight.detach() for m in linear],
                          [m.bias.detach() for m in linear], float(self.cfg.density_bias), float(max_depth), sigma, geo)
        return sigma, geo

    def composite_color(self, geo_feat: Tensor, dirs: Tensor, sample: Tensor, ray_start: Tensor,
                        weight: Tensor) -> Tensor | None:
        """:meth:`Field.composite_color` by the C++ kernels (CPU, float32, no gradients, :meth:`color` not
        replaced; None otherwise)."""
        ext = None if torch.is_grad_enabled() or not self._computes("color") else native.usable(geo_feat, dirs, weight)
        if ext is None:
            return None
        out = geo_feat.new_empty(dirs.shape[0], 3)
        linear = [m for m in self.color_mlp if isinstance(m, torch.nn.Linear)]
        ext.decode_composite(ray_start, sample.contiguous(), weight.contiguous(), geo_feat.new_empty(0, 3), geo_feat,
                             dirs.contiguous(), 0, self.cfg.sh_degree, [], [], 0, 0,
                             [m.weight.detach() for m in linear], [m.bias.detach() for m in linear], [len(linear)],
                             True, [out])
        return out

    def composite_labels(self, u: Tensor, geo_feat: Tensor, sample: Tensor, ray_start: Tensor,
                         weight: Tensor) -> tuple[Tensor, Tensor | None] | None:
        """:meth:`Field.composite_labels` by the C++ kernels (CPU, float32, no gradients, the label decoders
        reading the geometry features, :meth:`labels` not replaced; None otherwise)."""
        g = self.cfg.grid
        tables = list(self.understanding_grid.tables[: self.understanding_grid.active_levels])
        fusable = not torch.is_grad_enabled() and g.head_uses_geometry and tables and self._computes("labels")
        ext = native.usable(u, geo_feat, weight, tables[0]) if fusable else None
        if ext is None:
            return None
        heads = [self.semantic_mlp] + ([self.instance_mlp] if self.instance_mlp is not None else [])
        linear = [[m for m in head if isinstance(m, torch.nn.Linear)] for head in heads]
        outs = [u.new_empty(ray_start.shape[0] - 1, layers[-1].out_features) for layers in linear]
        ext.decode_composite(ray_start, sample.contiguous(), weight.contiguous(), u.contiguous(), geo_feat,
                             u.new_empty(0, 3), 1, 0, [t.detach() for t in tables],
                             list(self.understanding_grid.resolutions[: len(tables)]),
                             len(self.understanding_grid.resolutions), g.head_position_frequencies,
                             [m.weight.detach() for layers in linear for m in layers],
                             [m.bias.detach() for layers in linear for m in layers], [len(layers) for layers in linear],
                             False, outs)
        return outs[0], (outs[1] if len(outs) > 1 else None)

    def color(self, geo_feat: Tensor, dirs: Tensor) -> Tensor:
        h = torch.cat([geo_feat, spherical_harmonics(dirs, self.cfg.sh_degree)], dim=-1)
        return torch.sigmoid(run_mlp(self.color_mlp, h, grad_columns=geo_feat.shape[1]))

    def labels(self, u: Tensor, geo_feat: Tensor) -> tuple[Tensor, Tensor | None]:
        g = self.cfg.grid
        parts = [self.understanding_grid.encode(u, g.head_position_frequencies)]
        if g.head_uses_geometry:
            parts.append(geo_feat.detach())
        h = torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0]
        cols = self.understanding_grid.out_dim  # the rest (encoding, detached geometry) needs no gradient
        inst = run_mlp(self.instance_mlp, h, grad_columns=cols) if self.instance_mlp is not None else None
        return run_mlp(self.semantic_mlp, h, grad_columns=cols), inst
