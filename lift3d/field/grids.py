"""Dense voxel feature grids with a CPU-friendly trilinear lookup.

Measured on 2-core CPUs: 3-D ``F.grid_sample`` and ``F.embedding``'s backward are several
times slower than gathering the 8 corners with ``index_select`` from a channels-last table and scattering
the backward with ``index_add_``. :func:`grid_lookup` does exactly that; :func:`grid_lookup_reference`
is the plain ``grid_sample`` version the tests compare it against. On the CPU, :meth:`DenseGrid.encode`
does all levels (and the positional encoding) in one C++ pass when the kernels of
:mod:`lift3d.field.native` are available, with :func:`grid_lookup` as the fallback.

Coordinates are in ``[0, 1]^3``; voxel *corners* (nodes) sit at ``i / (R - 1)``. Points outside are
clamped to the border.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lift3d.field import native
from lift3d.field.encodings import positional_encoding, positional_encoding_dim

# Corner offsets of a voxel (x fastest), used to build the 8 gather indices.
_CORNERS = torch.tensor([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=torch.long)


def trilinear_corners(u: Tensor, resolution: int) -> tuple[Tensor, Tensor]:
    """Flat node indices and trilinear weights of the 8 corners around each point.

    Parameters
    ----------
    u : Tensor
        ``[N, 3]`` coordinates in ``[0, 1]`` (clamped).
    resolution : int
        Nodes per axis ``R`` (≥ 2).

    Returns
    -------
    idx : Tensor
        ``[N, 8]`` int64 indices into a table of ``R^3`` nodes laid out ``x + R (y + R z)``.
    w : Tensor
        ``[N, 8]`` weights (sum to 1), same dtype as ``u``.
    """
    r = resolution
    p = u.clamp(0.0, 1.0) * (r - 1)
    i0 = p.floor().clamp_(0, r - 2)
    f = p - i0  # [N, 3] in [0, 1]
    i0 = i0.long()
    base = i0[:, 0] + r * (i0[:, 1] + r * i0[:, 2])  # [N]
    offs = torch.tensor([0, 1, r, r + 1, r * r, r * r + 1, r * r + r, r * r + r + 1], device=u.device)
    idx = base[:, None] + offs[None, :]
    fx, fy, fz = f[:, 0:1], f[:, 1:2], f[:, 2:3]
    gx, gy, gz = 1 - fx, 1 - fy, 1 - fz
    w = torch.cat(
        [gx * gy * gz, fx * gy * gz, gx * fy * gz, fx * fy * gz, gx * gy * fz, fx * gy * fz, gx * fy * fz, fx * fy * fz],
        dim=1,
    )
    return idx, w


#: When True, the backward of :func:`grid_lookup` adds straight into ``table.grad`` (kept allocated between
#: steps; zero it with ``zero_grad(set_to_none=False)``) instead of returning a fresh grid-sized gradient:
#: allocating a 34 MB zero tensor each step cost 14–22 ms in page faults on CPU, the in-place add ~0.
#: DDP needs gradients to flow through autograd's accumulation hooks, so distributed training turns it off.
ACCUMULATE_GRAD_IN_PLACE = True


def _scatter_grad(table: Tensor, idx: Tensor, rows: Tensor) -> Tensor | None:
    """Gradient of a row gather: ``rows`` added at ``idx``. In place into ``table.grad`` (returning None)
    when :data:`ACCUMULATE_GRAD_IN_PLACE`, else as a new grid-sized tensor."""
    if ACCUMULATE_GRAD_IN_PLACE and table.is_leaf:
        if table.grad is None:
            table.grad = torch.zeros_like(table)
        table.grad.index_add_(0, idx, rows.to(table.grad.dtype))
        return None
    return torch.zeros_like(table, dtype=rows.dtype).index_add_(0, idx, rows)


class _GatherTrilinear(torch.autograd.Function):
    """out[n] = Σ_k w[n, k] · table[idx[n, k]]; backward scatters with ``index_add_`` (no grad for idx/w)."""

    @staticmethod
    def forward(ctx, table: Tensor, idx: Tensor, w: Tensor) -> Tensor:  # type: ignore[override]
        n, c = idx.shape[0], table.shape[1]
        corners = table.index_select(0, idx.reshape(-1)).view(n, 8, c)
        out = torch.bmm(w.view(n, 1, 8), corners).view(n, c)
        ctx.save_for_backward(idx, w)
        ctx.table = table
        return out

    @staticmethod
    def backward(ctx, grad_out: Tensor):  # type: ignore[override]
        idx, w = ctx.saved_tensors
        table = ctx.table
        n, c = grad_out.shape
        # Outer product per point; a broadcast multiply is ~3x faster than bmm of 8x1 by 1xC matrices.
        contrib = (w.unsqueeze(-1) * grad_out.unsqueeze(1)).view(n * 8, c)
        return _scatter_grad(table, idx.reshape(-1), contrib), None, None


class _GatherRows(torch.autograd.Function):
    """``table[idx]`` whose backward adds into ``table.grad`` in place (see ACCUMULATE_GRAD_IN_PLACE)."""

    @staticmethod
    def forward(ctx, table: Tensor, idx: Tensor) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(idx)
        ctx.table = table
        return table.index_select(0, idx)

    @staticmethod
    def backward(ctx, grad_out: Tensor):  # type: ignore[override]
        (idx,) = ctx.saved_tensors
        return _scatter_grad(ctx.table, idx, grad_out), None


def _gradient_buffers(tables: tuple[Tensor, ...]) -> tuple[list[Tensor], list[bool]]:
    """Where a C++ backward adds each table's gradient: ``table.grad`` itself (allocated once, kept) when
    :data:`ACCUMULATE_GRAD_IN_PLACE`, else a fresh zero tensor for autograd; and which of the two it is."""
    in_place = [ACCUMULATE_GRAD_IN_PLACE and t.is_leaf for t in tables]
    grads = []
    for t, inplace in zip(tables, in_place):
        if inplace and t.grad is None:
            t.grad = torch.zeros_like(t)
        grads.append(t.grad if inplace else torch.zeros_like(t))
    return grads, in_place


def _returned(grads: list[Tensor], in_place: list[bool]) -> tuple[Tensor | None, ...]:
    """What a backward returns for the tables: None for the gradients it added in place."""
    return tuple(None if inplace else g for g, inplace in zip(grads, in_place))


def _native_encode(ext, u: Tensor, resolutions: tuple[int, ...], channels: int, pe: int,
                   tables: tuple[Tensor, ...]) -> Tensor:
    """``[grid features of every level | positional encoding]`` by the C++ kernels; levels beyond
    ``len(tables)`` (inactive) are zeros."""
    grid_dim = len(resolutions) * channels
    out = u.new_empty(u.shape[0], grid_dim + (positional_encoding_dim(3, pe) if pe >= 0 else 0))
    ext.grid_forward(u, [t.detach() for t in tables], list(resolutions[: len(tables)]), out, 0)
    if len(tables) < len(resolutions):
        out[:, len(tables) * channels:grid_dim].zero_()
    if pe >= 0:
        ext.positional_forward(u, pe, out, grid_dim)
    return out


class _NativeEncode(torch.autograd.Function):
    """:func:`_native_encode` with the C++ backward (in place into ``table.grad``, see ACCUMULATE_GRAD_IN_PLACE)."""

    @staticmethod
    def forward(ctx, u: Tensor, resolutions: tuple[int, ...], channels: int, pe: int,  # type: ignore[override]
                *tables: Tensor) -> Tensor:
        ext = native.load()
        ctx.save_for_backward(u)
        ctx.tables, ctx.resolutions = tables, resolutions
        return _native_encode(ext, u, resolutions, channels, pe, tables)

    @staticmethod
    def backward(ctx, grad_out: Tensor):  # type: ignore[override]
        (u,) = ctx.saved_tensors
        grad_out = grad_out if grad_out.stride(-1) == 1 else grad_out.contiguous()
        grads, in_place = _gradient_buffers(ctx.tables)
        native.load().grid_backward(u, grad_out, 0, grads, list(ctx.resolutions[: len(ctx.tables)]))
        return (None, None, None, None) + _returned(grads, in_place)


def gather_rows(table: Tensor, idx: Tensor) -> Tensor:
    """Rows ``table[idx]`` (``[N, C]``), differentiable w.r.t. ``table`` without a grid-sized temporary."""
    if not table.requires_grad:
        return table.index_select(0, idx)
    return _GatherRows.apply(table, idx)


def grid_lookup(table: Tensor, resolution: int, u: Tensor) -> Tensor:
    """Trilinear lookup in a dense channels-last grid.

    Parameters
    ----------
    table : Tensor
        ``[R^3, C]`` node features, layout ``x + R (y + R z)``.
    resolution : int
        ``R``.
    u : Tensor
        ``[N, 3]`` coordinates in ``[0, 1]``.

    Returns
    -------
    Tensor
        ``[N, C]`` interpolated features (differentiable w.r.t. ``table`` only).
    """
    idx, w = trilinear_corners(u.detach(), resolution)
    if not table.requires_grad:
        n = idx.shape[0]
        return torch.bmm(w.view(n, 1, 8), table.index_select(0, idx.reshape(-1)).view(n, 8, -1)).view(n, -1)
    return _GatherTrilinear.apply(table, idx, w.to(table.dtype))


def grid_lookup_reference(table: Tensor, resolution: int, u: Tensor) -> Tensor:
    """Plain ``F.grid_sample`` version of :func:`grid_lookup` (slow on CPU; used in tests)."""
    r = resolution
    vol = table.t().reshape(1, -1, r, r, r)  # [1, C, D(z), H(y), W(x)]
    g = (u.clamp(0, 1) * 2 - 1).view(1, -1, 1, 1, 3)  # grid_sample wants (x, y, z) in [-1, 1]
    out = F.grid_sample(vol, g, mode="bilinear", align_corners=True, padding_mode="border")
    return out.view(table.shape[1], -1).t()


class DenseGrid(nn.Module):
    """Multi-resolution dense feature grids (one channels-last table per level).

    Parameters
    ----------
    resolutions : sequence of int
        Nodes per axis of each level, coarse to fine (e.g. ``(32, 64, 128)``).
    channels : int
        Features per node and level; the output has ``len(resolutions) * channels`` features.
    init_std : float
        Standard deviation of the initial features.

    Examples
    --------
    >>> import torch
    >>> grid = DenseGrid((4, 8), channels=2)
    >>> grid(torch.rand(5, 3)).shape
    torch.Size([5, 4])
    """

    def __init__(self, resolutions: tuple[int, ...], channels: int, init_std: float = 1e-2):
        super().__init__()
        self.resolutions = tuple(int(r) for r in resolutions)
        self.channels = int(channels)
        self.tables = nn.ParameterList(
            [nn.Parameter(torch.randn(r**3, channels) * init_std) for r in self.resolutions]
        )
        # Levels beyond this count output zeros (coarse-to-fine training; all levels by default).
        self.active_levels = len(self.resolutions)

    @property
    def out_dim(self) -> int:
        return len(self.resolutions) * self.channels

    @property
    def num_params(self) -> int:
        return sum(t.numel() for t in self.tables)

    def forward(self, u: Tensor) -> Tensor:
        """``u``: ``[N, 3]`` in ``[0, 1]`` → ``[N, levels · channels]`` (zeros for inactive fine levels)."""
        return self.encode(u)

    def encode(self, u: Tensor, position_frequencies: int | None = None) -> Tensor:
        """Grid features, then (with ``position_frequencies``) the positional encoding of ``2u - 1``.

        ``u``: ``[N, 3]`` in ``[0, 1]`` → ``[N, levels · channels (+ 3 (1 + 2 F))]``, the decoder input in
        one matrix. Differentiable w.r.t. the tables only. Uses the C++ kernels on the CPU when available
        (:mod:`lift3d.field.native`), else :meth:`encode_torch`.
        """
        u = u.detach()
        ext = native.usable(u, self.tables[0])
        if ext is None:
            return self.encode_torch(u, position_frequencies)
        u = u.contiguous()
        tables = tuple(self.tables[: self.active_levels])
        pe = -1 if position_frequencies is None else int(position_frequencies)
        if torch.is_grad_enabled() and any(t.requires_grad for t in tables):
            return _NativeEncode.apply(u, self.resolutions, self.channels, pe, *tables)
        return _native_encode(ext, u, self.resolutions, self.channels, pe, tables)

    def encode_torch(self, u: Tensor, position_frequencies: int | None = None) -> Tensor:
        """The pure-torch :meth:`encode` (:func:`grid_lookup` per level; the reference for the C++ path)."""
        out = [grid_lookup(t, r, u) for t, r in zip(self.tables[: self.active_levels], self.resolutions)]
        missing = len(self.resolutions) - len(out)
        if missing:
            out.append(u.new_zeros(u.shape[0], missing * self.channels))
        if position_frequencies is not None:
            out.append(positional_encoding(u * 2 - 1, position_frequencies))
        return torch.cat(out, dim=-1)

    def total_variation(self, num_samples: int, generator: torch.Generator | None = None) -> Tensor:
        """Mean L2 norm of feature differences between neighbouring nodes (L_tv), on a random subset of
        ``num_samples`` nodes per level and axis (a full-grid TV would allocate grid-sized temporaries
        every step). On the CPU one C++ pass (:mod:`lift3d.field.native`; its backward adds into the tables'
        gradients in place), else :meth:`total_variation_torch` on the same node pairs."""
        pairs = []  # per level [3, n]: node b and its neighbour b + stride along x, y, z
        for table, r in zip(self.tables, self.resolutions):
            dev = table.device
            n = min(num_samples, r**3)
            base = torch.randint(0, r**3, (3, n), generator=generator, device=dev)
            strides = torch.tensor([[1], [r], [r * r]], device=dev)
            # Keep neighbours inside the grid along each axis.
            pairs.append(torch.where((base // strides) % r == r - 1, base - strides, base))
        ext = native.usable(*self.tables)
        if ext is None:
            return self.total_variation_torch(pairs)
        if torch.is_grad_enabled() and any(t.requires_grad for t in self.tables):
            return _NativeTotalVariation.apply(tuple(pairs), self.resolutions, *self.tables).mean()
        means = self.tables[0].new_empty(3 * len(self.tables))
        ext.tv_forward([t.detach() for t in self.tables], pairs, list(self.resolutions), means)
        return means.mean()

    def total_variation_torch(self, pairs: list[Tensor]) -> Tensor:
        """The pure-torch L_tv on given node pairs (``[3, n]`` per level; the reference for the C++ path;
        the gathers use :func:`gather_rows`, whose backward adds in place)."""
        terms = []
        for table, r, base in zip(self.tables, self.resolutions, pairs):
            for axis, stride in enumerate((1, r, r * r)):
                d = gather_rows(table, base[axis] + stride) - gather_rows(table, base[axis])
                terms.append(torch.sqrt((d * d).sum(-1) + 1e-12).mean())
        return torch.stack(terms).mean()


class _NativeTotalVariation(torch.autograd.Function):
    """Per level and axis, the mean TV of :meth:`DenseGrid.total_variation` by the C++ kernels (``[levels · 3]``);
    the backward adds into the tables' gradients in place (see ACCUMULATE_GRAD_IN_PLACE)."""

    @staticmethod
    def forward(ctx, pairs: tuple[Tensor, ...], resolutions: tuple[int, ...], *tables: Tensor) -> Tensor:  # type: ignore[override]
        means = tables[0].new_empty(3 * len(tables))
        native.load().tv_forward([t.detach() for t in tables], list(pairs), list(resolutions), means)
        ctx.pairs, ctx.resolutions, ctx.tables = pairs, resolutions, tables
        return means

    @staticmethod
    def backward(ctx, grad_means: Tensor):  # type: ignore[override]
        grads, in_place = _gradient_buffers(ctx.tables)
        native.load().tv_backward([t.detach() for t in ctx.tables], list(ctx.pairs), list(ctx.resolutions),
                                  grad_means.contiguous(), grads)
        return (None, None) + _returned(grads, in_place)


def default_resolutions(max_resolution: int, levels: int, min_resolution: int = 16) -> tuple[int, ...]:
    """Geometric progression of resolutions from ``min_resolution`` to ``max_resolution``.

    Examples
    --------
    >>> default_resolutions(128, 3, 32)
    (32, 64, 128)
    """
    if levels == 1:
        return (int(max_resolution),)
    g = math.exp((math.log(max_resolution) - math.log(min_resolution)) / (levels - 1))
    return tuple(int(round(min_resolution * g**i)) for i in range(levels))
