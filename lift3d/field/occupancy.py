"""Which cells of grid space hold density: the occupancy grid, kept from the field's own density.

As in instant-NGP, a coarse lattice over the field's grid space (``[0, 1]^3``, contracted for unbounded
scenes) remembers, per cell, the largest density the field has shown there recently: every few training
steps the field's density is evaluated at one random point in every cell, and the cell keeps
``max(decay · old, new)``. A cell is *empty* when light crossing it would lose less than a small fraction
of its intensity, i.e. when ``σ_max · L < threshold`` for the cell's length ``L`` in normalised units (the
optical depth across the cell; cells of contracted space are long).

The field gives zero density in empty cells (:class:`lift3d.field.space.SceneSpace`), and the renderer does
not evaluate the field there at all: rays skip empty space. It is a buffer of the model, saved with every
checkpoint and loaded with the run (:func:`lift3d.model.run.load_run` builds it for checkpoints written
before it existed).
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Iterator

import torch
from torch import Tensor, nn


def uncontract_torch(c: Tensor, kind: str) -> Tensor:
    """Inverse scene contraction in torch (see :func:`lift3d.field.encodings.uncontract`): contracted points
    ``[..., 3]`` (norm < 2) → normalised points."""
    if kind == "none":
        return c
    if kind == "linf":
        n = c.abs().amax(-1, keepdim=True)
    elif kind == "l2":
        n = c.norm(dim=-1, keepdim=True)
    else:
        raise ValueError(f"unknown contraction {kind!r}")
    far = 1.0 / ((2.0 - n).clamp_min(1e-6) * n.clamp_min(1e-12))
    return c * torch.where(n <= 1.0, torch.ones_like(n), far)


class OccupancyGrid(nn.Module):
    """A boolean lattice over grid space (``[R, R, R]``, index order x, y, z) of the cells that hold density.

    Parameters
    ----------
    contraction : str
        The field's contraction (``none``, ``linf``, ``l2``): how grid space maps to normalised space.

    Examples
    --------
    >>> import torch
    >>> occ = OccupancyGrid("none")
    >>> occ.update(lambda x: (x[:, 0] > 0.5).float() * 100.0, resolution=8, threshold=0.01)
    >>> occ.lookup(torch.tensor([[0.1, 0.5, 0.5], [0.9, 0.5, 0.5]])).tolist(), occ.fraction_occupied
    ([False, True], 0.25)
    """

    def __init__(self, contraction: str):
        super().__init__()
        self.contraction = contraction
        self.extent = 1.0 if contraction == "none" else 2.0
        # Empty tensors = not built yet: every cell counts as occupied.
        self.register_buffer("cell_density", torch.zeros(0))
        self.register_buffer("occupied", torch.ones(0, 0, 0, dtype=torch.bool))
        self.register_buffer("_cell_length", torch.zeros(0), persistent=False)
        self.updates = 0
        self._suspended = False

    @property
    def built(self) -> bool:
        """The grid holds measured cells (it was updated at least once, or loaded)."""
        return self.occupied.numel() > 0

    @property
    def resolution(self) -> int:
        return int(self.occupied.shape[0])

    @property
    def fraction_occupied(self) -> float:
        """Share of the cells that hold density (1.0 before the grid is built)."""
        return float(self.occupied.float().mean()) if self.built else 1.0

    def applies(self) -> bool:
        """The grid is built and not suspended (see :meth:`suspended`)."""
        return self.built and not self._suspended

    @contextmanager
    def suspended(self) -> Iterator[None]:
        """Within this block every cell counts as occupied (e.g. while measuring the field to update the grid)."""
        before, self._suspended = self._suspended, True
        try:
            yield
        finally:
            self._suspended = before

    def lookup(self, u: Tensor) -> Tensor:
        """``u``: ``[N, 3]`` grid coordinates in ``[0, 1]`` → ``[N]`` bool, the point's cell is occupied."""
        if not self.built:
            return torch.ones(u.shape[0], dtype=torch.bool, device=u.device)
        r = self.resolution
        idx = (u * r).long().clamp_(0, r - 1)
        flat = (idx[:, 0] * r + idx[:, 1]) * r + idx[:, 2]
        return self.occupied.reshape(-1).index_select(0, flat)

    def cell_length(self, resolution: int, device: torch.device) -> Tensor:
        """``[R^3]`` length of each cell in normalised units (its longest side; the cell side for bounded
        scenes, stretched by the inverse contraction in unbounded ones)."""
        if self._cell_length.numel() == resolution**3 and self._cell_length.device == device:
            return self._cell_length
        side = 2.0 * self.extent / resolution
        if self.contraction == "none":
            length = torch.full((resolution**3,), side, device=device)
        else:
            c = self._cell_centres(resolution, device) * self.extent
            lengths = []
            for axis in range(3):
                step = torch.zeros(3, device=device)
                step[axis] = 0.5 * side
                lo = uncontract_torch((c - step).clamp(-1.999, 1.999), self.contraction)
                hi = uncontract_torch((c + step).clamp(-1.999, 1.999), self.contraction)
                lengths.append((hi - lo).norm(dim=-1))
            length = torch.stack(lengths).amax(0)
        self._cell_length = length
        return length

    @staticmethod
    def _cell_centres(resolution: int, device: torch.device) -> Tensor:  # (used for the cell lengths)
        """``[R^3, 3]`` cell centres in ``[-1, 1]^3`` (flat index ``(i R + j) R + k`` over x, y, z)."""
        g = (torch.arange(resolution, device=device, dtype=torch.float32) + 0.5) / resolution * 2.0 - 1.0
        return torch.stack(torch.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)

    @torch.no_grad()
    def update(self, density: Callable[[Tensor], Tensor], *, resolution: int, threshold: float,
               decay: float = 0.95, generator: torch.Generator | None = None, subdivide: int = 1,
               chunk: int = 65536) -> None:
        """Measure the field once more and mark the cells.

        Parameters
        ----------
        density : callable
            Normalised points ``[N, 3]`` → density ``[N]`` (the field's, with this grid suspended).
        resolution : int
            Cells per axis (a change of resolution starts the grid afresh).
        threshold : float
            A cell is empty when ``σ_max · L`` (optical depth across it) is below this.
        decay : float
            Per update, the remembered density decays by this factor unless measured again.
        generator : torch.Generator, optional
            Where in each cell (or sub-cell) the density is measured (uniform); the centre without one.
        subdivide : int
            Measure at the centres of ``subdivide³`` sub-cells of every cell and keep the largest: a surface
            thinner than a cell is then not missed by a single measurement (building a grid at once, e.g.
            for a checkpoint without one; during training, updates at random points accumulate instead).
        chunk : int
            Points per density call.
        """
        device = self.occupied.device
        r = int(resolution)
        if self.cell_density.numel() != r**3:
            self.cell_density = torch.zeros(r**3, device=device)
        fine = r * max(1, int(subdivide))
        measured = torch.empty(fine**3, device=device)
        with self.suspended():
            # Cells in the order of the fields' grid tables (x fastest): consecutive measurements then read
            # neighbouring table rows (z fastest made every lookup a cache miss: 2.5x slower on a 128^3 grid).
            # (The random offsets are drawn in cell order, x slowest, as they always were.)
            offsets = None if generator is None else \
                torch.rand(fine**3, 3, generator=generator, device=generator.device).to(device)
            for s in range(0, fine**3, chunk):
                idx = torch.arange(s, min(s + chunk, fine**3), device=device)
                x, y, z = idx % fine, (idx // fine) % fine, idx // (fine * fine)
                g = torch.stack([x, y, z], -1).float()
                g = g + (0.5 if offsets is None else offsets.index_select(0, (x * fine + y) * fine + z))
                c = ((g / fine * 2.0 - 1.0) * self.extent).clamp(-self.extent * 0.9995, self.extent * 0.9995)
                measured[s:s + len(idx)] = density(uncontract_torch(c, self.contraction)).float()
        # Back to the cell index (x * fine + y) * fine + z of `occupied`.
        measured = torch.nan_to_num(measured, nan=0.0).view(fine, fine, fine).permute(2, 1, 0).reshape(-1)
        if fine != r:
            measured = torch.nn.functional.max_pool3d(measured.view(1, 1, fine, fine, fine), subdivide).reshape(-1)
        self.cell_density = torch.maximum(self.cell_density * decay, measured)
        tau = self.cell_density * self.cell_length(r, device)
        self.occupied = (tau >= threshold).reshape(r, r, r)
        self.updates += 1

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # The grid's size is data, not architecture: take the checkpoint's (older checkpoints have none).
        for key, empty in (("occupied", self.occupied), ("cell_density", self.cell_density)):
            full = prefix + key
            if full in state_dict:
                value = state_dict[full]
                # On this module's device (the checkpoint may have been mapped elsewhere), as a copy.
                setattr(self, key, value.to(device=empty.device, dtype=torch.bool if key == "occupied"
                                            else torch.float32, copy=True))
            else:
                state_dict[full] = empty
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)


@dataclass
class OccupancyConfig:
    """The occupancy grid kept from the field's density (instant-NGP's): rays skip its empty cells."""

    resolution: int = 64
    """Cells per axis over the field's grid space; 0 = no occupancy grid."""
    threshold: float = 0.01
    """A cell is empty when the optical depth across it (its largest recent density × its length) is below
    this: light crossing it would lose under 1 % of its intensity. The field gives zero density there."""
    update_every: int = 16
    """Training steps between two updates of the grid from the field's density."""
    start: int = 256
    """Training steps before the first update (the untrained field is opaque everywhere)."""
    decay: float = 0.95
    """Per update, a cell's remembered density decays by this factor unless measured again."""
    in_training: bool = False
    """Training renders also skip empty cells (zero density there; the grid always applies when rendering,
    evaluating and exporting). Off by default: what it does to accuracy in training is not measured yet
    (docs/presets.md)."""
