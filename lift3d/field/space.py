"""Where a field lives: normalised scene points → grid coordinates ``[0, 1]^3`` (with the scene contraction)."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from lift3d.field import native
from lift3d.field.encodings import contract, uncontract
from lift3d.field.occupancy import OccupancyGrid


class SceneSpace(nn.Module):
    """Maps normalised scene points to grid coordinates ``[0, 1]^3`` (contracting unbounded space).

    Bounded scenes use the box ``[-1, 1]^3``; points outside it are flagged invalid (zero density), and so are
    points outside :attr:`box` when one is set (:meth:`set_box`: a room's own box, which the normalised cube
    around it exceeds along its shorter sides).
    Unbounded scenes contract all of space into ``[-2, 2]^3``; every finite point is valid. Points in cells
    no training camera sees (:attr:`observed`) and, once it is built, in cells the occupancy grid marks
    empty (:attr:`occupancy`, :mod:`lift3d.field.occupancy`) are invalid too. In training the occupancy
    grid applies only when :attr:`occupancy_in_training` is set.
    """

    def __init__(self, contraction: str):
        super().__init__()
        self.contraction = contraction
        self.extent = 1.0 if contraction == "none" else 2.0
        # [R, R, R] bool over grid coordinates (index order x, y, z); empty = every cell observed.
        self.register_buffer("observed", torch.ones(0, 0, 0, dtype=torch.bool))
        self.occupancy = OccupancyGrid(contraction)
        self.occupancy_in_training = False
        # [2, 3] normalised lower and upper corner of the box the scene lives in; empty = the whole cube. Set from
        # the run's config (not saved in checkpoints: the config is).
        self.register_buffer("box", torch.zeros(0, 3), persistent=False)

    def set_box(self, lower, upper) -> None:
        """Points outside the axis-aligned box ``[lower, upper]`` (normalised coordinates, bounded scenes only)
        have no density, and rays start and stop at it (:meth:`ray_bounds`)."""
        if self.contraction != "none":
            raise ValueError("SceneSpace.set_box: only a bounded scene (contraction 'none') has a box")
        box = torch.tensor([list(lower), list(upper)], dtype=torch.float32, device=self.box.device)
        if box.shape != (2, 3) or not bool(torch.isfinite(box).all()) or not bool((box[0] < box[1]).all()):
            raise ValueError(f"SceneSpace.set_box: need lower < upper, 3 finite values each; got {box.tolist()}")
        self.box = box

    def ray_bounds(self) -> tuple:
        """``(lower, upper)`` of the box rays of a bounded scene start and stop at: :attr:`box`, else the cube
        ``(-1.0, 1.0)``."""
        if self.box.numel():
            return self.box[0], self.box[1]
        return -1.0, 1.0

    #: Contraction codes of the C++ kernels (lift3d/field/csrc/native.cpp).
    CONTRACTION_CODES = {"none": 0, "linf": 1, "l2": 2}

    def masks(self) -> tuple[Tensor, Tensor]:
        """The lattices that zero density now: ``observed`` and the occupancy grid's ``occupied`` (an empty
        tensor when it does not apply, e.g. in training without ``occupancy_in_training``)."""
        applies = self.occupancy.applies() and (self.occupancy_in_training or not self.training)
        occupied = self.occupancy.occupied if applies else self.observed.new_zeros(0, 0, 0)
        return self.observed, occupied

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """``x``: ``[N, 3]`` → ``u`` ``[N, 3]`` in ``[0, 1]``, ``valid`` ``[N]`` bool."""
        ext = native.usable(x)
        if ext is not None and x.dim() == 2:
            observed, occupied = self.masks()
            x = x.detach().contiguous()
            u = torch.empty_like(x)
            valid = torch.empty(x.shape[0], dtype=torch.bool)
            ext.space_forward(x, self.CONTRACTION_CODES[self.contraction], self.extent, observed, occupied, u, valid)
            return u, self._in_box(x, valid)
        return self.forward_torch(x)

    def clamp_to_box(self, x: Tensor, reach: float = float("inf")) -> Tensor:
        """``x`` ``[..., 3]`` within ``reach`` (∞-norm) of :attr:`box` moved onto its nearest point in the box;
        farther points stay (outside: no density). Unchanged without a box."""
        if not self.box.numel():
            return x
        inside = torch.minimum(torch.maximum(x, self.box[0].to(x.dtype)), self.box[1].to(x.dtype))
        near = (x - inside).abs().amax(-1, keepdim=True) <= reach
        return torch.where(near, inside, x)

    def _in_box(self, x: Tensor, valid: Tensor) -> Tensor:
        if not self.box.numel():
            return valid
        return valid & (x >= self.box[0]).all(-1) & (x <= self.box[1]).all(-1)

    def forward_torch(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """The pure-torch :meth:`forward` (the reference for the C++ path)."""
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
            valid = valid & self.observed.reshape(-1).index_select(0, (idx[:, 0] * r + idx[:, 1]) * r + idx[:, 2])
        occupied = self.masks()[1]
        if occupied.numel():
            valid = valid & self.occupancy.lookup(u)
        return u, self._in_box(x, valid)

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
