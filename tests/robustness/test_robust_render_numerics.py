"""Numerical extremes of volume rendering, contraction and the voxel grids (docs/robustness.md, section 1).

Property-based (hypothesis) where a whole range matters: σ from 0 to 1e6 (and exact zeros), Δt from 0 to
1e4, distances up to 1e4, points from 0 to 1e6; each property is checked against a float64 reference, and
the CPU bfloat16 autocast path against float64 with a loose tolerance. Every test here must be able to fail:
they compare numbers with independent references, not a function with itself.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from torch import nn

from lift3d.field.encodings import contract
from lift3d.field.grid import GridField, GridFieldConfig
from lift3d.field.grids import grid_lookup, grid_lookup_reference, trilinear_corners
from lift3d.field.registry import FieldConfig
from lift3d.field.space import SceneSpace
from lift3d.render.renderer import SamplingConfig, near_far, render_rays
from lift3d.render.volume import (
    composite,
    interval_midpoints,
    render_depth,
    render_weights,
    render_weights_reference,
)

#: Modest and reproducible: CI must not find a new random failure on every run, nor spend minutes here.
PROPS = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                 suppress_health_check=[HealthCheck.too_slow])


# ------------------------------------------------------------------------------------------ strategies
def _log_uniform(lo_exp: float, hi_exp: float):
    return st.floats(lo_exp, hi_exp).map(lambda e: float(10.0**e))


#: σ in [0, 1e6]: exact zeros, log-uniform magnitudes (1e-30 .. 1e6) and uniform ones, and the end points.
SIGMA = st.one_of(st.just(0.0), st.just(1e6), _log_uniform(-30, 6), st.floats(0.0, 1e6))
#: Δt from exactly 0 through 1e-12 (Δt → 0) up to 1e4 (huge).
DELTA = st.one_of(st.just(0.0), _log_uniform(-12, 4), st.just(1e4))


@st.composite
def ray_batches(draw, max_rays: int = 4, max_samples: int = 40):
    r = draw(st.integers(1, max_rays))
    s = draw(st.integers(1, max_samples))
    sigma = draw(hnp.arrays(np.float64, (r, s), elements=SIGMA))
    deltas = draw(hnp.arrays(np.float64, (r, s), elements=DELTA))
    return sigma, deltas


def _as32(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(a.astype(np.float32))


# ------------------------------------------------------------------------------------------ render weights
@PROPS
@given(ray_batches())
def test_weights_are_sound_and_match_float64_reference(batch):
    """Finite, w ≥ 0, Σw ≤ 1 + 1e-6, T non-increasing from T_0 = 1, w_i = T_i − T_{i+1}; float32 agrees
    with a plain float64 loop on the same (float32-representable) inputs."""
    sigma, deltas = batch
    s32, d32 = _as32(sigma), _as32(deltas)
    w, trans = render_weights(s32, d32)
    assert w.dtype == torch.float32
    assert torch.isfinite(w).all() and torch.isfinite(trans).all()
    assert (w >= 0).all() and (trans >= 0).all() and (trans <= 1).all()
    assert float(w.sum(-1).max()) <= 1.0 + 1e-6
    assert (trans[:, 0] == 1).all()
    assert (trans[:, 1:] <= trans[:, :-1]).all(), "transmittance must never increase along a ray"
    # Telescoping: the weight of a sample is the transmittance it removes.
    t_next = torch.cat([trans[:, 1:], (trans[:, -1] * torch.exp(-(s32[:, -1] * d32[:, -1]).clamp_max(1e4)))[:, None]], 1)
    assert torch.allclose(w, trans - t_next, atol=2e-6)
    ref = render_weights_reference(s32.double(), d32.double())
    assert (w.double() - ref).abs().max() < 1e-5


@PROPS
@given(ray_batches(max_rays=2, max_samples=16))
def test_weights_in_float64_equal_the_reference_loop(batch):
    sigma, deltas = batch
    s64, d64 = torch.from_numpy(sigma), torch.from_numpy(deltas)
    w, _ = render_weights(s64, d64)
    assert w.dtype == torch.float64
    assert torch.allclose(w, render_weights_reference(s64, d64), atol=1e-12, rtol=0)


@PROPS
@given(ray_batches(), st.sampled_from([1.0, 1e2, 1e4]))
def test_gradients_finite_and_depth_bounded_up_to_t_1e4(batch, far):
    """Backward through weights, colour compositing and depth stays finite for every σ/Δt combination; the
    expected depth of rays whose samples reach t = 1e4 lies within [0, t_max]."""
    sigma, deltas = batch
    s32 = _as32(sigma).requires_grad_(True)
    d32 = _as32(deltas)
    t_mid = torch.cumsum(d32, -1).clamp_max(far) if far < 1e4 else torch.linspace(0, far, d32.shape[1]).expand_as(d32)
    w, _ = render_weights(s32, d32)
    colours = torch.rand(*w.shape, 3, generator=torch.Generator().manual_seed(0))
    rgb = composite(w, colours)
    depth = render_depth(w, t_mid)
    depth_n = render_depth(w, t_mid, normalize=True)
    assert torch.isfinite(rgb).all() and torch.isfinite(depth).all() and torch.isfinite(depth_n).all()
    assert (depth >= 0).all() and (depth <= t_mid.max() * (1 + 1e-5) + 1e-6).all()
    assert (rgb <= 1 + 1e-5).all()
    (rgb.sum() + depth.sum() + depth_n.sum()).backward()
    assert torch.isfinite(s32.grad).all()


def test_all_empty_rays_render_nothing_with_finite_gradients():
    """σ = 0 everywhere (the sky): zero weights, T = 1, depth 0 even when normalised, zero gradients w.r.t.
    colour, finite gradients w.r.t. σ (which is how free space gets filled in)."""
    sigma = torch.zeros(3, 64, requires_grad=True)
    deltas = torch.tensor([[0.0] * 64, [1e-12] * 64, [1e4] * 64])
    w, trans = render_weights(sigma, deltas)
    assert (w == 0).all() and (trans == 1).all()
    t_mid = torch.cumsum(deltas, -1)
    assert (render_depth(w, t_mid, normalize=True) == 0).all()
    colour = torch.rand(3, 64, 3, requires_grad=True)
    composite(w, colour).sum().backward()
    assert (colour.grad == 0).all()
    assert torch.isfinite(sigma.grad).all()
    # Where Δt > 0, more density would have been visible: the gradient says so.
    assert (sigma.grad[1:] > 0).any()


def test_saturated_first_sample_takes_all_weight():
    """σ = 1e6 at the first sample with Δt = 1e-3: τ = 1e3, the ray stops there exactly."""
    sigma = torch.tensor([[1e6, 1e6, 3.0, 0.0]])
    w, trans = render_weights(sigma, torch.full_like(sigma, 1e-3))
    assert float(w[0, 0]) == pytest.approx(1.0, abs=1e-7)
    assert float(w[0, 1:].abs().max()) < 1e-30
    assert trans[0, 1:].max() == 0.0


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -1.0, -float("inf")])
def test_non_finite_or_negative_density_is_sanitised(bad):
    """A diverging decoder can emit NaN/±inf/negative σ: weights stay finite and Σw ≤ 1, and the bad
    sample does not poison the other rays."""
    sigma = torch.tensor([[0.5, bad, 0.5, 2.0], [0.5, 0.5, 0.5, 2.0]], requires_grad=True)
    w, trans = render_weights(sigma, torch.full((2, 4), 0.25))
    assert torch.isfinite(w).all() and torch.isfinite(trans).all()
    assert (w >= 0).all() and (trans[:, 1:] <= trans[:, :-1]).all()
    assert float(w.sum(-1).max()) <= 1 + 1e-6
    w[1].sum().backward()
    assert torch.isfinite(sigma.grad[1]).all()
    clean, _ = render_weights(torch.tensor([[0.5, 0.5, 0.5, 2.0]]), torch.full((1, 4), 0.25))
    assert torch.allclose(w[1], clean[0])


@PROPS
@given(st.lists(st.one_of(st.floats(0, 1e4), _log_uniform(-12, 4)), min_size=2, max_size=40),
       st.floats(0, 1e-9))
def test_interval_midpoints_of_near_equal_edges_up_to_1e4(values, jitter):
    """Sorted edges with Δt → 0 (duplicates, 1e-12 apart) and t up to 1e4: Δt ≥ 0, midpoints inside."""
    edges = torch.tensor(sorted(values), dtype=torch.float32)[None]
    edges = torch.cat([edges, edges[:, -1:] + jitter], 1)
    mid, d = interval_midpoints(edges)
    assert (d >= 0).all() and torch.isfinite(d).all()
    assert (mid >= edges[:, :-1] - 1e-3).all() and (mid <= edges[:, 1:] + 1e-3).all()


# ------------------------------------------------------------------------------------------ bfloat16
@PROPS
@given(ray_batches(max_rays=3, max_samples=32))
def test_bfloat16_weights_close_to_float64(batch):
    """Rendering weights computed from bfloat16 inputs (what an autocast decoder hands over): finite, Σw
    within bfloat16 rounding of 1, and the per-ray opacity within 2e-2 of float64."""
    sigma, deltas = batch
    sb, db = _as32(sigma).bfloat16(), _as32(deltas).bfloat16()
    w, trans = render_weights(sb, db)
    assert torch.isfinite(w.float()).all() and torch.isfinite(trans.float()).all()
    assert float(w.float().sum(-1).max()) <= 1.0 + 1e-2
    ref = render_weights_reference(sb.double(), db.double())
    assert (w.double().sum(-1) - ref.sum(-1)).abs().max() < 2e-2


def _small_field(contraction: str, seed: int = 0) -> GridField:
    torch.manual_seed(seed)
    cfg = FieldConfig(num_semantic_classes=5, num_instance_channels=4, contraction=contraction,
                      grid=GridFieldConfig(max_resolution=16, min_resolution=8, levels=2, head_hidden_dim=16))
    return GridField(cfg)


@pytest.mark.parametrize("bounded", [True, False])
def test_autocast_bfloat16_render_matches_float64(bounded):
    """The whole renderer under CPU bfloat16 autocast (training mode, proposal-free sampling) against the
    same field in float64: colours, opacity, depth and label probabilities agree loosely; gradients finite."""
    field = _small_field("none" if bounded else "linf")
    sc = SamplingConfig(proposal_resolutions=(), proposal_samples=(), num_samples=24, far_plane=1e4)
    g = torch.Generator().manual_seed(1)
    origins = torch.tensor([0.0, 0.0, -3.0]) + 0.1 * torch.randn(64, 3, generator=g)
    dirs = nn.functional.normalize(torch.tensor([0.0, 0.0, 1.0]) + 0.3 * torch.randn(64, 3, generator=g), dim=-1)
    ref = render_rays(copy.deepcopy(field).double(), nn.ModuleList(), origins.double(), dirs.double(), sc,
                      bounded=bounded)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = render_rays(field, nn.ModuleList(), origins, dirs, sc, bounded=bounded)
    for name in ("rgb", "opacity", "depth", "semantic", "instance"):
        assert torch.isfinite(getattr(out, name).float()).all(), name
    assert float(out.weights.float().sum(-1).max()) <= 1 + 1e-2
    assert (out.rgb.double() - ref.rgb).abs().max() < 0.05
    assert (out.opacity.double() - ref.opacity).abs().max() < 0.03
    rel_depth = (out.depth.double() - ref.depth).abs() / ref.depth.abs().clamp_min(1.0)
    assert rel_depth.max() < 0.05
    for name in ("semantic", "instance"):
        p = torch.softmax(getattr(out, name).float(), -1).double()
        assert (p - torch.softmax(getattr(ref, name), -1)).abs().max() < 0.05, name
    (out.rgb.float().sum() + out.semantic.float().sum() + out.depth.float().sum()).backward()
    grads = [p.grad for p in field.parameters() if p.grad is not None]
    assert grads and all(torch.isfinite(gr).all() for gr in grads)


# ------------------------------------------------------------------------------------------ contraction
def _extreme_points() -> torch.Tensor:
    """0, the faces / edges / corners of the AABB [-1, 1]^3 (where contraction switches branch), just
    inside and outside them, and far away (1e3 .. 1e6, both signs, axis and diagonal directions)."""
    pts = [[0.0, 0.0, 0.0], [1e-30, 0.0, 0.0], [1e-13, -1e-13, 1e-13]]
    for axis in range(3):
        for sign in (-1.0, 1.0):
            for mag in (1.0, 1.0 - 1e-7, 1.0 + 1e-7, 1e3, 1e6):
                p = [0.3, -0.2, 0.1]
                p[axis] = sign * mag
                pts.append(p)
    pts += [[1.0, 1.0, 1.0], [-1.0, 1.0, -1.0], [1.0, -1.0, 0.0], [1e6, 1e6, 1e6], [-1e6, 1e6, -1e6],
            [1e6, 0.0, 0.0], [0.0, -1e6, 1e-6]]
    return torch.tensor(pts, dtype=torch.float32)


@pytest.mark.parametrize("kind", ["linf", "l2"])
def test_contraction_at_zero_faces_and_1e6(kind):
    x = _extreme_points().requires_grad_(True)
    c = contract(x, kind)
    assert torch.isfinite(c).all()
    norm = (lambda v: v.abs().amax(-1)) if kind == "linf" else (lambda v: v.norm(dim=-1))
    n_in, n_out = norm(x.detach()), norm(c.detach())
    inside = n_in <= 1
    assert torch.equal(c.detach()[inside], x.detach()[inside]), "the unit ball stays where it is"
    assert (n_out <= 2 + 1e-6).all()
    # Contracted radius is 2 − 1/r outside: monotone, continuous at the face, → 2 at 1e6.
    expected = torch.where(inside, n_in, 2 - 1 / n_in.clamp_min(1e-12))
    assert torch.allclose(n_out, expected, atol=1e-6)
    # Direction is kept (rays through the origin stay straight).
    far = n_in > 1
    cos = nn.functional.cosine_similarity(c.detach()[far], x.detach()[far], dim=-1)
    assert (cos > 1 - 1e-6).all()
    c.sum().backward()
    assert torch.isfinite(x.grad).all()


@PROPS
@given(hnp.arrays(np.float64, (8, 3), elements=st.one_of(
    st.just(0.0), st.sampled_from([-1.0, 1.0]), st.floats(-1.0, 1.0), _log_uniform(-12, 6),
    _log_uniform(-12, 6).map(lambda v: -v))))
def test_field_at_any_point_gives_finite_density_and_gradients(points):
    """Bounded (no contraction) and unbounded (L∞ contraction) fields at points from 0 to ±1e6: σ finite
    and ≥ 0, σ = 0 outside a bounded box and on nothing else, label logits finite, every parameter
    gradient finite."""
    x = torch.from_numpy(points.astype(np.float32))
    for contraction in ("none", "linf"):
        field = _small_field(contraction)
        sigma, geo, u = field.geometry(x)
        sem, inst = field.labels(u, geo)
        dirs = nn.functional.normalize(torch.ones_like(x), dim=-1)
        rgb = field.color(geo, dirs)
        for t in (sigma, geo, u, sem, inst, rgb):
            assert torch.isfinite(t).all()
        assert (sigma >= 0).all() and (u >= 0).all() and (u <= 1).all()
        outside = (x.abs() > 1).any(-1)
        if contraction == "none":
            assert (sigma[outside] == 0).all()
            assert (sigma[~outside] > 0).all()
        else:
            assert (sigma > 0).all(), "every finite point is inside contracted space"
        (sigma.sum() + sem.sum() + inst.sum() + rgb.sum()).backward()
        for name, p in field.named_parameters():
            assert p.grad is None or torch.isfinite(p.grad).all(), name


def test_scene_space_faces_are_inside_and_far_points_map_to_the_border():
    x = _extreme_points()
    bounded = SceneSpace("none")
    u, valid = bounded(x)
    on_or_inside = (x.abs() <= 1).all(-1)
    # Points within float32 rounding of a face (1 + 1e-7) may fall either way; everything else must not.
    clear = ((x.abs() - 1).abs() > 1e-6).all(-1) | ~on_or_inside & ((x.abs() - 1) > 1e-6).any(-1)
    assert torch.equal(valid[clear], on_or_inside[clear])
    assert valid[(x.abs() == 1).any(-1) & on_or_inside].all(), "points on the AABB faces belong to the scene"
    assert (u >= 0).all() and (u <= 1).all()
    unbounded = SceneSpace("linf")
    u2, valid2 = unbounded(x)
    assert valid2.all()
    far = x.abs().amax(-1) >= 1e6
    assert ((u2[far] - 0.5).abs().amax(-1) > 0.5 - 1e-6).all(), "1e6 lands on the border of the grid"
    # Non-finite points (a NaN pose slipping through) are flagged, not propagated.
    u3, valid3 = unbounded(torch.tensor([[float("nan"), 0, 0], [float("inf"), 0, 0]]))
    assert not valid3.any() and torch.isfinite(u3).all()


# ------------------------------------------------------------------------------------------ grids
@pytest.mark.parametrize("resolution", [2, 3, 16])
def test_grid_lookup_on_the_border_matches_grid_sample(resolution):
    """u exactly 0 and 1 (the AABB faces in grid space), 1 − 1e-7, outside [0, 1] (clamped): corner
    indices in range, weights a partition of unity, values equal to ``grid_sample``, gradients finite and
    conserving the upstream gradient."""
    g = torch.Generator().manual_seed(0)
    vals = [0.0, 1.0, 1 - 1e-7, 1e-7, 0.5, -1e6, 1e6]
    u = torch.tensor([[a, b, c] for a in vals for b in vals[:3] for c in vals[::3]], dtype=torch.float32)
    idx, w = trilinear_corners(u, resolution)
    assert idx.min() >= 0 and idx.max() < resolution**3
    assert (w >= 0).all() and torch.allclose(w.sum(-1), torch.ones(len(u)), atol=1e-6)
    table = torch.randn(resolution**3, 5, generator=g, requires_grad=True)
    out = grid_lookup(table, resolution, u)
    ref = grid_lookup_reference(table.detach(), resolution, u)
    assert torch.allclose(out, ref, atol=1e-5)
    upstream = torch.rand(out.shape, generator=g)
    (out * upstream).sum().backward()
    assert torch.isfinite(table.grad).all()
    assert torch.allclose(table.grad.sum(0), upstream.sum(0), rtol=1e-4)


def test_near_far_of_axis_aligned_rays_and_rays_that_miss():
    """Direction components exactly 0 (axis-aligned rays), origins on a face, far away (1e4) or missing the
    box: finite near ≤ far, and a ray that misses renders nothing."""
    sc = SamplingConfig(proposal_resolutions=(), proposal_samples=(), num_samples=16)
    origins = torch.tensor([[0.0, 0.0, -1e4], [1.0, 0.0, 0.0], [5.0, 5.0, -3.0], [0.0, 0.0, 0.0]])
    dirs = torch.tensor([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    near, far = near_far(origins, dirs, sc, bounded=True)
    assert torch.isfinite(near).all() and torch.isfinite(far).all() and (far >= near).all()
    assert float(near[0]) == pytest.approx(1e4 - 1, rel=1e-6) and float(far[0]) == pytest.approx(1e4 + 1, rel=1e-6)
    assert float(far[2] - near[2]) == 0.0
    out = render_rays(_small_field("none"), nn.ModuleList(), origins, dirs, sc, bounded=True)
    assert all(torch.isfinite(t).all() for t in (out.rgb, out.depth, out.opacity, out.semantic, out.weights))
    assert float(out.opacity[2]) == 0.0 and float(out.rgb[2].abs().max()) == 0.0
    assert math.isfinite(float(out.depth.max())) and float(out.depth[0]) <= 1e4 + 1
