"""Building blocks the field kinds share: the density activation, small MLPs, proposal density grids."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from lift3d.field import native
from lift3d.field.grids import DenseGrid


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


def run_mlp(mlp: nn.Sequential, x: Tensor) -> Tensor:
    """``mlp(x)`` for an MLP of :func:`make_mlp`; without autograd on the CPU, one fused C++ pass
    (:mod:`lift3d.field.native`: about twice MKL's speed on these narrow layers, and no temporaries)."""
    if torch.is_grad_enabled() and any(p.requires_grad for p in mlp.parameters()):
        return mlp(x)
    ext = native.usable(x)
    if ext is None:
        return mlp(x)
    linear = [m for m in mlp if isinstance(m, nn.Linear)]
    x = x if x.stride(-1) == 1 else x.contiguous()
    out = x.new_empty(x.shape[0], linear[-1].out_features)
    if x.shape[0]:
        ext.mlp_forward(x, [m.weight.detach() for m in linear], [m.bias.detach() for m in linear], out)
    return out


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
