"""The occupancy grid and early ray termination: same renders as the plain path, fewer field evaluations,
kept in the checkpoint (older checkpoints still load)."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
import torch

from lift3d.field.occupancy import OccupancyGrid, uncontract_torch
from lift3d.field.space import SceneSpace
from lift3d.model.run import load_run
from lift3d.render.renderer import RenderOptions, SamplingConfig, render_rays
from lift3d.synth import SynthOptions, make_scene
from lift3d.train.trainer import train

SHORT = {
    "field": {"grid": {"resolution_cap": 32, "min_resolution": 16, "head_hidden_dim": 32},
              "occupancy": {"resolution": 16, "start": 20, "update_every": 20}},
    "sampling": {"proposal_resolutions": [24], "proposal_samples": [32], "num_samples": 24},
    "data": {"images_per_batch": 2, "rays_per_image": 96, "patch_size": 8},
    "optim": {"steps": 100, "warmup_steps": 10},
    "trainer": {"eval_every": 0, "eval_images": 1, "checkpoint_every": 1000, "log_every": 20, "device": "cpu"},
}


@pytest.fixture(scope="module")
def run_path(tmp_path_factory):
    root = tmp_path_factory.mktemp("scenes") / "room"
    make_scene(root, SynthOptions(kind="indoor", seed=101, noise="moderate", n_views=8, width=32, height=32),
               progress=False)
    out = tmp_path_factory.mktemp("runs")
    return train(root, preset="fast", output_dir=out, overrides=SHORT, progress=False, print_summary=False).run.path


def test_cells_with_density_are_occupied_and_decay_forgets():
    occ = OccupancyGrid("none")
    assert not occ.built and occ.fraction_occupied == 1.0
    occ.update(lambda x: (x[:, 0] > 0.5).float() * 100.0, resolution=8, threshold=0.01)
    assert occ.built and occ.fraction_occupied == 0.25
    u = torch.tensor([[0.1, 0.5, 0.5], [0.9, 0.5, 0.5]])
    assert occ.lookup(u).tolist() == [False, True]
    # An emptied cell is forgotten once its remembered density has decayed below the threshold.
    # (σ 100 over cells of length 0.25: optical depth 25, halved per update: 12.5, 6.25, 3.125.)
    for expected in (True, True, False):
        occ.update(lambda x: torch.zeros(len(x)), resolution=8, threshold=4.0, decay=0.5)
        assert occ.lookup(u).tolist() == [False, expected]
    with occ.suspended():
        assert not occ.applies()


@pytest.mark.parametrize("contraction, subdivide, chunk", [("none", 1, 100), ("l2", 2, 700), ("linf", 3, 5000)])
def test_the_chunked_measurement_matches_a_cell_by_cell_reference(contraction, subdivide, chunk):
    """Each cell keeps the largest density at its sub-cell points (jittered by the generator's offsets, drawn
    x-slowest), whatever the chunking: the update's chunked loop against one point at a time."""
    w = torch.tensor([0.7, -1.3, 0.4])

    def density(x):
        # elementwise, not x @ w: a matrix product rounds differently over many rows than over one (an Intel Xeon's
        # kernels did), and far out in contracted space, where x is in the thousands, sin turned that last bit into
        # a difference of 1e-3
        return torch.relu(torch.sin(5.0 * (x[:, 0] * w[0] + x[:, 1] * w[1] + x[:, 2] * w[2])) * 40.0 + 10.0 * x[:, 0])

    res = 5
    fine = res * subdivide
    occ = OccupancyGrid(contraction)
    occ.update(density, resolution=res, threshold=0.01, generator=torch.Generator().manual_seed(3),
               subdivide=subdivide, chunk=chunk)
    offsets = torch.rand(fine**3, 3, generator=torch.Generator().manual_seed(3)).view(fine, fine, fine, 3)
    expected = torch.zeros(res, res, res)
    for i, j, k in itertools.product(range(fine), repeat=3):
        g = (torch.tensor([i, j, k], dtype=torch.float32) + offsets[i, j, k]) / fine * 2.0 - 1.0
        c = (g * occ.extent).clamp(-occ.extent * 0.9995, occ.extent * 0.9995)
        value = density(uncontract_torch(c[None], contraction))[0]
        cell = (i // subdivide, j // subdivide, k // subdivide)
        expected[cell] = torch.maximum(expected[cell], value)
    assert torch.allclose(occ.cell_density.view(res, res, res), expected, rtol=1e-5, atol=1e-5)


def test_contracted_cells_are_longer_outside_the_unit_ball():
    occ = OccupancyGrid("linf")
    length = occ.cell_length(8, torch.device("cpu")).view(8, 8, 8)
    assert torch.allclose(length[3:5, 3:5, 3:5], torch.full((2, 2, 2), 0.5))  # side 2·2/8 in [-1, 1]
    assert length[0, 0, 0] > 4 * length[4, 4, 4]


class Slab(torch.nn.Module):
    """A field with an opaque slab across ``0.2 < x < 0.4`` and nothing elsewhere; labels vary with position."""

    def __init__(self):
        super().__init__()
        self.space = SceneSpace("none")

    def geometry(self, x, space=None):
        u, valid = self.space(x) if space is None else space
        sigma = torch.where((x[:, 0] > 0.2) & (x[:, 0] < 0.4), 200.0, 0.0) * valid
        return sigma, torch.cat([x, x.square()], -1), u

    def color(self, geo, dirs):
        return torch.sigmoid(geo[:, :3] * 3 + dirs)

    def labels(self, u, geo):
        return torch.cat([u, -u], -1), u[:, :2] * 4


def test_skipping_empty_cells_and_terminating_rays_is_exact_up_to_the_thresholds():
    g = torch.Generator().manual_seed(3)
    o = torch.rand(64, 3, generator=g) * 0.4 - torch.tensor([0.9, 0.2, 0.2])
    d = torch.tensor([1.0, 0.0, 0.0]) + 0.15 * torch.randn(64, 3, generator=g)
    d = d / d.norm(dim=-1, keepdim=True)
    field = Slab().eval()
    counted = []
    geometry = field.geometry
    field.geometry = lambda x, space=None: (counted.append(len(x)), geometry(x, space))[1]
    none = torch.nn.ModuleList()
    plain_cfg = SamplingConfig(proposal_resolutions=(), num_samples=96, termination_transmittance=0.0)
    plain = render_rays(field, none, o, d, plain_cfg, bounded=True)
    n_plain = sum(counted)
    field.space.occupancy.update(lambda x: geometry(x)[0], resolution=16, threshold=0.01, subdivide=2)
    assert 0.05 < field.space.occupancy.fraction_occupied < 0.2
    counted.clear()
    fast = render_rays(field, none, o, d, SamplingConfig(proposal_resolutions=(), num_samples=96), bounded=True)
    n_fast = sum(counted)
    assert n_fast < 0.3 * n_plain, (n_fast, n_plain)  # empty space before the slab and everything behind it
    assert float(plain.opacity.min()) > 0.99  # every ray hits the slab
    for a, b in ((fast.rgb, plain.rgb), (fast.opacity, plain.opacity), (fast.depth, plain.depth),
                 (fast.semantic, plain.semantic), (fast.instance, plain.instance)):
        assert torch.allclose(a, b, atol=2e-3), (a - b).abs().max()


def _rays_towards_slab(seed: int, n: int = 128):
    """``n`` rays from in front of :class:`Slab`, pointing at it within about 6 degrees of +x."""
    g = torch.Generator().manual_seed(seed)
    o = torch.rand(n, 3, generator=g) * 0.4 - torch.tensor([0.9, 0.2, 0.2])
    d = torch.tensor([1.0, 0.0, 0.0]) + 0.1 * torch.randn(n, 3, generator=g)
    return o, d / d.norm(dim=-1, keepdim=True)


def _softened_slab(density_scale: float) -> Slab:
    """A :class:`Slab` (eval mode) whose density is scaled by ``density_scale``."""
    field = Slab().eval()
    geometry = field.geometry
    field.geometry = lambda x, space=None: (lambda s, *rest: (s * density_scale, *rest))(*geometry(x, space))
    return field


def test_render_label_coverage_decodes_fewer_samples_outside_training_only():
    """Renders outside training decode labels at the fewest top samples holding 90 % of the top-8 weight,
    and the labels stay close to what all eight give; training renders decode all eight."""
    o, d = _rays_towards_slab(seed=4)
    field = _softened_slab(0.08)  # translucent
    decoded = []
    labels = field.labels
    field.labels = lambda u, geo: (decoded.append(len(u)), labels(u, geo))[1]
    none = torch.nn.ModuleList()
    out = {}
    for coverage in (0.0, 0.9):
        cfg = SamplingConfig(proposal_resolutions=(), num_samples=96, render_label_coverage=coverage)
        for training in (False, True):
            decoded.clear()
            torch.manual_seed(0)  # the same jittered samples in both training renders
            r = render_rays(field, none, o, d, cfg, RenderOptions(training=training), bounded=True)
            out[coverage, training] = (sum(decoded), r.semantic.detach())
    assert out[0.0, False][0] == out[0.0, True][0] == out[0.9, True][0] == 128 * 8  # the training cap
    assert out[0.9, False][0] < 0.8 * out[0.0, False][0]  # about 6 of 8 on this translucent slab
    assert torch.allclose(out[0.9, True][1], out[0.0, True][1])  # training is unaffected
    few, all8 = out[0.9, False][1], out[0.0, False][1]
    assert float((few.argmax(-1) == all8.argmax(-1)).float().mean()) > 0.95  # (this field's labels nearly tie)
    assert float(torch.nn.functional.cosine_similarity(few, all8, dim=-1).min()) > 0.99
    ratio = few.norm(dim=-1) / all8.norm(dim=-1)  # the kept weight is scaled up to all eight samples' weight
    assert float((ratio - 1).abs().max()) < 0.03, ratio


def test_render_color_coverage_decodes_fewer_samples_outside_training_only():
    """Renders outside training decode colour at the fewest samples holding 99 % of the weight, scaled up to
    all of it: the colour stays within the dropped weight of what every sample gives; training decodes all."""
    o, d = _rays_towards_slab(seed=6)
    field = _softened_slab(0.5)  # a soft surface
    decoded = []
    color = field.color
    field.color = lambda geo, dirs: (decoded.append(len(geo)), color(geo, dirs))[1]
    none = torch.nn.ModuleList()
    out = {}
    for coverage in (0.0, 0.99):
        cfg = SamplingConfig(proposal_resolutions=(), num_samples=96, render_color_coverage=coverage)
        for training in (False, True):
            decoded.clear()
            torch.manual_seed(0)  # the same jittered samples in both training renders
            r = render_rays(field, none, o, d, cfg, RenderOptions(training=training, with_labels=False), bounded=True)
            out[coverage, training] = (sum(decoded), r.rgb.detach(), r.opacity.detach())
    assert out[0.99, True][0] == out[0.0, True][0]
    assert out[0.99, False][0] < 0.9 * out[0.0, False][0]
    assert torch.equal(out[0.99, True][1], out[0.0, True][1])  # training is unaffected
    assert torch.equal(out[0.99, False][2], out[0.0, False][2])  # so is the opacity
    # Each channel of a colour lies in [0, 1]: swapping 1 % of the weight moves it by at most 0.01.
    assert float((out[0.99, False][1] - out[0.0, False][1]).abs().max()) < 0.01


def _rays(n: int = 256):
    g = torch.Generator().manual_seed(5)
    d = torch.randn(n, 3, generator=g)
    return torch.zeros(n, 3) + 0.05 * torch.randn(n, 3, generator=g), d / d.norm(dim=-1, keepdim=True)


def _render_counting(model, origins, dirs):
    """The model's render and the number of points its field's geometry was evaluated at."""
    counted = []
    geometry = model.field.geometry

    def counting(x, *args, **kwargs):
        counted.append(len(x))
        return geometry(x, *args, **kwargs)

    model.field.geometry = counting
    try:
        with torch.no_grad():
            out = model.render(origins, dirs)
    finally:
        del model.field.geometry
    return out, sum(counted)


def test_occupancy_and_termination_render_what_the_plain_path_renders(run_path):
    run = load_run(run_path, device="cpu")
    model = run.model
    occ = model.field.space.occupancy
    assert occ.built and occ.fraction_occupied < 0.9, occ.fraction_occupied  # the grid does skip space
    origins, dirs = _rays()
    fast, n_fast = _render_counting(model, origins, dirs)
    plain_cfg = dataclasses.replace(model.cfg.sampling, termination_transmittance=0.0)
    fast_cfg, model.cfg.sampling = model.cfg.sampling, plain_cfg
    try:
        with occ.suspended():
            plain, n_plain = _render_counting(model, origins, dirs)
    finally:
        model.cfg.sampling = fast_cfg
    assert n_fast <= n_plain
    # A cell the grid calls empty may still have held a little density where no update measured it: a few
    # rays may change by a few per cent (measured after 100 steps: 1 ray of 256 by 0.04), the rest not.
    rgb = (fast.rgb - plain.rgb).abs().amax(-1)
    assert float(rgb.mean()) < 0.005 and float((rgb > 0.01).float().mean()) < 0.02 and float(rgb.max()) < 0.1
    opacity = (fast.opacity - plain.opacity).abs()
    assert float(opacity.mean()) < 0.005 and float(opacity.max()) < 0.1
    sem = (fast.semantic.softmax(-1) - plain.semantic.softmax(-1)).abs().amax(-1)
    assert float(sem.mean()) < 0.01


def test_the_grid_is_in_the_checkpoint_and_old_checkpoints_still_load(run_path, tmp_path):
    run = load_run(run_path, device="cpu")
    occupied = run.model.field.space.occupancy.occupied.clone()
    ckpt = sorted((run_path / "checkpoints").glob("*.pt"))[-1] if (run_path / "checkpoints").is_dir() \
        else sorted(run_path.rglob("*.pt"))[-1]
    state = torch.load(ckpt, weights_only=False)
    keys = [k for k in state["model"] if k.startswith("field.space.occupancy.")]
    assert sorted(keys) == ["field.space.occupancy.cell_density", "field.space.occupancy.occupied"]
    assert torch.equal(state["model"]["field.space.occupancy.occupied"], occupied)
    # A checkpoint written before the grid existed: the grid is measured from the field at load.
    for k in keys:
        del state["model"][k]
    torch.save(state, ckpt)
    old = load_run(run_path, device="cpu")
    rebuilt = old.model.field.space.occupancy
    assert rebuilt.built and rebuilt.resolution == occupied.shape[0]
    # Measured at sub-cell centres instead of accumulated at random points: nearly the same cells.
    assert (rebuilt.occupied == occupied).float().mean() > 0.9
    out = old.render_rays(np.zeros((4, 3), np.float32), np.eye(3, dtype=np.float32)[[0, 1, 2, 0]])
    assert np.isfinite(out["rgb"]).all()


def test_in_training_the_grid_zeroes_density_only_when_asked():
    """The grid always applies when rendering; in training only with field.occupancy.in_training (fog control)."""
    space = SceneSpace("none")
    space.occupancy.update(lambda x: (x[:, 0] > 0.5).float() * 100.0, resolution=8, threshold=0.01)
    x = torch.tensor([[-0.5, 0.0, 0.0], [0.8, 0.0, 0.0]])
    assert space.train()(x)[1].tolist() == [True, True]
    space.occupancy_in_training = True
    assert space(x)[1].tolist() == [False, True]
    space.occupancy_in_training = False
    assert space.eval()(x)[1].tolist() == [False, True]
    assert space.forward_torch(x)[1].tolist() == [False, True]
