"""Coordinate and direction encodings: scene contraction, positional encoding, spherical harmonics."""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from lift3d.field import native


def contract(x: Tensor, kind: str = "linf") -> Tensor:
    """Scene contraction of mip-NeRF 360: the unit ball stays, the rest of space folds into radius 2.

    Parameters
    ----------
    x : Tensor
        ``[..., 3]`` points in normalised scene coordinates (foreground box ≈ ``[-1, 1]^3``).
    kind : {"linf", "l2", "none"}
        ``l2``: mip-NeRF 360's ``(2 - 1/|x|) x/|x|`` (a ball of radius 2). ``linf``: the same radial formula with
        the max-norm, so contracted space fills the cube ``[-2, 2]^3`` (no grid cells wasted in the cube's
        corners; rays through the origin stay straight). ``none``: identity (bounded scenes).

    Returns
    -------
    Tensor
        ``[..., 3]`` contracted points; finite and with finite gradients for any finite input
        (including 0 and 1e6).

    Examples
    --------
    >>> import torch
    >>> contract(torch.tensor([[0.5, 0.0, 0.0], [4.0, 0.0, 0.0]])).tolist()
    [[0.5, 0.0, 0.0], [1.75, 0.0, 0.0]]
    """
    if kind == "none":
        return x
    if kind == "l2":
        n = x.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        scale = torch.where(n <= 1.0, torch.ones_like(n), (2.0 - 1.0 / n) / n)
        return x * scale
    if kind == "linf":
        n = x.abs().amax(dim=-1, keepdim=True).clamp_min(1e-12)
        scale = torch.where(n <= 1.0, torch.ones_like(n), (2.0 - 1.0 / n) / n)
        return x * scale
    raise ValueError(f"unknown contraction {kind!r}")


def uncontract(g: np.ndarray, kind: str) -> np.ndarray:
    """Inverse of :func:`contract` (numpy, float64): contracted points → normalised points.

    Points on or beyond the contracted boundary (radius 2) map to ``inf``.

    Examples
    --------
    >>> import numpy as np
    >>> uncontract(np.array([[0.5, 0.0, 0.0], [1.75, 0.0, 0.0]]), "linf").tolist()
    [[0.5, 0.0, 0.0], [4.0, 0.0, 0.0]]
    """
    g = np.asarray(g, np.float64)
    if kind == "none":
        return g
    if kind == "linf":
        n = np.abs(g).max(-1, keepdims=True)
    elif kind == "l2":
        n = np.linalg.norm(g, axis=-1, keepdims=True)
    else:
        raise ValueError(f"unknown contraction {kind!r}")
    with np.errstate(divide="ignore", invalid="ignore"):
        # contract: c = x (2 - 1/m) / m with m = |x|  ⇒  |c| = 2 - 1/m  ⇒  m = 1 / (2 - |c|),  x = c m / |c|.
        far = np.where(n >= 2.0, np.inf, 1.0 / (2.0 - n)) / np.maximum(n, 1e-12)
        scale = np.where(n <= 1.0, 1.0, far)
        return g * scale


def positional_encoding(x: Tensor, num_frequencies: int, include_input: bool = True) -> Tensor:
    """NeRF's sinusoidal encoding ``[x, sin(2^k π x), cos(2^k π x)]``, ``k < num_frequencies``.

    ``[N, D]`` → ``[N, D (include_input + 2 num_frequencies)]``.
    """
    if num_frequencies == 0:
        return x if include_input else x[..., :0]
    freqs = (2.0 ** torch.arange(num_frequencies, device=x.device, dtype=x.dtype)) * math.pi
    xb = (x[..., None, :] * freqs[:, None]).flatten(-2)  # [N, F*D]
    parts = [x] if include_input else []
    parts += [torch.sin(xb), torch.cos(xb)]
    return torch.cat(parts, dim=-1)


def positional_encoding_dim(in_dim: int, num_frequencies: int, include_input: bool = True) -> int:
    return in_dim * (int(include_input) + 2 * num_frequencies)


# Real spherical-harmonic constants (orthonormal basis, as used by Plenoxels / 3D Gaussian splatting).
_C0 = 0.28209479177387814
_C1 = 0.4886025119029199
_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
       1.445305721320277, -0.5900435899266435)


def spherical_harmonics(d: Tensor, degree: int) -> Tensor:
    """Real SH basis of unit directions up to ``degree`` (0–3): ``[N, 3]`` → ``[N, (degree+1)^2]``.

    Not differentiable w.r.t. ``d`` on the CPU path of :mod:`lift3d.field.native` (view directions are data).
    """
    if not 0 <= degree <= 3:
        raise ValueError("spherical harmonics degree must be 0..3")
    ext = native.usable(d) if not d.requires_grad else None
    if ext is not None and d.dim() == 2 and d.shape[1] == 3:
        out = d.new_empty(d.shape[0], (degree + 1) ** 2)
        ext.sh_forward(d.contiguous(), degree, out, 0)
        return out
    return spherical_harmonics_torch(d, degree)


def spherical_harmonics_torch(d: Tensor, degree: int) -> Tensor:
    """The pure-torch :func:`spherical_harmonics` (the reference for the C++ path)."""
    if not 0 <= degree <= 3:
        raise ValueError("spherical harmonics degree must be 0..3")
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    out = [torch.full_like(x, _C0)]
    if degree >= 1:
        out += [-_C1 * y, _C1 * z, -_C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [_C2[0] * xy, _C2[1] * yz, _C2[2] * (2 * zz - xx - yy), _C2[3] * xz, _C2[4] * (xx - yy)]
    if degree >= 3:
        out += [
            _C3[0] * y * (3 * xx - yy),
            _C3[1] * xy * z,
            _C3[2] * y * (4 * zz - xx - yy),
            _C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            _C3[4] * x * (4 * zz - xx - yy),
            _C3[5] * z * (xx - yy),
            _C3[6] * x * (xx - 3 * yy),
        ]
    return torch.stack(out, dim=-1)
