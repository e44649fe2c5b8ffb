"""The C++ kernels of lift3d.field.native agree with the pure-torch path they replace, and lift3d falls back
to that path (with a one-line warning) when they cannot be built."""

from __future__ import annotations

import warnings

import pytest
import torch

from lift3d.field import native
from lift3d.field.encodings import spherical_harmonics, spherical_harmonics_torch
from lift3d.field.grids import DenseGrid
from lift3d.field.layers import make_mlp, run_mlp
from lift3d.field.space import SceneSpace
from lift3d.model.panoptic import _tiny_model

needs_kernels = pytest.mark.skipif(native.load() is None, reason="the C++ kernels could not be built here")


@pytest.fixture
def torch_path(monkeypatch):
    """A context in which lift3d uses the pure-torch path (as with LIFT3D_NATIVE=0)."""
    def switch():
        monkeypatch.setenv("LIFT3D_NATIVE", "0")
        assert native.usable(torch.zeros(1)) is None
    return switch


def _points(n: int, seed: int, scale: float = 1.0) -> torch.Tensor:
    return (torch.rand(n, 3, generator=torch.Generator().manual_seed(seed)) * 2 - 1) * scale


@needs_kernels
@pytest.mark.parametrize("contraction", ["none", "linf", "l2"])
def test_space_mapping_and_masks_match(contraction):
    space = SceneSpace(contraction).eval()
    g = torch.Generator().manual_seed(1)
    space.observed = torch.rand(8, 8, 8, generator=g) > 0.3
    space.occupancy.update(lambda x: (x[:, 0] > 0.2).float() * 50, resolution=6, threshold=0.01)
    x = _points(4000, 2, scale=3.0)
    u, valid = space(x)
    u_ref, valid_ref = space.forward_torch(x)
    assert torch.allclose(u, u_ref, atol=1e-6)
    assert torch.equal(valid, valid_ref) and 0 < int(valid.sum()) < len(x)


@needs_kernels
@pytest.mark.parametrize("active", [3, 2])
def test_grid_encoding_forward_and_backward_match(active):
    grid = DenseGrid((5, 9, 17), 2)
    grid.active_levels = active
    u = torch.rand(3000, 3, generator=torch.Generator().manual_seed(3)) * 1.1 - 0.05  # some outside: clamped
    out = grid.encode(u, 4)
    ref = grid.encode_torch(u, 4)
    assert out.shape == ref.shape
    assert torch.allclose(out, ref, atol=1e-5)
    weight = torch.randn(out.shape, generator=torch.Generator().manual_seed(4))
    grads = []
    for encode in (grid.encode, grid.encode_torch):
        for t in grid.tables:
            t.grad = None
        (encode(u, 4) * weight).sum().backward()
        grads.append([t.grad.clone() if t.grad is not None else torch.zeros_like(t) for t in grid.tables])
    for a, b in zip(*grads):
        assert torch.allclose(a, b, atol=1e-4)


@needs_kernels
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_spherical_harmonics_match(degree):
    d = _points(500, 5)
    d = d / d.norm(dim=-1, keepdim=True)
    assert torch.allclose(spherical_harmonics(d, degree), spherical_harmonics_torch(d, degree), atol=1e-6)


@needs_kernels
@pytest.mark.parametrize("shape", [(19, 64, 17, 2), (3, 5, 3, 1), (40, 33, 65, 3)])
def test_fused_mlp_matches_torch(shape):
    in_dim, hidden, out_dim, layers = shape
    torch.manual_seed(6)
    mlp = make_mlp(in_dim, hidden, out_dim, layers)
    x = torch.randn(1003, in_dim)  # not a multiple of the kernel's row block
    with torch.no_grad():
        assert torch.allclose(run_mlp(mlp, x), mlp(x), atol=1e-4)
        assert run_mlp(mlp, x[:0]).shape == (0, out_dim)
    assert run_mlp(mlp, x).requires_grad  # with autograd: torch's own layers


@needs_kernels
def test_rendering_matches_the_torch_path(torch_path):
    model = _tiny_model()
    with torch.no_grad():  # structure in the grids, so that the proposals and the occupancy have work to do
        for grid in (model.field.grid, *(p.grid for p in model.proposals)):
            for t in grid.tables:
                t.normal_(0, 2.0, generator=torch.Generator().manual_seed(t.numel()))
    model.update_occupancy(subdivide=1)
    o = _points(300, 7, scale=0.5)
    d = _points(300, 8)
    d = d / d.norm(dim=-1, keepdim=True)
    with torch.no_grad():
        fast = model.render(o, d)
        torch_path()
        ref = model.render(o, d)
    for a, b in ((fast.rgb, ref.rgb), (fast.depth, ref.depth), (fast.opacity, ref.opacity),
                 (fast.semantic, ref.semantic), (fast.instance, ref.instance)):
        assert torch.allclose(a, b, atol=1e-3, rtol=1e-3), (a - b).abs().max()


def test_without_a_compiler_lift3d_warns_once_and_uses_torch(monkeypatch):
    from torch.utils import cpp_extension

    def no_compiler(*args, **kwargs):
        raise RuntimeError("Error building extension: g++: command not found")

    monkeypatch.setattr(cpp_extension, "load", no_compiler)
    monkeypatch.setattr(native, "_module", None)
    monkeypatch.setattr(native, "_failed", None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert native.load() is None and native.load() is None
        grid = DenseGrid((5, 9), 2)
        u = torch.rand(10, 3)
        assert torch.allclose(grid.encode(u), grid.encode_torch(u))
    notes = [str(w.message) for w in caught if "C++" in str(w.message)]
    assert len(notes) == 1 and "\n" not in notes[0] and "pure-torch" in notes[0]


def test_the_same_source_from_two_checkouts_builds_from_one_path(monkeypatch, tmp_path):
    # The build records its sources' paths: two clones or worktrees of lift3d alternating would rebuild the
    # kernels (9-12 s) on every switch if each compiled its own file.
    from torch.utils import cpp_extension

    seen = []
    monkeypatch.setattr(cpp_extension, "load", lambda **kw: seen.append((kw["sources"], kw["build_directory"])))
    monkeypatch.setenv("LIFT3D_CACHE_DIR", str(tmp_path / "cache"))
    text = native._SOURCE.read_bytes()
    for checkout in ("a", "b"):
        src = tmp_path / checkout / "native.cpp"
        src.parent.mkdir()
        src.write_bytes(text)
        monkeypatch.setattr(native, "_SOURCE", src)
        monkeypatch.setattr(native, "_module", None)
        monkeypatch.setattr(native, "_failed", None)
        native.load()
    assert len(seen) == 2 and seen[0] == seen[1]
    (source,), build = seen[0]
    assert source.startswith(build) and open(source, "rb").read() == text
