"""lift3d export: labelled points, meshes, instances, file formats, the loading API and the CLI.

Most tests run the export pipeline on an *analytic* field (known spheres and a floor slab plugged into a
small model in place of its density and label heads), so that positions, visibility and instance ids can be
checked against exact answers. One session-scoped tiny training run checks the CLI end to end.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

import lift3d
from lift3d.data.cameras import look_at
from lift3d.data.ply import read_labelled_ply
from lift3d.data.scene import Category, FramePseudoLabels, SceneWriter, Segment, load_scene
from lift3d.errors import InputError
from lift3d.export import export_run
from lift3d.export.instances import assign_instances, voxel_downsample_majority
from lift3d.export.isosurface import choose_density_threshold
from lift3d.export.mesh import extract_labelled_mesh
from lift3d.export.pointcloud import OrientedBox, extract_labelled_points
from lift3d.export.writers.pcd import read_pcd, write_pcd
from lift3d.export.writers.semantickitti import read_semantickitti_label
from lift3d.model.normalization import SceneNormalization
from lift3d.model.panoptic import _tiny_model
from lift3d.model.run import LoadedRun
from lift3d.model.run_folder import RunFolder
from lift3d.utils.files import check_writable

# ------------------------------------------------------------------------------------------ analytic field
# Normalised coordinates. Shell A (a hollow ball) hides a solid ball C inside it; ball B stands apart; a
# floor slab (stuff) lies below. A and B share one instance channel: they must become two instances.
SHELL_A = (np.array([-0.3, 0.0, 0.0]), 0.30, 0.24)  # centre, outer radius, inner radius
BALL_B = (np.array([0.45, 0.0, 0.0]), 0.15)
BALL_C = (np.array([-0.3, 0.0, 0.0]), 0.10)  # inside A: never visible
FLOOR_TOP, FLOOR_BOTTOM, FLOOR_RADIUS = -0.5, -0.6, 0.9  # a round slab
PEAK_DENSITY = 200.0
RAMP = 0.01  # density rises from 0 to PEAK over this distance
THING, STUFF = 3, 1  # category ids of the tiny model's label space (semantic_ids [1, 2, 3], things [3])
WORLD_CENTER, WORLD_SCALE = np.array([1.0, 2.0, 3.0]), 0.5  # x_norm = (x_world - center) * scale



def extract_analytic(loaded, scene, **options):
    """:func:`extract_labelled_points` on the analytic scene without the view-surface step: the analytic field's
    rays reach an opacity of 0.5 on a tenth of its views' pixels, behind its shells' isosurface, so the step (tested
    on its own in test_export_steps.py) would judge the shells by renders that do not show them."""
    return extract_labelled_points(loaded, scene, **{"view_surface": False, **options})

def _inside_distance(x: torch.Tensor) -> torch.Tensor:
    """Signed distance *into* the nearest solid (positive inside)."""
    ca, ra_out, ra_in = SHELL_A
    d_a = (x - torch.as_tensor(ca, dtype=x.dtype)).norm(dim=-1)
    shell = torch.minimum(d_a - ra_in, ra_out - d_a)
    ball_b = BALL_B[1] - (x - torch.as_tensor(BALL_B[0], dtype=x.dtype)).norm(dim=-1)
    ball_c = BALL_C[1] - (x - torch.as_tensor(BALL_C[0], dtype=x.dtype)).norm(dim=-1)
    floor = torch.minimum(torch.minimum(FLOOR_TOP - x[:, 2], x[:, 2] - FLOOR_BOTTOM),
                          FLOOR_RADIUS - x[:, :2].norm(dim=-1))
    return torch.stack([shell, ball_b, ball_c, floor]).amax(0)


def analytic_model():
    """The tiny model with density and label heads replaced by the analytic scene (colour head kept)."""
    model = _tiny_model()
    field = model.field
    geo_dim = model.cfg.field.geo_feat_dim

    def geometry(x, space=None):
        sigma = PEAK_DENSITY * ((_inside_distance(x) / RAMP) + 0.5).clamp(0.0, 1.0)
        inside_box = (x.abs() <= 1.0).all(-1)
        return sigma * inside_box, torch.zeros(len(x), geo_dim), ((x + 1) / 2).clamp(0, 1)

    def labels(u, geo):
        x = u * 2 - 1
        sem = torch.zeros(len(x), 4)
        is_floor = x[:, 2] < (FLOOR_TOP + 0.05)
        sem[:, 3] = torch.where(is_floor, 0.0, 10.0)  # channel 3 = category 3 (thing)
        sem[:, 1] = torch.where(is_floor, 10.0, 0.0)  # channel 1 = category 1 (stuff)
        inst = torch.zeros(len(x), 3)
        inst[:, 0] = 10.0  # one instance channel for every thing point
        return sem, inst

    field.geometry = geometry
    field.labels = labels
    return model


def _write_ring_scene(root: Path, n_frames: int = 8, category: int = 1) -> Path:
    """Cameras on a ring around the analytic scene, looking at it (world coordinates); every view's 2D labels are
    one segment of ``category``."""
    cats = [Category(1, "floor", False, (80, 60, 40)), Category(2, "wall", False, (120, 120, 120)),
            Category(3, "ball", True, (200, 30, 30))]
    h, w = 30, 40
    with SceneWriter(root, cats) as writer:
        names = []
        for k in range(n_frames):
            a = 2 * np.pi * k / n_frames
            eye_n = np.array([2.0 * np.cos(a), 2.0 * np.sin(a), 0.9])
            eye = eye_n / WORLD_SCALE + WORLD_CENTER
            target = np.array([0.0, 0.0, -0.2]) / WORLD_SCALE + WORLD_CENTER
            seg = np.ones((h, w), np.int64)
            names.append(writer.add_frame(f"f{k:02d}", np.zeros((h, w, 3), np.uint8), look_at(eye, target),
                                          (30.0, 30.0, w / 2, h / 2),
                                          labels=FramePseudoLabels(seg, [Segment(1, category)])))
        writer.set_splits(train=names)
    return root


@pytest.fixture(scope="module", autouse=True)
def no_view_vote():
    """The ring scene's 2D labels show one stuff segment per view, which contradicts the analytic field's balls:
    the training views' vote (tested in test_export_views.py) would make them stuff. Off in this module."""
    import lift3d.export.views as views

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(views, "vote_point_labels", lambda xyz, semantic, *a, **k: (semantic, {"changed": 0}))
        yield


@pytest.fixture(scope="module")
def analytic(tmp_path_factory) -> SimpleNamespace:
    """A LoadedRun-like object over the analytic field, and its scene."""
    root = tmp_path_factory.mktemp("analytic")
    scene = load_scene(_write_ring_scene(root / "scene"))
    (root / "run").mkdir()
    model = analytic_model()
    norm = SceneNormalization(WORLD_CENTER.copy(), WORLD_SCALE, True,
                              np.stack([WORLD_CENTER - 2, WORLD_CENTER + 2]))
    loaded = LoadedRun(RunFolder(root / "run"), model.cfg, model, norm, model.labels, 0, torch.device("cpu"))
    return SimpleNamespace(loaded=loaded, scene=scene, root=root)


def _normalized(xyz_world: np.ndarray) -> np.ndarray:
    return (np.asarray(xyz_world, np.float64) - WORLD_CENTER) * WORLD_SCALE


@pytest.fixture(scope="module")
def surface_points(analytic):
    # The ring scene's 2D labels show one stuff segment per view: nothing would confirm the analytic balls as
    # things (the clean-up's support rule is tested in test_instance_cleanup.py).
    return extract_analytic(analytic.loaded, analytic.scene, num_points=20000, min_support_views=0)


# ------------------------------------------------------------------------------------------ geometry
def test_surface_points_lie_on_the_visible_surfaces(surface_points):
    pts = surface_points
    assert len(pts) == 20000 and pts.frame == "world"
    x = _normalized(pts.xyz)
    d_a = np.linalg.norm(x - SHELL_A[0], axis=1)
    d_b = np.linalg.norm(x - BALL_B[0], axis=1)
    on_a = np.abs(d_a - SHELL_A[1]) < 0.02
    on_b = np.abs(d_b - BALL_B[1]) < 0.02
    on_floor = (np.abs(x[:, 2] - FLOOR_TOP) < 0.02) | \
        ((np.abs(np.linalg.norm(x[:, :2], axis=1) - FLOOR_RADIUS) < 0.02) & (x[:, 2] > FLOOR_BOTTOM - 0.02))
    assert (on_a | on_b | on_floor).all(), "every point lies on a visible surface"
    assert on_a.sum() > 1000 and on_b.sum() > 300 and on_floor.sum() > 1000
    # Hidden surfaces: the inside of shell A, ball C inside it, the underside of the floor.
    assert not (d_a < SHELL_A[1] - 0.03).any()
    assert not ((x[:, 2] < FLOOR_TOP - 0.03) & (np.linalg.norm(x[:, :2], axis=1) < FLOOR_RADIUS - 0.03)).any()
    # Labels: things on the balls (one channel, two separated objects → two instances), stuff on the floor.
    assert set(np.unique(pts.semantic[on_floor]).tolist()) == {STUFF}
    assert (pts.instance[on_floor] == 0).all()
    assert set(np.unique(pts.instance[on_a]).tolist()) == {1}, "the larger object gets id 1"
    assert set(np.unique(pts.instance[on_b]).tolist()) == {2}
    assert pts.xyz.dtype == np.float32 and pts.semantic.dtype == np.int32 and pts.instance.dtype == np.int32
    assert pts.rgb.dtype == np.uint8 and pts.confidence.dtype == np.float32
    assert np.all((pts.confidence > 0.5) & (pts.confidence <= 1.0))


def test_a_sheet_thinner_than_the_coarse_lattice_is_still_contoured(monkeypatch):
    """A wall one fine cell thick, lying between two coarse-lattice nodes (what depth supervision makes of
    a wall): the coarse pass sees zero on both sides and, at 64³, would skip it."""
    from lift3d.export.isosurface import DEFAULT_LATTICE, field_isosurface, lattice_resolution

    model = _tiny_model()
    monkeypatch.setattr(type(model.field), "finest_resolution", property(lambda f: 128))  # claims 128³ detail
    x0 = 0.5 + 1.0 / 64  # halfway between two coarse nodes at 64³ (spacing 2/64)

    def geometry(x, space=None):
        sigma = torch.where((x[:, 0] - x0).abs() < 0.4 / 64, 500.0, 0.0)
        return sigma, torch.zeros(len(x), model.cfg.field.geo_feat_dim), ((x + 1) / 2).clamp(0, 1)

    model.field.geometry = geometry
    assert lattice_resolution(model) == 128
    surf = field_isosurface(model, 100.0, 128)
    assert surf.stats["coarse_cells"] == 128 and len(surf.faces) > 0
    xs = surf.vertices[:, 0]
    assert np.abs(xs - x0).max() < 2.0 / 128 and np.ptp(surf.vertices[:, 1]) > 1.5  # the whole sheet
    monkeypatch.setattr(type(model.field), "finest_resolution", property(lambda f: 0))  # no lattice (MLP)
    assert lattice_resolution(model) == DEFAULT_LATTICE
    assert field_isosurface(model, 100.0, 128).stats["coarse_cells"] == 64  # the default coarse lattice


@pytest.mark.parametrize("resolution", [64, 128])
def test_isosurface_equals_contouring_every_lattice_node(resolution):
    """One pass (the field's grid as fine as the export) or two (coarse, then fine nodes near τ): the surface
    is the one of the density evaluated at every node of the fine lattice; only points in the field's space
    are decoded (density 0 elsewhere by the Field contract)."""
    import pyvista as pv

    from lift3d.export.isosurface import field_density, field_isosurface

    model = _tiny_model()
    decoded = []

    def geometry(x, space=None):
        decoded.append(len(x))
        sigma = 300.0 * torch.exp(-((x - torch.tensor([0.1, -0.2, 0.05])).norm(dim=-1) / 0.35) ** 4)
        return sigma, torch.zeros(len(x), model.cfg.field.geo_feat_dim), ((x + 1) / 2).clamp(0, 1)

    model.field.geometry = geometry
    surf = field_isosurface(model, 100.0, resolution)
    assert surf.stats["coarse_cells"] == 64 and (surf.stats["refined_nodes"] > 0) == (resolution > 64)
    n = resolution + 1
    axis = np.linspace(-1.0, 1.0, n)
    nodes = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    volume = np.pad(geometry(torch.from_numpy(nodes).float())[0].numpy().reshape(n, n, n), 1)
    step = 2.0 / resolution
    image = pv.ImageData(dimensions=volume.shape, spacing=(step,) * 3, origin=(-1 - step,) * 3)
    image.point_data["density"] = volume.ravel(order="F")
    ref = image.contour([100.0], scalars="density", method="flying_edges", compute_scalars=False)
    assert len(surf.faces) == ref.n_cells > 100
    assert np.allclose(np.sort(surf.vertices, axis=0), np.sort(np.asarray(ref.points), axis=0), atol=1e-5)
    # Points outside the box are not decoded and have density 0.
    decoded.clear()
    x = np.array([[0.1, -0.2, 0.05], [1.5, 0.0, 0.0], [0.0, -3.0, 0.0]], np.float32)
    sigma = field_density(model, x)
    assert decoded == [1] and sigma[0] > 100 and sigma[1] == sigma[2] == 0


def test_automatic_threshold_matches_the_rendered_surface(analytic):
    tau, info = choose_density_threshold(analytic.loaded, analytic.scene)
    assert 0 < tau < PEAK_DENSITY, info
    assert info["mean_error_samples"] < 2.0



def test_refinement_moves_vertices_onto_the_rendered_surface():
    """A ball whose density ramps linearly from 0 at radius R0 to P at R0 - W: a ray going inwards along
    the normal reaches opacity 0.5 where P s² / (2 W) = ln 2, deeper than a low isosurface."""
    from lift3d.export.isosurface import field_isosurface, refine_to_rendered_surface

    r0, width, peak, tau = 0.5, 0.05, 100.0, 10.0
    model = _tiny_model()

    def geometry(x, space=None):
        s = r0 - x.norm(dim=-1)
        return peak * (s / width).clamp(0.0, 1.0), torch.zeros(len(x), model.cfg.field.geo_feat_dim), \
            ((x + 1) / 2).clamp(0, 1)

    model.field.geometry = geometry
    surf = field_isosurface(model, tau, 64)
    expected = r0 - np.sqrt(2 * width * np.log(2) / peak)  # 0.4737, about 0.7 voxel (2/64) inside
    iso_radius = np.median(np.linalg.norm(surf.vertices, axis=1))
    assert iso_radius > expected + 0.02  # σ = τ lies at 0.495 (0.497 with the grid's linear interpolation)
    refined = refine_to_rendered_surface(model, surf)
    radius = np.linalg.norm(refined.vertices, axis=1)
    assert np.median(np.abs(radius - expected)) < 1e-3 and np.abs(radius - expected).max() < 4e-3
    st = refined.stats["refine"]
    assert st["moved"] == st["vertices"] == len(surf.vertices)
    assert np.array_equal(refined.faces, surf.faces)
    # Too little density for a half-opaque short ray: nothing moves.
    model.field.geometry = lambda x, space=None: (0.05 * geometry(x)[0], *geometry(x)[1:])
    faint = refine_to_rendered_surface(model, field_isosurface(model, 0.5, 64))
    assert faint.stats["refine"]["moved"] == 0


def test_refinement_leaves_crevice_vertices_alone():
    """Two parallel slabs one voxel apart: the short ray of a vertex facing the gap starts inside the other
    slab (σ ≥ τ at its first sample), so that vertex must not jump onto the neighbour."""
    from lift3d.export.isosurface import field_isosurface, refine_to_rendered_surface

    model = _tiny_model()
    voxel = 2.0 / 64

    def geometry(x, space=None):
        gap = (x[:, 0].abs() < 0.5 * voxel)
        slab = (x[:, 0].abs() < 0.4) & ~gap & (x[:, 1].abs() < 0.6) & (x[:, 2].abs() < 0.6)
        return torch.where(slab, 1000.0, 0.0), torch.zeros(len(x), model.cfg.field.geo_feat_dim), \
            ((x + 1) / 2).clamp(0, 1)

    model.field.geometry = geometry
    surf = field_isosurface(model, 100.0, 64)
    refined = refine_to_rendered_surface(model, surf)
    facing_gap = (np.abs(surf.vertices[:, 0]) < voxel) & (np.abs(surf.vertices[:, 1]) < 0.5) & \
        (np.abs(surf.vertices[:, 2]) < 0.5)
    assert facing_gap.sum() > 100
    moved_by = np.abs(refined.vertices - surf.vertices).max(1)
    assert (moved_by[facing_gap] < 0.75 * voxel).all()  # stayed on its own side of the gap

def test_normalized_frame_and_transform(analytic, surface_points):
    norm_pts = extract_analytic(analytic.loaded, analytic.scene, num_points=20000, frame="normalized",
                                       density_threshold=surface_points.thresholds["density"])
    np.testing.assert_allclose(norm_pts.xyz, _normalized(surface_points.xyz), atol=1e-5)
    # transform maps normalised → world.
    homog = np.c_[norm_pts.xyz, np.ones(len(norm_pts))] @ surface_points.transform.T
    np.testing.assert_allclose(homog[:, :3], surface_points.xyz, atol=1e-4)
    np.testing.assert_array_equal(norm_pts.instance, surface_points.instance)


@contextlib.contextmanager
def dense_uniform_samples(model):
    """Render with dense uniform samples instead of the tiny model's untrained proposal grids, so that the
    rendered depth is exact up to the sample spacing. (Restored by hand: monkeypatch's undo deletes a
    submodule attribute of an nn.Module instead of restoring it, which broke the module-scoped field.)"""
    proposals, n = model.proposals, model.cfg.sampling.num_samples
    model.proposals, model.cfg.sampling.num_samples = torch.nn.ModuleList(), 384
    try:
        yield
    finally:
        model.proposals, model.cfg.sampling.num_samples = proposals, n


def test_rays_source_backprojects_opaque_rays(analytic):
    # Only the back-projection is under test (see dense_uniform_samples).
    with dense_uniform_samples(analytic.loaded.model):
        pts = extract_analytic(analytic.loaded, analytic.scene, source="rays", num_points=2000)
    x = _normalized(pts.xyz)
    d_a = np.linalg.norm(x - SHELL_A[0], axis=1)
    d_b = np.linalg.norm(x - BALL_B[0], axis=1)
    near_surface = (np.abs(d_a - SHELL_A[1]) < 0.03) | (np.abs(d_b - BALL_B[1]) < 0.03) | \
        (np.abs(x[:, 2] - FLOOR_TOP) < 0.03) | (np.abs(np.linalg.norm(x[:, :2], axis=1) - FLOOR_RADIUS) < 0.03)
    assert 0 < len(pts) <= 2000
    assert near_surface.mean() > 0.98
    assert pts.thresholds["opacity"] == 0.5


def test_tsdf_source_fuses_the_rendered_depth_of_the_training_views(analytic):
    with dense_uniform_samples(analytic.loaded.model):
        pts = extract_analytic(analytic.loaded, analytic.scene, source="tsdf", num_points=4000,
                                      min_support_views=0)  # no 2D thing segments here (see surface_points)
    x = _normalized(pts.xyz)
    voxel = pts.thresholds["tsdf"]["voxel"]
    d_a = np.linalg.norm(x - SHELL_A[0], axis=1)
    d_b = np.linalg.norm(x - BALL_B[0], axis=1)
    tol = 1.5 * voxel
    near_surface = (np.abs(d_a - SHELL_A[1]) < tol) | (np.abs(d_b - BALL_B[1]) < tol) | \
        (np.abs(x[:, 2] - FLOOR_TOP) < tol) | (np.abs(np.linalg.norm(x[:, :2], axis=1) - FLOOR_RADIUS) < tol)
    assert 0 < len(pts) <= 4000 and near_surface.mean() > 0.95
    # What no view sees is not fused: nothing of the ball hidden inside the shell.
    assert not np.any(np.linalg.norm(x - BALL_C[0], axis=1) < BALL_C[1] + 0.02)
    # Both visible objects are there, labelled by the heads at the points (thing on the balls).
    assert (d_b < BALL_B[1] + tol).sum() > 50 and (d_a < SHELL_A[1] + tol).sum() > 50
    on_b = d_b < BALL_B[1] + tol
    assert (pts.semantic[on_b] == THING).mean() > 0.95
    info = pts.thresholds["tsdf"]
    assert info["views"] == 8 and info["fused_pixels"] > 0
    with pytest.raises(InputError, match="--source"):
        extract_analytic(analytic.loaded, analytic.scene, source="voxels", num_points=10)


def test_box_fill_adds_the_rendered_surface_where_a_soft_wall_at_the_box_has_no_isosurface(analytic):
    # A wall the box hugs, as a room's box hugs its walls: density 60 over its last 0.04, below the isosurface's
    # threshold (100) but opaque enough (optical depth 2.4) that the views render it.
    model = analytic_model()
    solid = model.field.geometry

    def geometry(x, space=None):
        sigma, geo, u = solid(x, space)
        soft = ((x[:, 0] > 0.96) & (x.abs() <= 1.0).all(-1)).to(sigma.dtype) * 60.0
        return sigma + soft, geo, u

    model.field.geometry = geometry
    loaded = LoadedRun(analytic.loaded.run, model.cfg, model, analytic.loaded.norm, model.labels, 0,
                       torch.device("cpu"))
    kw = dict(num_points=20000, min_support_views=0, density_threshold=100.0, frame="normalized")
    plain = extract_labelled_points(loaded, analytic.scene, box_fill=False, **kw)
    filled = extract_labelled_points(loaded, analytic.scene, **kw)
    assert not (plain.xyz[:, 0] > 0.9).any() and plain.record("box-fill")["why"] == "off"
    wall = filled.xyz[:, 0] > 0.9
    assert wall.sum() > 200 and filled.xyz[wall, 0].min() > 0.96 - 1e-3
    assert filled.record("box-fill")["counts"]["points"] >= wall.sum()
    # the solids keep their isosurface: nothing is added next to them
    balls = ~wall
    assert abs(int(balls.sum()) - len(plain.xyz)) <= 0.02 * len(plain.xyz)


def test_thing_fill_adds_the_rendered_surface_of_a_soft_thing_where_the_views_label_that_thing(analytic, tmp_path,
                                                                                              monkeypatch):
    # Ball B soft: density 60 inside it, below the isosurface's threshold (100) but opaque (optical depth 18
    # across it), as an object few depth targets reached is in a field trained from images alone.
    model = analytic_model()
    solid = model.field.geometry

    def geometry(x, space=None):
        sigma, geo, u = solid(x, space)
        d_b = (x - torch.as_tensor(BALL_B[0], dtype=x.dtype)).norm(dim=-1)
        sigma = torch.where(d_b < BALL_B[1] + 2 * RAMP, (d_b < BALL_B[1]).to(sigma.dtype) * 60.0, sigma)
        return sigma, geo, u

    model.field.geometry = geometry
    loaded = LoadedRun(analytic.loaded.run, model.cfg, model, analytic.loaded.norm, model.labels, 0,
                       torch.device("cpu"))
    things_seen = load_scene(_write_ring_scene(tmp_path / "things", category=THING))
    kw = dict(num_points=20000, min_support_views=0, density_threshold=100.0, frame="normalized")

    def near_b(pts):
        return np.abs(np.linalg.norm(pts.xyz - BALL_B[0], axis=1) - BALL_B[1]) < 0.03

    with dense_uniform_samples(model):
        filled = extract_labelled_points(loaded, things_seen, **kw)
        plain = extract_labelled_points(loaded, things_seen, thing_fill=False, **kw)
        stuff_seen = extract_labelled_points(loaded, analytic.scene, **kw)
        voxels = extract_labelled_points(loaded, things_seen, voxel_size=0.02, **kw)
    # The views render the ball and label it a thing: its front faces come back, as the thing, one instance.
    on_b = near_b(filled)
    assert on_b.sum() > 40 and filled.record("thing-fill")["counts"]["points"] >= on_b.sum()
    assert (filled.semantic[on_b] == THING).all() and len(np.unique(filled.instance[on_b])) == 1
    # Nothing else is added: shell A keeps its isosurface points only.
    assert abs(int((~on_b).sum()) - len(plain.xyz)) <= 0.02 * len(plain.xyz)
    # Without the fill, or where the views' 2D labels call it stuff, the ball has no points.
    assert not near_b(plain).any() and not plain.record("thing-fill")["ran"]
    assert not near_b(stuff_seen).any() and stuff_seen.record("thing-fill")["counts"]["points"] == 0
    # Voxel down-sampling keeps track of which points were filled: the pieces of the sparse filled ball (tiny views)
    # join each other.
    import lift3d.export.steps.instances as instance_steps

    monkeypatch.setattr(instance_steps, "join_filled_instances", lambda xyz, sem, inst, filled, radius, channel=None: (inst, 0))
    with dense_uniform_samples(model):
        apart = extract_labelled_points(loaded, things_seen, voxel_size=0.02, **kw)
    pieces = len(np.unique(voxels.instance[near_b(voxels)]))
    assert near_b(voxels).sum() > 20 and pieces < len(np.unique(apart.instance[near_b(apart)])) / 2


def test_unbounded_scene_is_contoured_in_contracted_space_and_cropped(tmp_path):
    # Balls at the origin (foreground), at 2.5 (contracted background) and at 10 (beyond the export radius).
    balls = [(np.array([0.0, 0.0, 0.0]), 0.3), (np.array([0.0, 2.5, 0.0]), 0.5), (np.array([0.0, -10.0, 0.0]), 2.0)]
    model = _tiny_model()
    model.field.space.contraction, model.field.space.extent = "linf", 2.0
    model.bounded = False
    geo_dim = model.cfg.field.geo_feat_dim

    def geometry(x, space=None):
        inside = torch.stack([r - (x - torch.as_tensor(c, dtype=x.dtype)).norm(dim=-1) for c, r in balls]).amax(0)
        sigma = PEAK_DENSITY * (inside / (RAMP * (1 + x.norm(dim=-1))) + 0.5).clamp(0.0, 1.0)
        return sigma, torch.zeros(len(x), geo_dim), torch.rand(len(x), 3)

    model.field.geometry = geometry
    cats = [Category(1, "floor", False), Category(2, "wall", False), Category(3, "ball", True)]
    with SceneWriter(tmp_path / "scene", cats) as writer:
        names = []
        for k in range(12):  # a ring looking inwards and outwards, like a street capture
            a = 2 * np.pi * k / 12
            eye = np.array([0.9 * np.cos(a), 0.9 * np.sin(a), 0.3])
            target = eye * (3.0 if k % 2 else -1.0)
            target[2] = 0.0
            names.append(writer.add_frame(f"f{k:02d}", np.zeros((30, 40, 3), np.uint8), look_at(eye, target),
                                          (25.0, 25.0, 20.0, 15.0),
                                          labels=FramePseudoLabels(np.ones((30, 40), np.int64), [Segment(1, 1)])))
        writer.set_splits(train=names)
    scene = load_scene(tmp_path / "scene")
    norm = SceneNormalization(np.zeros(3), 1.0, False, np.array([[-1.0] * 3, [1.0] * 3]))
    (tmp_path / "run").mkdir()
    loaded = LoadedRun(RunFolder(tmp_path / "run"), model.cfg, model, norm, model.labels, 0, torch.device("cpu"))
    pts = extract_labelled_points(loaded, scene, num_points=20000, density_threshold=PEAK_DENSITY / 2)
    d = np.stack([np.linalg.norm(pts.xyz - c, axis=1) - r for c, r in balls], 1)
    near_ball = np.abs(d) < np.array([0.02, 0.2, 1.0])
    assert near_ball[:, :2].any(1).all(), "every point lies on the foreground or the background ball"
    assert near_ball[:, 0].sum() > 1000 and near_ball[:, 1].sum() > 100
    assert np.abs(pts.xyz).max() <= 4.0 + 1e-3, "far background beyond the export radius is skipped"
    # streets get no fills and no corner step (docs/export.md): an unbounded run shows none of their premises
    for name in ("box-fill", "thing-fill", "stuff-corners"):
        assert pts.record(name)["why"].startswith("premise not shown"), name
    assert pts.stats["premises"]["shown"] == []


def test_obb_crop_keeps_exactly_the_points_inside(analytic, surface_points):
    # A box around ball B only (world frame), rotated 45° about z.
    center = BALL_B[0] / WORLD_SCALE + WORLD_CENTER
    box = OrientedBox.from_params(center, (0.0, 0.0, np.pi / 4), (0.8, 0.8, 0.8))
    cropped = extract_analytic(analytic.loaded, analytic.scene, num_points=20000, obb=box,
                                      density_threshold=surface_points.thresholds["density"])
    assert 0 < len(cropped) < len(surface_points)
    assert box.contains(cropped.xyz).all()
    expected = box.contains(surface_points.xyz).sum()
    assert len(cropped) == expected
    # Inside the box lives only ball B: one instance, renumbered to 1.
    assert set(np.unique(cropped.instance).tolist()) <= {0, 1} and cropped.instance.max() == 1


def test_obb_rotation_convention():
    box = OrientedBox.from_params((0, 0, 0), (0, 0, np.pi / 2), (4, 1, 1))  # yaw 90°: long side along y
    assert box.contains(np.array([[0, 1.9, 0]])).all()
    assert not box.contains(np.array([[1.9, 0, 0]])).any()
    with pytest.raises(InputError, match="obb-scale"):
        OrientedBox.from_params(scale=(1, 0, 1))


# ------------------------------------------------------------------------------------------ labels
def test_voxel_downsampling_votes_labels_instead_of_averaging():
    rng = np.random.default_rng(0)
    # Voxel [0,1)^3 holds three points of class 3 and two of class 5; an average would give 3.8 or 4.
    xyz = np.array([[0.1, 0.1, 0.1], [0.2, 0.2, 0.2], [0.3, 0.3, 0.3], [0.4, 0.4, 0.4], [0.5, 0.5, 0.5],
                    [1.5, 0.5, 0.5]])
    sem = np.array([3, 3, 3, 5, 5, 5])
    chan = np.array([2, 2, 2, 1, 1, 0])
    conf = np.array([0.6, 0.8, 1.0, 0.1, 0.1, 0.5], np.float32)
    rgb = rng.integers(0, 255, (6, 3)).astype(np.uint8)
    out_xyz, out_rgb, out_sem, out_chan, out_conf = voxel_downsample_majority(xyz, rgb, sem, chan, conf, 1.0)
    assert out_sem.tolist() == [3, 5] and out_chan.tolist() == [2, 0]
    np.testing.assert_allclose(out_conf, [0.8, 0.5], atol=1e-6)  # mean confidence of the winning label
    np.testing.assert_allclose(out_xyz[0], [0.3, 0.3, 0.3], atol=1e-6)
    np.testing.assert_array_equal(out_rgb[0], np.round(rgb[:5].mean(0)).astype(np.uint8))
    assert out_sem.dtype == np.int32


def test_voxel_size_option_in_the_pipeline(analytic, surface_points):
    voxel = 0.1  # world units
    pts = extract_analytic(analytic.loaded, analytic.scene, num_points=20000, voxel_size=voxel,
                                  density_threshold=surface_points.thresholds["density"])
    keys = np.floor(pts.xyz / voxel).astype(np.int64)
    assert len(np.unique(keys, axis=0)) == len(pts) < len(surface_points)
    assert set(np.unique(pts.semantic).tolist()) <= {THING, STUFF}  # never an averaged class such as 2
    assert pts.instance.max() == 2


def test_instance_ids_are_contiguous_and_stable():
    rng = np.random.default_rng(1)
    # Four blobs of one class and one raw channel (so only space separates them) and some stuff.
    centers = np.array([[0, 0, 0], [5, 0, 0], [1, 5, 0], [0, 0, 5]], float)
    sizes = [50, 200, 120, 120]
    xyz = np.concatenate([c + rng.uniform(-0.1, 0.1, (n, 3)) for c, n in zip(centers, sizes)]
                         + [rng.uniform(10, 11, (30, 3))])
    sem = np.array([7] * sum(sizes) + [1] * 30)
    chan = np.array([4] * sum(sizes) + [0] * 30)
    ids = assign_instances(xyz, sem, chan, link_radius=0.5).instance
    starts = np.cumsum([0] + sizes)[:-1]
    # Largest first; equal sizes ordered by centroid x (the blob at x = 0 before the one at x = 1).
    assert [int(ids[s]) for s in starts] == [4, 1, 3, 2]
    for s, n in zip(starts, sizes):
        assert len(np.unique(ids[s:s + n])) == 1
    assert (ids[-30:] == 0).all()
    # Stable: the same points in another order get the same ids.
    perm = rng.permutation(len(xyz))
    np.testing.assert_array_equal(assign_instances(xyz[perm], sem[perm], chan[perm], link_radius=0.5).instance,
                                  ids[perm])


def test_min_points_relabels_fragments_to_their_surroundings_or_drops_isolated_ones():
    rng = np.random.default_rng(2)
    chair = rng.uniform(0, 1, (2000, 3))  # class 7, channel 1
    speck = np.array([[0.5, 0.5, 1.02], [0.52, 0.5, 1.02]])  # class 9, channel 2, touching the chair
    lonely = np.array([[20.0, 20.0, 20.0]])  # class 7, channel 3, far from everything
    xyz = np.concatenate([chair, speck, lonely])
    sem = np.array([7] * 2000 + [9, 9] + [7])
    chan = np.array([1] * 2000 + [2, 2] + [3])
    kept_all = assign_instances(xyz, sem, chan, link_radius=0.2)
    assert kept_all.instance.max() == 3 and kept_all.keep.all()
    res = assign_instances(xyz, sem, chan, link_radius=0.2, min_points=5)
    assert res.semantic[2000:2002].tolist() == [7, 7], "the speck takes the chair's class"
    assert res.instance[2000:2002].tolist() == [1, 1] and (res.instance[:2000] == 1).all()
    assert not res.keep[2002], "an isolated fragment is dropped"
    assert res.stats["fragments_relabelled"] == 1 and res.stats["fragments_dropped"] == 1


def test_min_points_in_the_pipeline(analytic, surface_points):
    # Ball B is about one fifth of the thing points; min_points above its size makes it a fragment, which
    # would take the label of its surroundings, but nothing is within reach of it: it is dropped.
    pts = surface_points
    b_size = int((pts.instance == 2).sum())
    pruned = extract_analytic(analytic.loaded, analytic.scene, num_points=20000, min_points=b_size + 1,
                                     density_threshold=pts.thresholds["density"])
    assert pruned.instance.max() == 1
    assert len(pruned) == len(pts) - b_size
    np.testing.assert_array_equal(pruned.xyz, pts.xyz[pts.instance != 2])


def test_min_confidence_filter(analytic, surface_points):
    pts = extract_analytic(analytic.loaded, analytic.scene, num_points=20000, min_confidence=0.9999999,
                                  density_threshold=surface_points.thresholds["density"])
    assert len(pts) < len(surface_points)
    assert (pts.confidence >= 0.9999999).all()


def test_outlier_removal_keeps_a_subset_and_records_its_settings(analytic, surface_points):
    pts = extract_analytic(analytic.loaded, analytic.scene, num_points=20000, remove_outliers=True,
                                  std_ratio=0.5, density_threshold=surface_points.thresholds["density"])
    assert 0 < len(pts) < len(surface_points)
    before = {tuple(p) for p in surface_points.xyz.round(5).tolist()}
    assert all(tuple(p) in before for p in pts.xyz.round(5).tolist())
    record = pts.record("outlier-removal")
    assert record["ran"] and record["settings"] == {"enabled": True, "neighbours": 20, "std_ratio": 0.5}
    assert record["counts"]["removed"] > 0 and record["counts"]["points_after"] >= len(pts)


def test_bad_options_are_input_errors(analytic):
    for kwargs, flag in (({"source": "lidar"}, "--source"), ({"frame": "camera"}, "--frame"),
                         ({"num_points": 0}, "--num-points"), ({"voxel_size": -1.0}, "--voxel-size"),
                         ({"min_confidence": 2.0}, "--min-confidence"), ({"density_threshold": -1.0}, "--density")):
        with pytest.raises(InputError, match=flag):
            extract_analytic(analytic.loaded, analytic.scene, num_points=kwargs.pop("num_points", 100),
                                    **kwargs)


# ------------------------------------------------------------------------------------------ files
@pytest.fixture(scope="module")
def exported(analytic, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("export")
    export_run(analytic.root / "run", out, pointcloud=True, mesh=True, formats=("ply", "pcd", "label"),
               split_instances=True, resolution=64, loaded=analytic.loaded, scene=analytic.scene,
               num_points=20000, command="pytest", view_surface=False)  # (see extract_analytic)
    return out


def test_export_writes_every_file(exported):
    names = {p.name for p in exported.iterdir()}
    assert {"points.ply", "points.pcd", "points.label", "points.bin", "mesh.ply", "instances.json", "classes.json",
            "metadata.json", "instances"} <= names
    assert not [n for n in names if n.startswith(".")], "no temporary files left behind"
    meta = json.loads((exported / "metadata.json").read_text())
    assert meta["frame"] == "world" and meta["lift3d_version"] == lift3d.__version__
    assert meta["command"] == "pytest" and meta["thresholds"]["points"]["density"] > 0
    np.testing.assert_allclose(np.asarray(meta["transform"])[:3, :3], np.eye(3) / WORLD_SCALE)
    classes = json.loads((exported / "classes.json").read_text())["classes"]
    assert [(c["id"], c["name"], c["isthing"]) for c in classes] == [(1, "floor", False), (2, "wall", False),
                                                                     (3, "ball", True)]


def test_points_ply_opens_in_plyfile_open3d_and_pyvista(exported):
    from plyfile import PlyData

    ply = PlyData.read(str(exported / "points.ply"))
    v = ply["vertex"].data
    types = {name: v.dtype[name] for name in v.dtype.names}
    assert types["x"] == np.float32 and types["red"] == np.uint8 and types["semantic"] == np.int32
    assert types["instance"] == np.int32 and types["confidence"] == np.float32

    import open3d as o3d

    pc = o3d.t.io.read_point_cloud(str(exported / "points.ply"))
    mine = read_labelled_ply(exported / "points.ply")
    assert pc.point["semantic"].dtype == o3d.core.int32 and pc.point["instance"].dtype == o3d.core.int32
    np.testing.assert_array_equal(pc.point["semantic"].numpy().ravel(), mine["semantic"])
    np.testing.assert_array_equal(pc.point["instance"].numpy().ravel(), mine["instance"])
    np.testing.assert_allclose(pc.point["positions"].numpy(), mine["xyz"])

    import pyvista as pv

    cloud = pv.read(str(exported / "points.ply"))
    np.testing.assert_allclose(np.asarray(cloud.points), mine["xyz"])


def test_pcd_opens_in_open3d_with_its_label_field(exported, tmp_path):
    import open3d as o3d

    mine = read_labelled_ply(exported / "points.ply")
    for path in (exported / "points.pcd", tmp_path / "ascii.pcd"):
        if path.name == "ascii.pcd":
            write_pcd(path, mine["xyz"], rgb=mine["rgb"], semantic=mine["semantic"], instance=mine["instance"],
                      confidence=mine["confidence"], binary=False)
        pc = o3d.t.io.read_point_cloud(str(path))
        np.testing.assert_array_equal(pc.point["label"].numpy().ravel(), mine["semantic"])
        np.testing.assert_array_equal(pc.point["instance"].numpy().ravel(), mine["instance"])
        np.testing.assert_array_equal(pc.point["colors"].numpy(), mine["rgb"])
        np.testing.assert_allclose(pc.point["positions"].numpy(), mine["xyz"], rtol=1e-6)
        np.testing.assert_allclose(pc.point["confidence"].numpy().ravel(), mine["confidence"], rtol=1e-6)
        ours = read_pcd(path)
        np.testing.assert_array_equal(ours["label"], mine["semantic"])
        np.testing.assert_array_equal(ours["rgb"], mine["rgb"])


def test_semantickitti_label_round_trip(exported):
    mine = read_labelled_ply(exported / "points.ply")
    sem, inst = read_semantickitti_label(exported / "points.label")
    np.testing.assert_array_equal(sem, mine["semantic"])
    np.testing.assert_array_equal(inst, mine["instance"])
    raw = np.fromfile(exported / "points.label", "<u4")
    np.testing.assert_array_equal(raw, (mine["instance"].astype(np.uint32) << 16) | mine["semantic"].astype(np.uint32))
    scan = np.fromfile(exported / "points.bin", "<f4").reshape(-1, 4)
    np.testing.assert_allclose(scan[:, :3], mine["xyz"])


def test_mesh_has_per_vertex_labels_and_instance_submeshes(exported):
    mesh = read_labelled_ply(exported / "mesh.ply")
    assert len(mesh["faces"]) > 100 and mesh["semantic"].dtype == np.int32
    assert set(np.unique(mesh["semantic"]).tolist()) <= {THING, STUFF}
    x = _normalized(mesh["xyz"])
    on_b = np.abs(np.linalg.norm(x - BALL_B[0], axis=1) - BALL_B[1]) < 0.05
    on_a = np.abs(np.linalg.norm(x - SHELL_A[0], axis=1) - SHELL_A[1]) < 0.05
    # Mesh instance ids agree with the point cloud's (A = 1, B = 2).
    assert np.bincount(mesh["instance"][on_a]).argmax() == 1
    assert np.bincount(mesh["instance"][on_b]).argmax() == 2
    subs = sorted(p.name for p in (exported / "instances").iterdir())
    assert "1_ball.ply" in subs and "2_ball.ply" in subs
    sub = read_labelled_ply(exported / "instances" / "2_ball.ply")
    assert (sub["instance"] == 2).all() and len(sub["faces"]) > 10
    import pyvista as pv

    assert pv.read(str(exported / "mesh.ply")).n_cells == len(mesh["faces"])


def test_mesh_api_without_points(analytic):
    mesh = extract_labelled_mesh(analytic.loaded, analytic.scene, resolution=48, frame="normalized")
    d_b = np.abs(np.linalg.norm(mesh.vertices - BALL_B[0], axis=1) - BALL_B[1])
    assert (d_b < 0.03).sum() > 20
    assert mesh.faces.max() < len(mesh.vertices) and mesh.instance.max() >= 2


def test_load_labelled_points_and_instances_api(exported):
    pts = lift3d.load_labelled_points(exported / "points.ply")
    same = lift3d.load_labelled_points(exported)
    np.testing.assert_array_equal(pts.instance, same.instance)
    assert pts.classes[3].name == "ball" and pts.classes[3].isthing and pts.class_name(1) == "floor"
    assert pts.metadata["frame"] == "world"
    records = lift3d.instances(exported)
    assert [r.id for r in records] == [1, 2]
    by_id = pts.instance_indices()
    for r in records:
        members = pts.xyz[by_id[r.id]]
        assert r.class_name == "ball" and r.count == len(members)
        np.testing.assert_allclose(r.centroid, members.mean(0), atol=1e-4)
        np.testing.assert_allclose(r.aabb, [members.min(0), members.max(0)], atol=1e-5)
        assert r.obb.contains(members, margin=1e-4).all()
        assert 0 < r.mean_confidence <= 1
    # The PCD loads into the same arrays.
    via_pcd = lift3d.load_labelled_points(exported / "points.pcd")
    np.testing.assert_array_equal(via_pcd.semantic, pts.semantic)


def test_readonly_output_dir_is_an_input_error_naming_it(tmp_path, monkeypatch):
    target = tmp_path / "locked"
    target.mkdir()
    with _read_only(target, monkeypatch):
        with pytest.raises(InputError) as err:
            check_writable(target, folder=True)
    assert str(target) in str(err.value) and "not writable" in str(err.value)


@contextlib.contextmanager
def _read_only(folder: Path, monkeypatch):
    """Make ``folder`` unwritable: chmod for ordinary users; root ignores modes, so ``chattr +i`` (or, where
    the filesystem refuses, a patched ``mkstemp`` that fails as a read-only folder would)."""
    if os.geteuid() != 0:
        folder.chmod(0o555)
        try:
            yield
        finally:
            folder.chmod(0o755)
        return
    chattr = shutil.which("chattr")
    if chattr and subprocess.run([chattr, "+i", str(folder)], capture_output=True).returncode == 0:
        try:
            yield
        finally:
            subprocess.run([chattr, "-i", str(folder)], capture_output=True)
        return
    import tempfile

    real = tempfile.mkstemp

    def refuse(*args, dir=None, **kwargs):
        if dir is not None and Path(dir) == folder:
            raise PermissionError(13, "Permission denied")
        return real(*args, dir=dir, **kwargs)

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    yield


def test_failed_write_leaves_no_partial_file(analytic, tmp_path, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    (out / "points.ply").write_bytes(b"previous complete file")
    import lift3d.utils.atomic as atomic

    def disk_full(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(atomic.os, "fsync", disk_full)
    with pytest.raises(InputError, match="points.ply"):
        export_run(analytic.root / "run", out, loaded=analytic.loaded, scene=analytic.scene, num_points=2000,
                   view_surface=False,
                   formats=("ply", "pcd"))
    assert (out / "points.ply").read_bytes() == b"previous complete file"
    assert sorted(p.name for p in out.iterdir()) == ["points.ply"], "no temporary or partial files"


# ------------------------------------------------------------------------------------------ CLI end to end
def test_cli_end_to_end(tiny_run, tmp_path, capsys):
    from lift3d.cli.main import main

    out = tmp_path / "export"
    rc = main(["export", "--run", str(tiny_run), "--pointcloud", "--mesh", "--format", "ply", "pcd", "label",
               "--num-points", "4000", "--resolution", "32", "--min-points", "20", "--voxel-size", "0.02",
               "--output-dir", str(out), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    assert "lift3d export: wrote" in capsys.readouterr().out
    pts = lift3d.load_labelled_points(out)
    records = lift3d.instances(out)
    assert 0 < len(pts) <= 4000
    ids = np.unique(pts.instance[pts.instance > 0])
    assert ids.tolist() == list(range(1, len(ids) + 1)) == [r.id for r in records]
    assert all(r.count >= 20 for r in records)
    meta = json.loads((out / "metadata.json").read_text())
    assert meta["source_run"]["path"] == str(tiny_run.resolve()) and meta["options"]["min_points"] == 20
    assert meta["command"].startswith("lift3d ")
    # the scene's depth maps judge the points: every training frame's map took part
    sensor = next(r for r in meta["steps"]["points"] if r["name"] == "sensor-surface")
    train_frames = load_scene(meta["source_run"]["scene"]).split("train")
    assert sensor["ran"] and sensor["counts"]["depth_maps"] == len(train_frames)
    gt = read_labelled_ply(load_scene(meta["source_run"]["scene"]).gt_points_path)
    assert np.linalg.norm(pts.xyz.mean(0) - gt["xyz"].mean(0)) < np.linalg.norm(np.ptp(gt["xyz"], 0))


def test_a_room_from_images_alone_keeps_its_field_and_export_inside_its_scene_box(tiny_run, tmp_path):
    """From images alone the run records the scene's box grown by its pad (config.yml), the loaded field has no
    density outside it, and the exported points lie in it (up to the isosurface's voxel, where the contour
    crosses the box's face). With a depth map in every training frame the rays run to the cube, as before."""
    from lift3d.synth import SynthOptions, make_scene
    from lift3d.train.trainer import train

    with_depth = lift3d.load_run(tiny_run, "cpu")
    assert with_depth.cfg.scene["render_box"]["normalized"] is None
    assert "depth map" in with_depth.cfg.scene["render_box"]["why"] and not with_depth.model.field.space.box.numel()
    make_scene(tmp_path / "scene",
               SynthOptions(kind="indoor", seed=0, noise="moderate", n_views=8, width=32, height=32, depth="none"),
               progress=False)
    result = train(tmp_path / "scene", preset="fast", output_dir=tmp_path / "runs", progress=False,
                   print_summary=False, overrides={
                       "optim": {"steps": 15}, "losses": {"feature": 0.0}, "data": {"patch_size": 0, "rays_per_image": 128},
                       "field": {"grid": {"resolution_cap": 48}},
                       "trainer": {"eval_every": 0, "eval_images": 0, "checkpoint_every": 0}})
    loaded = lift3d.load_run(result.run.path, "cpu")
    scene = loaded.scene()
    box = loaded.cfg.scene["render_box"]
    assert "scene_box" in box["why"]
    aabb = np.asarray(scene.scene_box.aabb)
    pad = loaded.cfg.field.scene_box_pad * np.linalg.norm(aabb[1] - aabb[0])
    assert pad > 0
    np.testing.assert_allclose(box["normalized"], loaded.norm.to_normalized(aabb + [[-pad] * 3, [pad] * 3]))
    space = loaded.model.field.space
    np.testing.assert_allclose(space.box.numpy(), box["normalized"], rtol=1e-6)
    lo, hi = (torch.as_tensor(b) for b in box["normalized"])
    outside = torch.stack([(lo + hi) / 2 + torch.tensor([0.0, 0.0, 1.0]) * ((hi - lo)[2] / 2 + 0.01)])
    assert not bool(space(outside)[1].any())
    pts = extract_labelled_points(loaded, scene, num_points=4000)
    assert pts.record("sensor-surface")["why"] == "no training frame has a depth map"
    voxel = 2.0 / loaded.norm.scale / pts.thresholds["surface_resolution"]
    assert np.all(pts.xyz >= aabb[0] - pad - 1.5 * voxel) and np.all(pts.xyz <= aabb[1] + pad + 1.5 * voxel)


def test_cli_fill_switches_reach_the_point_export(tiny_run, tmp_path, monkeypatch):
    import lift3d.export.pointcloud as pointcloud
    from lift3d.cli.main import main

    seen = []

    def fake(loaded, scene, points, **kwargs):
        seen.append((points.step("box-fill").enabled, points.step("thing-fill").enabled))
        raise InputError("fake", "stop here")

    monkeypatch.setattr(pointcloud, "extract_labelled_points", fake)
    for flags, expected in (([], (True, True)), (["--no-box-fill"], (False, True)), (["--no-thing-fill"], (True, False))):
        assert main(["export", "--run", str(tiny_run), "--pointcloud", "--output-dir", str(tmp_path / "out"),
                     "--quiet", *flags]) == 2
        assert seen[-1] == expected


def test_cli_errors_are_one_line(tiny_run, tmp_path, capsys):
    from lift3d.cli.main import main

    assert main(["export", "--run", str(tiny_run), "--output-dir", str(tmp_path)]) == 2
    assert "give --pointcloud and/or --mesh" in capsys.readouterr().err
    assert main(["export", "--run", str(tmp_path / "nope"), "--pointcloud", "--output-dir", str(tmp_path)]) == 2
    assert main(["export", "--run", str(tiny_run), "--pointcloud", "--obb-center", "0", "0", "0",
                 "--output-dir", str(tmp_path)]) == 2
    assert "--obb-scale" in capsys.readouterr().err


def test_benchmark_export_reports_time_and_memory(tiny_run, tmp_path):
    from lift3d.export.pointcloud import benchmark_export

    result = benchmark_export(tiny_run, num_points=3000, output_dir=tmp_path / "not" / "yet")
    assert result["points"] > 0 and result["seconds"] > 0 and result["peak_rss_mb"] > 50
    assert result["seconds"] >= result["extract_seconds"] > 0
    assert {"threshold", "isosurface", "visibility", "heads", "instances"} <= set(result["stages"])
