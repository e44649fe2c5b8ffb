"""Field kind ``mlp``: a plain NeRF MLP with semantic and instance branches (Semantic-NeRF style), the
ablation's Base. Settings: ``field.mlp.*`` (:class:`MLPFieldConfig`) besides the shared ``field.*`` ones."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lift3d.field.base import Field
from lift3d.field.encodings import positional_encoding, positional_encoding_dim, spherical_harmonics
from lift3d.field.layers import density_activation, make_mlp, run_mlp

if TYPE_CHECKING:  # the registry imports this module
    from lift3d.field.registry import FieldConfig


@dataclass
class MLPFieldConfig:
    """The plain NeRF MLP of the ``mlp`` field (the ablation's Base)."""

    width: int = 256
    """Trunk width."""
    depth: int = 6
    """Trunk depth."""
    frequencies: int = 8
    """Positional-encoding frequencies of the position."""

    def derive_sizes(self, resolution_for: Callable[[int, int], tuple[int, str]]) -> dict[str, str]:
        """Nothing the scene decides (no lattice)."""
        return {}

    def derive_label_sizes(self, label_resolution_for: Callable[..., tuple[int, str]]) -> dict[str, str]:
        """Nothing: the plain MLP has no understanding grid."""
        return {}


class MLPField(Field):
    """A plain NeRF MLP with semantic and instance branches (field kind ``mlp``).

    Examples
    --------
    >>> import torch
    >>> from lift3d.field.registry import FieldConfig
    >>> field = MLPField(FieldConfig(num_semantic_classes=3, contraction="none", mlp=MLPFieldConfig(width=16, depth=2)))
    >>> sigma, geo, u = field.geometry(torch.zeros(4, 3))
    >>> sigma.shape, field.labels(u, geo)[1] is None, field.finest_resolution
    (torch.Size([4]), True, 0)
    """

    def __init__(self, cfg: FieldConfig):
        super().__init__(cfg.contraction)
        m = cfg.mlp
        self.cfg = cfg
        pe = positional_encoding_dim(3, m.frequencies)
        self.trunk = make_mlp(pe, m.width, m.width, m.depth - 1)
        self.sigma_out = nn.Linear(m.width, 1 + cfg.geo_feat_dim)
        self.color_mlp = make_mlp(cfg.geo_feat_dim + (cfg.sh_degree + 1) ** 2, m.width // 2, 3, 1)
        self.semantic_mlp = make_mlp(m.width, m.width // 2, cfg.num_semantic_classes, 1)
        self.instance_mlp = (
            make_mlp(m.width, m.width // 2, cfg.num_instance_channels, 1)
            if cfg.num_instance_channels > 0 else None
        )

    @property
    def has_instances(self) -> bool:
        return self.instance_mlp is not None

    def geometry(self, x: Tensor, space: tuple[Tensor, Tensor] | None = None) -> tuple[Tensor, Tensor, Tensor]:
        u, valid = self.space(x) if space is None else space
        h = F.relu(run_mlp(self.trunk, positional_encoding(u * 2 - 1, self.cfg.mlp.frequencies)))
        out = self.sigma_out(h)
        sigma = density_activation(out[:, 0] + self.cfg.density_bias) * valid
        return sigma, out[:, 1:], u

    def color(self, geo_feat: Tensor, dirs: Tensor) -> Tensor:
        h = torch.cat([geo_feat, spherical_harmonics(dirs, self.cfg.sh_degree)], dim=-1)
        return torch.sigmoid(run_mlp(self.color_mlp, h))

    def labels(self, u: Tensor, geo_feat: Tensor) -> tuple[Tensor, Tensor | None]:
        # The label branches read the trunk at these points (the renderer calls labels on a subset of the
        # samples); without gradient, because labels must not shape geometry.
        with torch.no_grad():
            h = F.relu(run_mlp(self.trunk, positional_encoding(u * 2 - 1, self.cfg.mlp.frequencies)))
        inst = run_mlp(self.instance_mlp, h) if self.instance_mlp is not None else None
        return run_mlp(self.semantic_mlp, h), inst
