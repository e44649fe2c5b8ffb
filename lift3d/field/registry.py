"""Field kinds: kind name → (config dataclass, :class:`~lift3d.field.base.Field` subclass), and the ``field``
section of the run configuration.

Adding a field kind: write one module (its config dataclass with a ``derive_sizes`` method, and its
:class:`~lift3d.field.base.Field` subclass), then register it here — an entry in :data:`FIELD_KINDS` and
its settings section in :class:`FieldConfig` (``field.<kind>.*`` in config.yml and on the command line).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from dataclasses import field as dc_field
from typing import Any, NamedTuple

from lift3d.field.base import Field
from lift3d.field.grid import GridField, GridFieldConfig
from lift3d.field.mlp import MLPField, MLPFieldConfig
from lift3d.field.occupancy import OccupancyConfig


class FieldKind(NamedTuple):
    """A registered field kind."""

    config: type
    field: type[Field]


#: Every field kind ``field.kind`` may name.
FIELD_KINDS: dict[str, FieldKind] = {
    "grid": FieldKind(GridFieldConfig, GridField),
    "mlp": FieldKind(MLPFieldConfig, MLPField),
}


@dataclass
class FieldConfig:
    """Settings every field kind shares; each kind's own are in ``field.<kind>`` (``field.grid``, ...).

    Zero-valued sizes are derived from the scene (written to config.yml)."""

    kind: str = "grid"
    """``grid``: the paper's model S (voxel grids, ``field.grid.*``); ``mlp``: a plain NeRF MLP (the ablation's
    Base, ``field.mlp.*``)."""
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
    geo_feat_dim: int = 15
    """Geometry features passed from the density decoder to the colour decoder."""
    sh_degree: int = 3
    """Spherical-harmonic degree of the view-direction encoding (0–3)."""
    observed_resolution: int = 64
    """Cells of an R³ lattice over the grid's space that no training camera sees get zero density (as
    instant-NGP marks untrained cells): space behind every camera gets no gradient, keeps its opaque initial
    density and would fog novel views and the export. 0 disables."""
    clip_to_scene_box: bool = True
    """Bounded scenes with a ``scene_box`` in transforms.json: the lattice of observed cells zeroes the cells
    outside that box, and when training frames lack depth maps the field has no density outside the box at all
    and rays start and stop at it, not at the normalised cube around it (padded and cubic: a 7 × 5 × 2.45 m
    room's cube reaches 2.4 m above its ceiling). With whole cells only, an images-only room's ceiling rose into
    the cells the box cuts (exported up to 11 cm above the box). With a depth map in every training frame the
    rays keep the cube: there the box cost F-score 0.001-0.005 and point mIoU 0.001-0.007 (the benchmark notes,
    docs/notes/2026-11-29-benchmark-history.md, "Rays that stop at the room's box").
    The choice goes to ``config.yml`` (``scene.render_box``). Turn off when the declared box is too tight."""
    scene_box_pad: float = 0.005
    """With ``clip_to_scene_box``: how far the field's box reaches past the ``scene_box``, as a share of its
    diagonal. A wall on the box's face needs room behind it to become opaque."""
    occupancy: OccupancyConfig = dc_field(default_factory=OccupancyConfig)
    grid: GridFieldConfig = dc_field(default_factory=GridFieldConfig)
    mlp: MLPFieldConfig = dc_field(default_factory=MLPFieldConfig)

    @property
    def kind_config(self) -> Any:
        """The settings section of :attr:`kind` (e.g. ``self.grid``)."""
        field_kind(self.kind)
        return getattr(self, self.kind)


def field_kind(kind: str) -> FieldKind:
    """The registry entry of ``kind``; an unknown kind is a ValueError naming the known ones."""
    if kind not in FIELD_KINDS:
        raise ValueError(f"unknown field kind {kind!r} (known: {', '.join(FIELD_KINDS)})")
    return FIELD_KINDS[kind]


def build_field(cfg: FieldConfig) -> Field:
    """The field ``cfg.kind`` names, built from ``cfg``."""
    field = field_kind(cfg.kind).field(cfg)
    field.space.occupancy_in_training = cfg.occupancy.in_training
    return field


# ------------------------------------------------------------------------------------------ old layout
#: Settings that config.yml / checkpoints written before the per-kind sections held flat under ``field``.
_FLAT_KEYS: dict[str, tuple[str, str]] = {
    **{f"grid_{k}": ("grid", k) for k in ("levels", "min_resolution", "max_resolution", "resolution_cap", "channels")},
    **{k: ("grid", k) for k in ("coarse_to_fine", "position_frequencies", "density_hidden_dim", "color_hidden_dim",
                                "color_layers", "understanding_resolutions", "understanding_channels",
                                "head_hidden_dim", "head_layers", "head_position_frequencies", "head_uses_geometry")},
    **{f"mlp_{k}": ("mlp", k) for k in ("width", "depth", "frequencies")},
}


def upgrade_field_settings(values: dict) -> dict:
    """``field`` settings in the current layout: keys of the old flat layout (``grid_levels``,
    ``head_hidden_dim``, ``mlp_width``, ...) move into their kind's section; everything else is kept.

    Examples
    --------
    >>> upgrade_field_settings({"kind": "grid", "grid_levels": 2, "mlp_width": 64, "grid": {"channels": 2}})
    {'kind': 'grid', 'grid': {'channels': 2, 'levels': 2}, 'mlp': {'width': 64}}
    """
    if not isinstance(values, dict):
        return values
    out: dict = {}
    moved: dict[str, dict] = {}
    for key, val in values.items():
        if key in _FLAT_KEYS:
            section, name = _FLAT_KEYS[key]
            moved.setdefault(section, {})[name] = val
        else:
            out[key] = val
    for section, vals in moved.items():
        current = out.get(section)
        out[section] = {**(current if isinstance(current, dict) else {}), **vals}
    return out


def _check_registry() -> None:
    """Every registered kind has its settings section in :class:`FieldConfig` (of its config class)."""
    sections = {f.name: f for f in dataclasses.fields(FieldConfig)}
    for name, kind in FIELD_KINDS.items():
        f = sections.get(name)
        if f is None or f.default_factory is not kind.config:  # type: ignore[comparison-overlap]
            raise TypeError(f"field kind {name!r}: FieldConfig needs `{name}: {kind.config.__name__}`")


_check_registry()
