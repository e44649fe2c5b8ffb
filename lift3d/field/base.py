"""What the rest of lift3d may ask of a field: the :class:`Field` interface.

A field answers "what is at a point" — ``(x, d) → (σ, rgb, semantic logits, instance logits)``. The renderer,
the model, the trainer and the export use only what :class:`Field` declares; everything else (grids,
decoders, their sizes) is the kind's own business. A field kind is one module (:mod:`lift3d.field.grid`,
:mod:`lift3d.field.mlp`) holding its config dataclass and its :class:`Field` subclass, registered in
:mod:`lift3d.field.registry`.

Positions enter in normalised scene coordinates (the foreground box is ``[-1, 1]^3``, see
:class:`lift3d.model.normalization.SceneNormalization`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

from torch import Tensor, nn

from lift3d.field.grids import DenseGrid
from lift3d.field.space import SceneSpace


class Field(nn.Module, ABC):
    """A panoptic radiance field.

    Parameters
    ----------
    contraction : str
        ``none`` (bounded scene in ``[-1, 1]^3``), ``linf`` or ``l2`` (unbounded, contracted); the field's
        :attr:`space` maps points to grid coordinates with it.
    """

    space: SceneSpace

    def __init__(self, contraction: str):
        super().__init__()
        self.space = SceneSpace(contraction)

    @abstractmethod
    def geometry(self, x: Tensor, space: tuple[Tensor, Tensor] | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """Density and geometry features.

        Parameters
        ----------
        x : Tensor
            ``[N, 3]`` normalised scene points.
        space : (Tensor, Tensor), optional
            ``self.space(x)`` when the caller has it already (the renderer does): grid coordinates ``[N, 3]``
            and validity ``[N]``.

        Returns
        -------
        sigma : Tensor
            ``[N]`` density (≥ 0; 0 outside a bounded scene and in unobserved space).
        geo_feat : Tensor
            ``[N, F]`` features for :meth:`color` (and :meth:`labels`).
        u : Tensor
            ``[N, 3]`` grid coordinates in ``[0, 1]`` (reused by :meth:`labels`).
        """

    @abstractmethod
    def color(self, geo_feat: Tensor, dirs: Tensor) -> Tensor:
        """``geo_feat`` ``[N, F]``, unit view directions ``dirs`` ``[N, 3]`` → rgb ``[N, 3]`` in ``[0, 1]``."""

    @abstractmethod
    def labels(self, u: Tensor, geo_feat: Tensor) -> tuple[Tensor, Tensor | None]:
        """Semantic logits ``[N, U]`` and instance logits ``[N, V]`` (None without an instance head).

        Labels must not shape geometry: implementations read ``geo_feat`` detached.
        """

    def march(self, u: Tensor, valid: Tensor, deltas: Tensor, max_depth: float) -> tuple[Tensor, Tensor] | None:
        """An optional fused path for rendering without gradients: density and geometry features at the
        samples of a batch of rays, taken in order along each ray, only where ``valid``, until the ray's
        optical depth ``Σ σΔt`` reaches ``max_depth`` (early ray termination).

        Parameters
        ----------
        u : Tensor
            ``[R·S, 3]`` grid coordinates of the samples (ray-major, from :attr:`space`).
        valid : Tensor
            ``[R, S]`` bool, the field may have density there.
        deltas : Tensor
            ``[R, S]`` interval lengths.
        max_depth : float
            Optical depth at which a ray stops (``inf``: never).

        Returns
        -------
        (sigma, geo_feat) or None
            ``[R, S]`` densities and ``[R·S, F]`` features, 0 at the samples not evaluated; None when the field
            has no such path here (the renderer then evaluates :meth:`geometry` block by block:
            :func:`lift3d.render.renderer.geometry_where_needed`). None by default.
        """
        return None

    def composite_color(self, geo_feat: Tensor, dirs: Tensor, sample: Tensor, ray_start: Tensor,
                        weight: Tensor) -> Tensor | None:
        """An optional fused path for rendering without gradients: ``Σ w · colour`` over the chosen samples
        of every ray (what :meth:`color`, then a weighted sum per ray, give).

        Parameters
        ----------
        geo_feat : Tensor
            ``[N, F]`` geometry features, a row per sample (as :meth:`march` returns them).
        dirs : Tensor
            ``[R, 3]`` unit view direction of each ray.
        sample : Tensor
            ``[K]`` int64 row of ``geo_feat`` of each chosen sample; ray ``r``'s samples are
            ``sample[ray_start[r]:ray_start[r + 1]]``.
        ray_start : Tensor
            ``[R + 1]`` int64, non-decreasing.
        weight : Tensor
            ``[K]`` rendering weight of each chosen sample.

        Returns
        -------
        Tensor or None
            ``[R, 3]``; None when the field has no such path here (the renderer then decodes and sums with
            torch operators). None by default.
        """
        return None

    def composite_labels(self, u: Tensor, geo_feat: Tensor, sample: Tensor, ray_start: Tensor,
                         weight: Tensor) -> tuple[Tensor, Tensor | None] | None:
        """As :meth:`composite_color` for :meth:`labels`: ``Σ w · semantic logits`` ``[R, U]`` and
        ``Σ w · instance logits`` ``[R, V]`` (None without an instance head) over the chosen samples of every
        ray; ``u`` ``[N, 3]`` grid coordinates, a row per sample like ``geo_feat``. None by default."""
        return None

    @property
    @abstractmethod
    def has_instances(self) -> bool:
        """The field has an instance head (the scene's labels have thing classes)."""

    @property
    def tv_grids(self) -> list[DenseGrid]:
        """The voxel grids the total-variation loss L_tv regularises (none by default)."""
        return []

    def grid_parameters(self) -> list[nn.Parameter]:
        """Parameters trained with the grid learning rate (``optim.lr_grid``): every dense grid's."""
        return [p for m in self.modules() if isinstance(m, DenseGrid) for p in m.parameters()]

    def set_training_progress(self, progress: float) -> None:
        """Called before every training step with the fraction of training done (in ``[0, 1]``), e.g. to
        switch on finer grid levels one by one. Nothing by default."""

    @property
    def finest_resolution(self) -> int:
        """Cells per axis of the finest lattice the field resolves (the export contours its isosurface at
        least this finely); 0 when it has no lattice (e.g. a plain MLP)."""
        return 0
