"""Rendering math: fast paths against plain references, and numerics at the extremes."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lift3d.field import grids
from lift3d.field.encodings import contract, positional_encoding, spherical_harmonics
from lift3d.field.grids import DenseGrid, default_resolutions, grid_lookup, grid_lookup_reference
from lift3d.render.samplers import (
    interlevel_loss,
    outer_bound,
    ray_aabb,
    sample_pdf,
    spacing_fn,
    spacing_fn_inv,
    uniform_edges,
)
from lift3d.render.volume import (composite, interval_midpoints, median_depth, opacity_crossing, render_depth, render_weights,
                                 render_weights_reference)


def test_render_weights_match_reference_float64():
    g = torch.Generator().manual_seed(0)
    sigma = torch.rand(7, 13, generator=g, dtype=torch.float64) * 5
    deltas = torch.rand(7, 13, generator=g, dtype=torch.float64) * 0.3
    w, trans = render_weights(sigma, deltas)
    ref = render_weights_reference(sigma, deltas)
    assert torch.allclose(w, ref, atol=1e-12)
    # T_i is the product of (1 - alpha_j) for j < i.
    alpha = 1 - torch.exp(-sigma * deltas)
    expected_t = torch.cumprod(torch.cat([torch.ones(7, 1, dtype=torch.float64), 1 - alpha[:, :-1]], 1), 1)
    assert torch.allclose(trans, expected_t, atol=1e-12)


def test_render_weights_hand_case():
    # Two samples, sigma*delta = ln 2 each: w = [1/2, 1/4].
    s = torch.tensor([[math.log(2.0), math.log(2.0)]])
    w, _ = render_weights(s, torch.ones(1, 2))
    assert torch.allclose(w, torch.tensor([[0.5, 0.25]]), atol=1e-7)


@settings(max_examples=60, deadline=None)
@given(
    log_sigma=st.lists(st.floats(-8, 6), min_size=1, max_size=24),
    log_delta=st.floats(-12, 4),
    far=st.sampled_from([1.0, 1e2, 1e4]),
)
def test_render_weights_extremes_are_sound(log_sigma, log_delta, far):
    """σ in [0, 1e6], Δt from 1e-12 to 1e4: no NaN/Inf, Σw ≤ 1, transmittance non-increasing."""
    sigma = torch.tensor([10.0**x for x in log_sigma] + [0.0], dtype=torch.float32)[None]
    deltas = torch.full_like(sigma, 10.0**log_delta)
    t_mid = torch.linspace(0, far, sigma.shape[1])[None]
    w, trans = render_weights(sigma, deltas)
    assert torch.isfinite(w).all() and torch.isfinite(trans).all()
    assert (w >= 0).all()
    assert float(w.sum()) <= 1.0 + 1e-6
    assert (trans[:, 1:] <= trans[:, :-1] + 1e-7).all()
    assert torch.isfinite(render_depth(w, t_mid)).all()
    # float32 agrees with a float64 reference.
    ref = render_weights_reference(sigma.double(), deltas.double())
    assert torch.allclose(w.double(), ref, atol=1e-5)


def test_render_weights_survive_nan_and_inf_density():
    sigma = torch.tensor([[float("nan"), float("inf"), 1.0, -3.0]])
    w, _ = render_weights(sigma, torch.ones_like(sigma))
    assert torch.isfinite(w).all() and float(w.sum()) <= 1 + 1e-6


def test_empty_rays_have_zero_weight_and_finite_gradients():
    sigma = torch.zeros(4, 8, requires_grad=True)
    w, _ = render_weights(sigma, torch.full((4, 8), 0.1))
    assert float(w.detach().abs().sum()) == 0.0
    w.sum().backward()
    assert torch.isfinite(sigma.grad).all()


def test_opacity_crossing_matches_a_finely_subdivided_ray():
    # Reference: split every interval into 2000 pieces of the same density and walk until opacity 0.5.
    g = torch.Generator().manual_seed(0)
    sigma = torch.rand(64, 12, generator=g, dtype=torch.float64) * 8.0
    sigma[:, :3] = 0.0  # empty space first
    deltas = torch.rand(64, 12, generator=g, dtype=torch.float64) * 0.2 + 0.01
    dist, reached = opacity_crossing(sigma, deltas)
    sub = 2000
    fine_sigma = sigma.repeat_interleave(sub, dim=1)
    fine_deltas = (deltas / sub).repeat_interleave(sub, dim=1)
    w, _ = render_weights(fine_sigma, fine_deltas)
    opacity = w.cumsum(-1)
    ends = fine_deltas.cumsum(-1)
    for r in range(len(sigma)):
        assert bool(reached[r]) == bool(opacity[r, -1] >= 0.5)
        if reached[r]:
            k = int((opacity[r] < 0.5).sum())
            assert abs(float(dist[r]) - float(ends[r, k])) <= float(fine_deltas[r, k]) + 1e-9


def test_opacity_crossing_edge_cases():
    deltas = torch.ones(4, 3)
    sigma = torch.tensor([[0.0, 0.0, 0.0], [1e6, 0.0, 0.0], [float("nan"), float("inf"), 0.0],
                          [0.0, 0.0, math.log(2.0)]])
    dist, reached = opacity_crossing(sigma, deltas)
    assert reached.tolist() == [False, True, True, True]
    assert torch.isfinite(dist).all()
    assert float(dist[0]) == 0.0 and float(dist[1]) < 1e-3  # saturated: at the start of its interval
    assert 1.0 <= float(dist[2]) < 1.001  # NaN counts as empty, +inf as opaque
    assert float(dist[3]) == pytest.approx(3.0, abs=1e-5)  # ln 2 over the last interval: exactly at its end
    with pytest.raises(ValueError, match="level"):
        opacity_crossing(sigma, deltas, level=1.0)


def test_median_depth_from_weights_matches_the_crossing_from_densities():
    # The renderer holds weights, the isosurface densities: both must put the median at the same place.
    g = torch.Generator().manual_seed(1)
    sigma = torch.rand(64, 12, generator=g, dtype=torch.float64) * 8.0
    sigma[:, :3] = 0.0
    sigma[:8] = 0.0  # rays that never reach 0.5
    sigma[8:16, 5] = 1e4  # a hard wall
    deltas = torch.rand(64, 12, generator=g, dtype=torch.float64) * 0.2 + 0.01
    edges = torch.cat([torch.full((64, 1), 0.3, dtype=torch.float64), 0.3 + deltas.cumsum(-1)], -1)
    t_mid, _ = interval_midpoints(edges)
    w, _ = render_weights(sigma, deltas)
    dist, reached = median_depth(w, t_mid, deltas)
    ref, ref_reached = opacity_crossing(sigma, deltas)
    assert reached.tolist() == ref_reached.tolist() and not reached[:8].any() and reached[8:16].all()
    assert torch.equal(dist[~reached], torch.zeros(int((~reached).sum()), dtype=torch.float64))
    # opacity_crossing counts from 0. A saturated interval's optical depth is only known as far as 1 - Σ w
    # resolves its transmittance out (~1e-16 here): the crossing is then within a few % of that interval.
    k = (w.cumsum(-1) < 0.5).sum(-1).clamp(max=11)
    slack = 0.03 * deltas.gather(-1, k[:, None]).squeeze(-1) + 1e-9
    assert ((dist - ref - 0.3).abs()[reached] <= slack[reached]).all()
    soft = reached & (sigma * deltas).lt(30).all(-1)  # no saturated interval: exact
    assert soft.sum() > 20 and torch.allclose(dist[soft], ref[soft] + 0.3, atol=1e-9)
    # A surface of opacity 0.6 over [1.0, 1.1] and faint fog over 500 m behind it (an unbounded scene's
    # background): the fog drags the expected depth far away, the median stays in the surface.
    d = torch.tensor([[1.0, 0.1] + [50.0] * 10], dtype=torch.float64)
    s = torch.tensor([[0.0, math.log(1 / 0.4) / 0.1] + [0.01] * 10], dtype=torch.float64)
    tm, _ = interval_midpoints(torch.cat([torch.zeros(1, 1, dtype=torch.float64), d.cumsum(-1)], -1))
    wf, _ = render_weights(s, d)
    dist_fog, _ = median_depth(wf, tm, d)
    assert 1.0 < float(dist_fog) < 1.1 and float(render_depth(wf, tm, normalize=True)) > 30.0
    with pytest.raises(ValueError, match="level"):
        median_depth(w, t_mid, deltas, level=0.0)


def test_composite_is_weighted_sum():
    w = torch.rand(5, 6)
    v = torch.rand(5, 6, 4)
    assert torch.allclose(composite(w, v), (w[..., None] * v).sum(1), atol=1e-6)


@pytest.mark.parametrize("in_place", [True, False])
def test_grid_lookup_matches_grid_sample(in_place, monkeypatch):
    monkeypatch.setattr(grids, "ACCUMULATE_GRAD_IN_PLACE", in_place)
    g = torch.Generator().manual_seed(1)
    r = 9
    table = torch.nn.Parameter(torch.randn(r**3, 3, generator=g))
    u = torch.rand(200, 3, generator=g) * 1.2 - 0.1  # also outside [0, 1]: clamped to the border
    fast = grid_lookup(table, r, u)
    ref = grid_lookup_reference(table.detach().requires_grad_(True), r, u)
    assert torch.allclose(fast, ref, atol=1e-5)
    up = torch.randn(200, 3, generator=g)
    (fast * up).sum().backward()
    ref_table = table.detach().clone().requires_grad_(True)
    (grid_lookup_reference(ref_table, r, u) * up).sum().backward()
    assert torch.allclose(table.grad, ref_table.grad, atol=1e-5)


def test_grid_gradient_accumulates_over_two_lookups():
    r = 5
    table = torch.nn.Parameter(torch.randn(r**3, 2))
    u1, u2 = torch.rand(10, 3), torch.rand(10, 3)
    (grid_lookup(table, r, u1).sum() + grid_lookup(table, r, u2).sum()).backward()
    ref = table.detach().clone().requires_grad_(True)
    (grid_lookup_reference(ref, r, u1).sum() + grid_lookup_reference(ref, r, u2).sum()).backward()
    assert torch.allclose(table.grad, ref.grad, atol=1e-5)


def test_dense_grid_total_variation_is_zero_for_constant_grid_and_positive_otherwise():
    grid = DenseGrid((6,), channels=2)
    with torch.no_grad():
        grid.tables[0].fill_(3.0)
    assert float(grid.total_variation(500)) < 1e-5
    with torch.no_grad():
        grid.tables[0].normal_()
    tv = grid.total_variation(500)
    tv.backward()
    assert float(tv) > 0.1 and torch.isfinite(grid.tables[0].grad).all()


def test_default_resolutions():
    assert default_resolutions(128, 3, 32) == (32, 64, 128)
    assert default_resolutions(96, 1, 32) == (96,)


@pytest.mark.parametrize("kind", ["l2", "linf"])
def test_contraction_inside_identity_outside_bounded_and_finite(kind):
    x = torch.tensor([[0.0, 0.0, 0.0], [0.3, -0.2, 0.9], [1.0, 0.0, 0.0], [5.0, 1.0, 0.0], [1e6, -1e6, 3.0]],
                     requires_grad=True)
    c = contract(x, kind)
    assert torch.allclose(c[:3], x[:3])
    norm = c.norm(dim=-1) if kind == "l2" else c.abs().amax(-1)
    assert (norm <= 2.0 + 1e-6).all()
    assert float(norm[-1]) > 1.99
    c.sum().backward()
    assert torch.isfinite(x.grad).all()


def test_positional_encoding_and_sh_shapes():
    x = torch.rand(4, 3)
    assert positional_encoding(x, 2).shape == (4, 3 + 12)
    d = torch.nn.functional.normalize(torch.randn(50, 3), dim=-1)
    sh = spherical_harmonics(d, 3)
    assert sh.shape == (50, 16)
    assert torch.allclose(sh[:, 0], torch.full((50,), 0.28209479177387814))
    # Degree-1 terms are proportional to the direction components.
    assert torch.allclose(sh[:, 2], 0.4886025119029199 * d[:, 2], atol=1e-6)


def test_spacing_roundtrip_and_ray_aabb():
    t = torch.tensor([0.01, 0.5, 1.0, 3.0, 1e4])
    for kind in ("linear", "lindisp"):
        # float32 near s = 1 resolves t = 1e4 to ~2e-4 relative: ample for sample placement.
        assert torch.allclose(spacing_fn_inv(spacing_fn(t, kind), kind), t, rtol=5e-4)
    o = torch.tensor([[-3.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 5.0, 0.0]])
    d = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    near, far = ray_aabb(o, d)
    assert torch.allclose(near[:2], torch.tensor([2.0, -1.0])) and torch.allclose(far[:2], torch.tensor([4.0, 1.0]))
    assert far[2] <= near[2]  # misses the box


def test_uniform_edges_sorted_and_span_the_interval():
    near, far = torch.full((6,), 0.5), torch.full((6,), 2.5)
    for jitter in (False, True):
        e = uniform_edges(near, far, 16, "linear", jitter, torch.Generator().manual_seed(0))
        assert e.shape == (6, 17)
        assert (e[:, 1:] >= e[:, :-1]).all()
        assert torch.allclose(e[:, 0], near) and torch.allclose(e[:, -1], far)


def test_sample_pdf_concentrates_where_the_weight_is():
    edges = torch.linspace(0, 1, 11).expand(3, 11).contiguous()
    weights = torch.zeros(3, 10)
    weights[:, 7] = 1.0  # all mass in [0.7, 0.8]
    new = sample_pdf(edges, weights, 32, jitter=False)
    assert (new[:, 1:] >= new[:, :-1]).all()
    mid = 0.5 * (new[:, 1:] + new[:, :-1])
    inside = ((mid >= 0.7) & (mid <= 0.8)).float().mean()
    assert float(inside) > 0.8
    jittered = sample_pdf(edges, weights, 32, jitter=True, generator=torch.Generator().manual_seed(0))
    assert (jittered >= 0).all() and (jittered <= 1).all()


def test_interlevel_loss_zero_when_proposal_bounds_fine_weights():
    edges = torch.linspace(0, 1, 9)[None]
    w = torch.tensor([[0.0, 0.1, 0.6, 0.2, 0.0, 0.0, 0.05, 0.0]])
    assert float(interlevel_loss(edges, w, edges, w)) < 1e-9
    # The proposal puts all its mass elsewhere: the bound is 0, loss = Σ w²/w = Σ w.
    p = torch.zeros_like(w)
    p[0, 0] = 1.0
    assert abs(float(interlevel_loss(edges, w, edges, p)) - float(w[0, 1:].sum())) < 1e-5


def test_outer_bound_hand_case():
    fine = torch.tensor([[0.0, 0.5, 1.0]])
    env = torch.tensor([[0.0, 0.25, 0.75, 1.0]])
    wenv = torch.tensor([[0.1, 0.2, 0.3]])
    # [0, 0.5] overlaps env intervals 0 and 1; [0.5, 1] overlaps 1 and 2.
    assert torch.allclose(outer_bound(fine, env, wenv), torch.tensor([[0.3, 0.5]]))


def test_render_rays_extremes_no_nan():
    from lift3d.field.grid import GridField, GridFieldConfig
    from lift3d.field.layers import ProposalGrid
    from lift3d.field.registry import FieldConfig
    from lift3d.render.renderer import RenderOptions, SamplingConfig, render_rays

    torch.manual_seed(0)
    for contraction, bounded in (("none", True), ("linf", False)):
        cfg = FieldConfig(num_semantic_classes=3, num_instance_channels=2, contraction=contraction,
                          grid=GridFieldConfig(max_resolution=16, min_resolution=8, head_hidden_dim=8))
        field = GridField(cfg)
        with torch.no_grad():
            field.density_mlp[-1].bias[0] = 30.0  # saturated density everywhere
        props = torch.nn.ModuleList([ProposalGrid(8)])
        scfg = SamplingConfig(far_plane=1e4, proposal_samples=(16,), num_samples=8)
        o = torch.tensor([[0.0, 0.0, 0.0], [5.0, 5.0, 5.0], [0.0, 0.0, 0.0]])
        d = torch.nn.functional.normalize(torch.tensor([[1.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.0, 0.0, -1.0]]), dim=-1)
        out = render_rays(field, props, o, d, scfg, RenderOptions(training=True), bounded=bounded)
        for t in (out.rgb, out.depth, out.semantic, out.instance, out.distill):
            assert torch.isfinite(t).all()
        assert (out.opacity <= 1 + 1e-6).all()
        if bounded:
            assert float(out.opacity[1]) == 0.0  # the ray that misses the box renders nothing
        (out.rgb.sum() + out.semantic.sum() + out.distill).backward()
        assert all(torch.isfinite(p.grad).all() for p in field.parameters() if p.grad is not None)


def test_depth_guided_edges_land_around_the_measured_depth():
    from lift3d.render.renderer import add_depth_guided_edges

    s = torch.linspace(0.0, 1.0, 9)[None].repeat(3, 1)  # [3, 9]
    near, far = torch.zeros(3), torch.ones(3)
    out = add_depth_guided_edges(s, torch.tensor([0.3, 0.0, 0.99]), near, far, 4, 0.06, "linear")
    assert out.shape == (3, 13) and (out.diff(dim=-1) >= 0).all()
    added = [sorted(set(out[0].tolist()) - set(s[0].tolist()))]
    assert np.allclose(added[0], [0.24, 0.28, 0.32, 0.36], atol=1e-6)
    assert (out[1, 9:] == 1.0).all()  # no depth: zero-length intervals at the far end
    assert float(out[2].max()) == 1.0  # clamped to the far plane
    # Unbounded (lin/disparity spacing): the new edges map back to distances around the depth.
    near, far = torch.full((1,), 0.05), torch.full((1,), 1e3)
    s_ud = uniform_edges(near, far, 8, "lindisp", False)
    out = add_depth_guided_edges(s_ud, torch.tensor([4.0]), near, far, 3, 0.5, "lindisp")
    t = spacing_fn_inv(out, "lindisp")
    assert torch.isclose(t, torch.tensor(4.0), atol=1e-4).any() and ((t > 3.49) & (t < 4.51)).sum() >= 3


def test_depth_guided_samples_put_weight_where_the_training_depth_says():
    """A field with a thin wall the proposal has not seen: without guidance no sample lands on it."""
    from lift3d.render.renderer import RenderOptions, SamplingConfig, render_rays

    class Wall(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.space = type("S", (), {"__call__": lambda self, x: (x, torch.ones(len(x), dtype=torch.bool)),
                                        "ray_bounds": lambda self: (-1.0, 1.0)})()

        def geometry(self, x, space=None):
            sigma = torch.where((x[:, 0] - 0.6).abs() < 0.01, 1e4, 0.0)
            return sigma, torch.zeros(len(x), 4), x

        def color(self, geo, dirs):
            return torch.ones(len(geo), 3)

    o = torch.tensor([[-0.9, 0.0, 0.0]])
    d = torch.tensor([[1.0, 0.0, 0.0]])
    cfg = SamplingConfig(proposal_resolutions=(), num_samples=8, near_gradient_distance=0.0)
    plain = render_rays(Wall(), torch.nn.ModuleList(), o, d, cfg, RenderOptions(training=True, with_labels=False),
                        bounded=True, generator=torch.Generator().manual_seed(0))
    guided = render_rays(Wall(), torch.nn.ModuleList(), o, d, cfg, RenderOptions(training=True, with_labels=False),
                         bounded=True, generator=torch.Generator().manual_seed(0), depth_target=torch.tensor([1.5]))
    assert float(plain.opacity[0]) < 0.5 < float(guided.opacity[0])
    assert abs(float(guided.depth[0]) - 1.5) < 0.01
