"""The C++ kernels of lift3d.field.native agree with the pure-torch path they replace, and lift3d falls back
to that path (with a one-line warning) when they cannot be built."""

from __future__ import annotations

import math
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
def test_total_variation_and_its_gradient_match():
    grid = DenseGrid((5, 9, 17), 3)
    with torch.no_grad():
        for t in grid.tables:
            t.normal_(generator=torch.Generator().manual_seed(t.numel()))
    results = []
    for path in ("native", "torch"):
        for t in grid.tables:
            t.grad = None
        g = torch.Generator().manual_seed(12)  # the same node pairs for both
        if path == "native":
            tv = grid.total_variation(300, g)
        else:
            pairs = []
            for r in grid.resolutions:
                base = torch.randint(0, r**3, (3, min(300, r**3)), generator=g)
                strides = torch.tensor([[1], [r], [r * r]])
                pairs.append(torch.where((base // strides) % r == r - 1, base - strides, base))
            tv = grid.total_variation_torch(pairs)
        (3.0 * tv).backward()
        results.append((tv.detach(), [t.grad.clone() for t in grid.tables]))
    (tv_a, grads_a), (tv_b, grads_b) = results
    assert torch.allclose(tv_a, tv_b, rtol=1e-5) and float(tv_a) > 0.1
    for a, b in zip(grads_a, grads_b):
        assert torch.allclose(a, b, atol=1e-6)


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
    assert run_mlp(mlp, x).requires_grad  # with autograd: the training kernels (tested below)


@needs_kernels
@pytest.mark.parametrize("shape,rows,cols", [((27, 64, 16, 1), 1003, 12), ((31, 64, 3, 2), 97, 31),
                                             ((54, 33, 22, 2), 5, 0), ((8, 16, 4, 3), 0, 8)])
def test_training_mlp_kernels_match_torch_autograd(shape, rows, cols):
    """Forward, weight/bias gradients and the gradient of the input's first ``cols`` columns (none after)."""
    in_dim, hidden, out_dim, layers = shape
    torch.manual_seed(7)
    mlp = make_mlp(in_dim, hidden, out_dim, layers)
    x = torch.randn(rows, in_dim, requires_grad=cols > 0)
    upstream = torch.randn(rows, out_dim)
    y = run_mlp(mlp, x, grad_columns=cols)
    y.backward(upstream)
    fused = [p.grad.clone() for p in mlp.parameters()]
    for p in mlp.parameters():
        p.grad = None
    x_ref = x.detach().clone().requires_grad_(cols > 0)
    y_ref = mlp(torch.cat([x_ref[:, :cols], x_ref[:, cols:].detach()], 1))
    y_ref.backward(upstream)
    assert torch.allclose(y, y_ref, atol=1e-5)
    for a, b in zip(fused, (p.grad for p in mlp.parameters())):
        assert torch.allclose(a, b, atol=1e-4, rtol=1e-4)
    if cols:
        assert torch.allclose(x.grad, x_ref.grad, atol=1e-5)
        assert x.grad[:, cols:].abs().sum() == 0


@needs_kernels
def test_training_mlp_kernels_are_deterministic_across_thread_counts():
    mlp = make_mlp(27, 64, 16, 1)
    x = torch.randn(5000, 27, generator=torch.Generator().manual_seed(1))
    grads = []
    threads = torch.get_num_threads()
    try:
        for n in (1, 2, 3):
            torch.set_num_threads(n)
            mlp.zero_grad()
            run_mlp(mlp, x).pow(2).sum().backward()
            grads.append([p.grad.clone() for p in mlp.parameters()])
    finally:
        torch.set_num_threads(threads)
    for other in grads[1:]:
        assert all(torch.equal(a, b) for a, b in zip(grads[0], other))


def _marching_inputs(field, n_rays=40, n_samples=24):
    g = torch.Generator().manual_seed(9)
    with torch.no_grad():
        for t in field.grid.tables:
            t.normal_(0, 2.0, generator=g)
    u = torch.rand(n_rays * n_samples, 3, generator=g)
    valid = torch.rand(n_rays, n_samples, generator=g) > 0.2
    deltas = torch.rand(n_rays, n_samples, generator=g) * 0.05
    return u, valid, deltas


@needs_kernels
def test_marching_equals_the_geometry_at_every_valid_sample():
    field = _tiny_model().field
    u, valid, deltas = _marching_inputs(field)
    with torch.no_grad():
        sigma, geo = field.march(u, valid, deltas, float("inf"))  # no termination
        ref_sigma, ref_geo, _ = field.geometry(u, space=(u, valid.reshape(-1)))
    flat = valid.reshape(-1)
    assert torch.allclose(sigma.reshape(-1), ref_sigma, rtol=1e-5, atol=1e-6)
    assert torch.allclose(geo[flat], ref_geo[flat], atol=1e-5)
    assert geo[~flat].abs().sum() == 0


@needs_kernels
def test_marching_stops_a_ray_once_its_transmittance_is_negligible():
    field = _tiny_model().field
    u, valid, deltas = _marching_inputs(field)
    eps = 1e-3
    with torch.no_grad():
        sigma, _ = field.march(u, valid, deltas, -math.log(eps))
        full, _ = field.march(u, valid, deltas, float("inf"))
    skipped = valid & (sigma == 0) & (full > 0)
    assert skipped.any()
    # Every skipped sample lies behind the point where the evaluated samples made the ray opaque ...
    optical_before = torch.cumsum(sigma * deltas, 1) - sigma * deltas
    assert (optical_before[skipped] >= -math.log(eps)).all()
    # ... and skipping changes the rendered weights by less than the threshold.
    from lift3d.render.volume import render_weights
    assert (render_weights(sigma, deltas)[0] - render_weights(full, deltas)[0]).abs().max() < eps
    with torch.enable_grad():
        assert field.march(u, valid, deltas, 1.0) is None  # training takes the differentiable path


@needs_kernels
def test_fused_compositing_equals_decoding_and_summing():
    from lift3d.render.renderer import ray_starts

    model = _tiny_model()
    field = model.field
    u, valid, deltas = _marching_inputs(field, n_rays=30, n_samples=10)
    g = torch.Generator().manual_seed(11)
    with torch.no_grad():
        for t in field.understanding_grid.tables:
            t.normal_(0, 1.0, generator=g)
        _, geo = field.march(u, torch.ones_like(valid), deltas, float("inf"))
        dirs = torch.nn.functional.normalize(torch.randn(30, 3, generator=g), dim=-1)
        sample = torch.sort(torch.randperm(300, generator=g)[:120]).values
        sample = sample[(sample // 10) % 7 != 3]  # some rays choose no sample
        ray = sample // 10
        w = torch.rand(len(sample), generator=g)
        start = ray_starts(ray, 30)
        rgb = field.composite_color(geo, dirs, sample, start, w)
        sem, inst = field.composite_labels(u, geo, sample, start, w)
        rgb_ref = torch.zeros(30, 3).index_add_(0, ray, w[:, None] * field.color(geo[sample], dirs[ray]))
        s_ref, i_ref = field.labels(u[sample], geo[sample])
        sem_ref = torch.zeros(30, s_ref.shape[1]).index_add_(0, ray, w[:, None] * s_ref)
        inst_ref = torch.zeros(30, i_ref.shape[1]).index_add_(0, ray, w[:, None] * i_ref)
    assert torch.allclose(rgb, rgb_ref, atol=1e-5)
    assert torch.allclose(sem, sem_ref, atol=1e-4) and torch.allclose(inst, inst_ref, atol=1e-4)
    assert (rgb[(torch.arange(30) % 7) == 3] == 0).all()


@needs_kernels
def test_fused_compositing_rejects_inconsistent_indices():
    field = _tiny_model().field
    geo, u, dirs, w = torch.zeros(10, 15), torch.rand(10, 3), torch.tensor([[0.0, 0.0, 1.0]] * 2), torch.ones(3)
    with torch.no_grad():
        with pytest.raises(RuntimeError, match="outside geo's rows"):
            field.composite_color(geo, dirs, torch.tensor([0, 1, 10]), torch.tensor([0, 1, 3]), w)
        with pytest.raises(RuntimeError, match="non-decreasing|from 0 to K"):
            field.composite_labels(u, geo, torch.tensor([0, 1, 2]), torch.tensor([0, 3, 2]), w)


@needs_kernels
def test_fused_paths_step_aside_for_a_replaced_method():
    """A field whose geometry or labels were replaced (a subclass, a test double) renders through them."""
    field = _tiny_model().field
    u, valid, deltas = _marching_inputs(field)
    field.geometry = lambda x, space=None: (torch.zeros(len(x)), torch.zeros(len(x), 15), x)
    field.labels = lambda u, geo: (torch.zeros(len(u), 4), None)
    with torch.no_grad():
        assert field.march(u, valid, deltas, 1.0) is None
        assert field.composite_labels(u, torch.zeros(len(u), 15), torch.arange(3), torch.tensor([0, 3]),
                                      torch.ones(3)) is None


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
