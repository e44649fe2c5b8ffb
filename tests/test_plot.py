"""lift3d plot: the palette, 3D pictures (pixel colours at known projections), run and benchmark charts, CLI.

Everything renders off-screen (VTK without a display, matplotlib Agg); windows only in the --show smoke test,
which needs a display (``tests/interop.py``: skipped without one, failed under CI, where ``.ci/run`` runs the
suite under xvfb-run).
"""

from __future__ import annotations

import colorsys
import json
import os
from dataclasses import dataclass

import imageio.v3 as iio
import numpy as np
import pytest

from lift3d.cli.main import main
from lift3d.data.ply import write_labelled_ply
from lift3d.errors import InputError
from lift3d.viz import bench as vbench
from lift3d.viz import palette, points, run as vrun
from lift3d.data.categories import Category, as_class_table, read_class_table
from lift3d.viz.palette import INSTANCE_NONE, instance_color, panoptic_color, semantic_color
from interop import require_display

CLASSES = [
    {"id": 1, "name": "floor", "isthing": 0, "color": [152, 223, 138]},
    {"id": 3, "name": "chair", "isthing": 1, "color": [188, 189, 34]},
    {"id": 4, "name": "table", "isthing": 1, "color": [255, 127, 14]},
]
# Deliberately not 1 and 2: a categorical colour map would colour them by rank, the palette by id.
ID_A, ID_B = 7, 12
CENTER_A, CENTER_B = np.array([-1.0, 0.0, 0.2]), np.array([1.0, 0.0, 0.2])


def _cube(center, half=0.2, n=9):
    g = np.linspace(-half, half, n)
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) + center


def _two_instance_cloud():
    """A stuff floor (z = 0) with two well-separated dense cubes of points: instance 7 (chair), 12 (table)."""
    fx, fy = np.meshgrid(np.linspace(-2, 2, 41), np.linspace(-1, 1, 21), indexing="ij")
    floor = np.stack([fx.ravel(), fy.ravel(), np.zeros(fx.size)], -1)
    a, b = _cube(CENTER_A), _cube(CENTER_B)
    xyz = np.concatenate([floor, a, b]).astype(np.float32)
    semantic = np.concatenate([np.full(len(floor), 1), np.full(len(a), 3), np.full(len(b), 4)]).astype(np.int32)
    instance = np.concatenate([np.zeros(len(floor)), np.full(len(a), ID_A), np.full(len(b), ID_B)]).astype(np.int32)
    return {"xyz": xyz, "semantic": semantic, "instance": instance}


@pytest.fixture
def export_dir(tmp_path):
    """points.ply + classes.json + instances.json as `lift3d export` writes them."""
    d = tmp_path / "export"
    cloud = _two_instance_cloud()
    write_labelled_ply(d / "points.ply", cloud["xyz"], semantic=cloud["semantic"], instance=cloud["instance"],
                       confidence=np.ones(len(cloud["xyz"]), np.float32))
    (d / "classes.json").write_text(json.dumps(CLASSES))
    records = []
    for inst_id, cls, name, c in ((ID_A, 3, "chair", CENTER_A), (ID_B, 4, "table", CENTER_B)):
        records.append({"id": inst_id, "class_id": cls, "class_name": name, "count": 729, "centroid": c.tolist(),
                        "aabb": {"min": (c - 0.2).tolist(), "max": (c + 0.2).tolist()},
                        "obb": {"center": c.tolist(), "rotation": np.eye(3).tolist(), "extent": [0.4, 0.4, 0.4]},
                        "mean_confidence": 1.0})
    (d / "instances.json").write_text(json.dumps(records))
    return d


def _pixel(img, renderer, world):
    """Pixel (row, col) of a world point in a screenshot: VTK's own projection of the renderer's camera."""
    from vtkmodules.vtkRenderingCore import vtkCoordinate

    coord = vtkCoordinate()
    coord.SetCoordinateSystemToWorld()
    coord.SetValue(*(float(v) for v in world))
    x, y = coord.GetComputedDisplayValue(renderer)
    return img.shape[0] - 1 - int(y), int(x)  # display y grows upwards, image rows downwards


def _patch(img, rc, r=2):
    return img[rc[0] - r: rc[0] + r + 1, rc[1] - r: rc[1] + r + 1].reshape(-1, 3)


def _not_blank(img, background=(255, 255, 255)):
    differs = np.any(img[..., :3] != np.asarray(background, np.uint8), axis=-1)
    return differs.mean(), float(img[..., :3].astype(float).std())


# ------------------------------------------------------------------------------------------ palette
def test_instance_colors_depend_on_the_id_only_and_match_render_previews():
    ids = np.arange(1, 300)
    colors = instance_color(ids)
    # Independent reference: the documented formula through the standard library.
    for k in (1, 2, 7, 12, 255, 299):
        h, s, v = (k * 0.6180339887498949) % 1.0, 0.65 + 0.35 * ((k * 7) % 3) / 2.0, 0.75 + 0.25 * ((k * 5) % 2)
        assert colors[k - 1].tolist() == np.round(np.array(colorsys.hsv_to_rgb(h, s, v)) * 255).astype(int).tolist()
    # Same colour whatever else is in the array, in whatever order (no categorical re-spreading).
    assert (instance_color([12])[0] == instance_color([3, 12, 5000])[1]).all()
    assert (instance_color(np.array([[12, 7]]))[0] == instance_color(12)[0]).all()
    # lift3d render's instance_vis previews use the same colours: an object looks the same in 2D and 3D.
    from lift3d.render.output import instance_colors

    assert (instance_colors(300)[1:] == colors).all()
    # No instance → grey; instances are saturated (never mistaken for grey stuff) and neighbours differ.
    assert instance_color([0, -3]).tolist() == [list(INSTANCE_NONE)] * 2
    hsv = np.array([colorsys.rgb_to_hsv(*(c / 255.0)) for c in colors])
    assert hsv[:, 1].min() > 0.5
    assert np.abs(colors[1:20].astype(int) - colors[:19].astype(int)).sum(1).min() > 60


def test_semantic_and_panoptic_colors_follow_the_class_table():
    table = as_class_table(CLASSES)
    assert semantic_color([3, 1, 0], table).tolist() == [[188, 189, 34], [152, 223, 138], list(palette.VOID_COLOR)]
    unknown = semantic_color([42], table)[0]
    assert (unknown == semantic_color([42], [])[0]).all() and not (unknown == instance_color(42)[0]).all()
    sem = np.array([[1, 3, 3, 0]])
    inst = np.array([[0, ID_A, ID_B, 0]])
    img = panoptic_color(sem, inst, table)
    assert img[0, 0].tolist() == [152, 223, 138]  # stuff: class colour
    assert (img[0, 1] == instance_color(ID_A)[0]).all() and (img[0, 2] == instance_color(ID_B)[0]).all()
    assert img[0, 3].tolist() == [0, 0, 0]  # void
    tinted = panoptic_color(sem, inst, table, tint_stuff=True)
    assert np.abs(tinted[0, 0].astype(int) - np.array(INSTANCE_NONE)).sum() < np.abs(
        img[0, 0].astype(int) - np.array(INSTANCE_NONE)).sum()


def test_class_tables_are_read_and_checked(tmp_path):
    (tmp_path / "classes.json").write_text(json.dumps(CLASSES))
    assert read_class_table(tmp_path / "classes.json")[1] == Category(3, "chair", True, (188, 189, 34))
    (tmp_path / "t.json").write_text(json.dumps({"categories": CLASSES}))  # a transforms.json-like table
    assert len(read_class_table(tmp_path / "t.json")) == 3
    (tmp_path / "bad.json").write_text(json.dumps([{"id": 1, "color": [300, 0, 0]}]))
    with pytest.raises(InputError, match="color"):
        read_class_table(tmp_path / "bad.json")
    (tmp_path / "junk.json").write_text("{nope")
    with pytest.raises(InputError, match="JSON"):
        read_class_table(tmp_path / "junk.json")


# ------------------------------------------------------------------------------------------ 3D pictures
def test_rendered_pixels_carry_the_palette_colours_at_projected_centres():
    cloud = _two_instance_cloud()
    pl = points.plot_instances(cloud, points.PlotStyle(window_size=(480, 200)), classes=CLASSES, view="top")
    try:
        img = np.asarray(pl.screenshot(None, return_img=True))[..., :3]
        assert img.shape == (200, 480, 3)
        inst_view, class_view = pl.renderers[0], pl.renderers[1]
        assert class_view.camera is inst_view.camera  # linked: both views always show the same angle
        for center, inst_id, cls in ((CENTER_A, ID_A, 3), (CENTER_B, ID_B, 4)):
            want_inst = instance_color(inst_id)[0]
            want_cls = semantic_color(cls, as_class_table(CLASSES))[0]
            rc = _pixel(img, inst_view, center)
            assert rc[1] < 480 * 0.42, "the instance view is the left panel"
            assert (_patch(img, rc) == want_inst).all(axis=1).mean() > 0.8, (rc, _patch(img, rc)[:3])
            rc = _pixel(img, class_view, center)
            assert (_patch(img, rc) == want_cls).all(axis=1).mean() > 0.8, (rc, _patch(img, rc)[:3])
        # The two instances project to opposite sides (A at x = -1 left of B at x = +1).
        assert _pixel(img, inst_view, CENTER_A)[1] < _pixel(img, inst_view, CENTER_B)[1]
        # The floor between them is stuff: grey-ish in the instance view (never an instance colour).
        floor = _patch(img, _pixel(img, inst_view, (0.0, 0.0, 0.0)))[0]
        assert not any((floor == instance_color(i)[0]).all() for i in (ID_A, ID_B))
        assert int(floor.max()) - int(floor.min()) < 60
    finally:
        pl.close()
    # The same id keeps its colour in another picture with other ids around it.
    only_b = {k: v[cloud["instance"] != ID_A] for k, v in cloud.items()}
    only_b["instance"] = np.where(only_b["instance"] == ID_B, ID_B, 0)
    pl = points.plot_instances(only_b, points.PlotStyle(window_size=(480, 200)), classes=CLASSES, view="top")
    try:
        img = np.asarray(pl.screenshot(None, return_img=True))[..., :3]
        rc = _pixel(img, pl.renderers[0], CENTER_B)
        assert (_patch(img, rc) == instance_color(ID_B)[0]).all(axis=1).mean() > 0.8
    finally:
        pl.close()


def test_save_views_writes_pngs_of_the_requested_size(export_dir, tmp_path):
    out = tmp_path / "pics"
    paths = points.save_views(export_dir / "points.ply", out, ["iso", "front"],
                              points.PlotStyle(boxes=True, window_size=(360, 180)))
    assert [p.name for p in paths] == ["points_iso.png", "points_front.png"]
    for p in paths:
        img = iio.imread(p)
        assert img.shape[:2] == (180, 360)
        covered, spread = _not_blank(img)
        assert covered > 0.03 and spread > 10
    # classes.json beside the file gave the class colours: the chair colour is in the picture.
    img = iio.imread(paths[0])[..., :3]
    assert (img == np.array([188, 189, 34], np.uint8)).all(-1).sum() > 20


def test_mesh_renders_with_per_vertex_colours(tmp_path):
    import pyvista as pv

    box = pv.Box(bounds=(-0.3, 0.3, -0.3, 0.3, 0.0, 0.6), level=4, quads=False).triangulate()
    plane = pv.Plane(center=(0, 0, 0), i_size=3, j_size=2, i_resolution=12, j_resolution=8).triangulate()
    faces = np.concatenate([box.faces.reshape(-1, 4)[:, 1:], plane.faces.reshape(-1, 4)[:, 1:] + box.n_points])
    xyz = np.concatenate([box.points, plane.points])
    sem = np.r_[np.full(box.n_points, 3), np.full(plane.n_points, 1)]
    inst = np.r_[np.full(box.n_points, ID_A), np.zeros(plane.n_points)]
    write_labelled_ply(tmp_path / "mesh.ply", xyz, semantic=sem, instance=inst, faces=faces)
    geom = points.as_geometry(tmp_path / "mesh.ply")
    assert geom.is_mesh and len(geom.faces) == len(faces)
    pl = points.plot_instances(tmp_path / "mesh.ply", points.PlotStyle(window_size=(400, 200)), classes=CLASSES,
                               view="top")
    try:
        img = np.asarray(pl.screenshot(None, return_img=True))[..., :3].astype(float)
        patch = _patch(img, _pixel(img, pl.renderers[0], (0.0, 0.0, 0.6)))
    finally:
        pl.close()
    # Lit surfaces scale the colour; its chromaticity (r:g:b) stays the palette's.
    want = instance_color(ID_A)[0].astype(float)
    got = patch.mean(0)
    assert np.abs(got / got.sum() - want / want.sum()).max() < 0.04, (got, want)


def test_inputs_other_than_files(tmp_path):
    cloud = _two_instance_cloud()

    @dataclass
    class ExportedPoints:  # stands in for the export API's dataclass
        xyz: np.ndarray
        semantic: np.ndarray
        instance: np.ndarray
        confidence: np.ndarray

    obj = ExportedPoints(cloud["xyz"], cloud["semantic"], cloud["instance"], np.ones(len(cloud["xyz"])))
    assert (points.as_geometry(obj).instance == cloud["instance"]).all()
    import pyvista as pv

    poly = pv.PolyData(cloud["xyz"])
    poly.point_data["instance"] = cloud["instance"]
    g = points.as_geometry(poly)
    assert (g.instance == cloud["instance"]).all() and not g.has_semantic and not g.is_mesh
    with pytest.raises(InputError, match="semantic has 2 values"):
        points.as_geometry({"xyz": np.zeros((3, 3)), "semantic": [1, 2]})
    with pytest.raises(InputError, match=r"\[N, 3\]"):
        points.as_geometry(np.zeros((4, 2)))


def _turned_room(turn_deg: float, up: str = "z"):
    """A 4 × 4 × 2.5 m room of stuff (walls as point lines, floor and ceiling as grids) turned about the up axis,
    and a thing in its middle; axes swapped to put ``up`` where it says."""
    t = np.radians(turn_deg)
    turn = np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])
    s, h = np.linspace(-2, 2, 41), np.linspace(0, 2.5, 11)
    ss, hh = [a.ravel() for a in np.meshgrid(s, h)]
    walls = {"near": np.c_[np.full_like(ss, 2), ss, hh], "far": np.c_[np.full_like(ss, -2), ss, hh],
             "left": np.c_[ss, np.full_like(ss, 2), hh], "right": np.c_[ss, np.full_like(ss, -2), hh]}
    gx, gy = [a.ravel() for a in np.meshgrid(s, s)]
    parts = {**walls, "floor": np.c_[gx, gy, np.zeros_like(gx)], "ceiling": np.c_[gx, gy, np.full_like(gx, 2.5)],
             "thing": np.array([[0.0, 0, 0.5], [0.2, 0, 0.7]])}
    names = np.concatenate([[k] * len(v) for k, v in parts.items()])
    xyz = np.concatenate(list(parts.values())) @ turn.T
    view = turn @ np.array([1.0, 0.0, 0.6])  # from outside the near wall, above
    if up == "-y":  # z-up → -y-up: (x, y, z) → (x, -z, y)
        swap = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
        xyz, view = xyz @ swap.T, swap @ view
    return xyz, np.where(names == "thing", 7, 0), names, view


@pytest.mark.parametrize("turn_deg,up", [(0.0, "z"), (45.0, "z"), (30.0, "-y")])
def test_the_cutaway_takes_the_near_wall_of_a_room_turned_about_its_up_axis(turn_deg, up):
    # A capture keeps its own world frame and a room need not be a box along the axes: cutting only the faces of
    # the axis-aligned bounding box left most of a near wall turned 45° standing in front of the room (it took
    # 31 % of it, near the corners).
    xyz, inst, names, view = _turned_room(turn_deg, up)
    keep = points.cutaway_mask(xyz, inst, view, up=up)
    cut = {k: 1 - keep[names == k].mean() for k in np.unique(names)}
    assert cut["near"] > 0.95 and cut["ceiling"] > 0.95
    # of the far wall only the top row goes, with the ceiling it meets
    assert cut["far"] <= 1 / 11 + 1e-9 and cut["thing"] == 0 and cut["floor"] < 0.2


def test_cutaway_and_hide():
    xyz = np.array([[0, 0, 0], [0, 0, 1.0], [0, 0, 0.5], [0, 0, 1.0], [-1, 0, 0.5], [1, 0, 0.5]])
    inst = np.array([0, 0, 0, 5, 0, 0])
    # From above: the stuff at the top ("ceiling") goes, the instance at the same height stays.
    assert points.cutaway_mask(xyz, inst, (0, 0, 1)).tolist() == [True, False, True, True, True, True]
    # From +x: the stuff wall at +x goes, the far wall stays.
    assert points.cutaway_mask(xyz, inst, (1, 0, 0)).tolist() == [True, True, True, True, True, False]
    cloud = _two_instance_cloud()
    with pytest.raises(InputError, match="unknown class 'sofa'"):
        points.plot_instances(cloud, points.PlotStyle(hide=("sofa",)), classes=CLASSES)
    with pytest.raises(InputError, match="nothing to draw"):
        points.plot_instances(cloud, points.PlotStyle(hide=("floor", "chair", "4")), classes=CLASSES)


def test_boxes_from_instances_json_and_computed(export_dir):
    boxes = points.read_instance_boxes(export_dir / "instances.json")
    assert [b.id for b in boxes] == [ID_A, ID_B]
    assert np.allclose(boxes[0].corners().min(0), CENTER_A - 0.2)
    computed = points.instance_boxes(points.as_geometry(export_dir / "points.ply"))
    assert [(b.id, b.class_id) for b in computed] == [(ID_A, 3), (ID_B, 4)]
    assert np.allclose(computed[1].corners().max(0), CENTER_B + 0.2, atol=1e-6)
    # Box lines are drawn in the instance colour: a box larger than its points puts that colour where,
    # without boxes, there is only background (the middle of a vertical edge, beside the cube).
    big = points.InstanceBox(ID_A, 3, "chair", CENTER_A, np.eye(3), np.array([0.8, 0.8, 0.8]))
    edge_middle = CENTER_A + np.array([-0.4, -0.4, 0.0])
    found = []
    for with_boxes in (False, True):
        style = points.PlotStyle(boxes=with_boxes, window_size=(400, 200))
        pl = points.plot_instances(export_dir / "points.ply", style, instances=[big], view="front")
        img = np.asarray(pl.screenshot(None, return_img=True))[..., :3]
        found.append(bool((_patch(img, _pixel(img, pl.renderers[0], edge_middle), 1) == instance_color(ID_A)[0])
                          .all(-1).any()))
        pl.close()
    assert found == [False, True]
    (export_dir / "broken.json").write_text(json.dumps([{"id": 1}]))
    with pytest.raises(InputError, match="obb or aabb"):
        points.read_instance_boxes(export_dir / "broken.json")


def test_turntable_gif(export_dir, tmp_path):
    path = points.save_turntable(export_dir / "points.ply", tmp_path / "spin.gif",
                                 points.PlotStyle(window_size=(200, 100)), frames=4)
    frames = iio.imread(path, index=None)
    assert frames.shape[:3] == (4, 100, 200)
    assert not np.array_equal(frames[0], frames[1])  # the camera moved
    assert not list(tmp_path.glob(".spin*"))  # no temporary file left behind
    with pytest.raises(InputError, match="at least 2 frames"):
        points.save_turntable(export_dir / "points.ply", tmp_path / "x.gif", frames=1)


def test_mp4_without_ffmpeg_is_a_clear_error(export_dir, tmp_path):
    import importlib.util

    if importlib.util.find_spec("imageio_ffmpeg") is not None:
        pytest.skip("imageio-ffmpeg is installed: MP4 works here")
    with pytest.raises(InputError, match="imageio-ffmpeg"):
        points.save_turntable(export_dir / "points.ply", tmp_path / "spin.mp4", frames=2)


# ------------------------------------------------------------------------------------------ run pictures
def _panels(with_gt=True):
    sem = np.ones((12, 16), np.int64)
    sem[3:9, 4:12] = 3
    inst = np.where(sem == 3, ID_A, 0)
    depth = np.linspace(1, 3, 12 * 16).reshape(12, 16)
    return [vrun.FramePanels(f"frame_{k}", np.full((12, 16, 3), 90, np.uint8), np.full((12, 16, 3), 0.4), depth,
                             (sem, np.where(sem == 3, 55, 0)), (sem, inst), (sem, inst) if with_gt else None, 21.5)
            for k in range(2)]


def test_frame_grid_shows_the_panoptic_colours(tmp_path):
    path = vrun.plot_frame_grid(_panels(), CLASSES, tmp_path / "views.png", title="t")
    img = iio.imread(path)[..., :3]
    covered, spread = _not_blank(img)
    assert covered > 0.2 and spread > 20
    # Lifted panoptic and GT show instance 7 in its palette colour, exactly (nearest-neighbour upsampling);
    # the pseudo-label's own per-frame id 55 in another.
    n_a = int((img == instance_color(ID_A)[0]).all(-1).sum())
    n_55 = int((img == instance_color(55)[0]).all(-1).sum())
    assert n_a == 2 * n_55 > 0
    assert (img == np.array([152, 223, 138], np.uint8)).all(-1).sum() > 500  # floor: class colour
    no_gt = iio.imread(vrun.plot_frame_grid(_panels(with_gt=False), CLASSES, tmp_path / "v2.png"))
    assert no_gt.shape[1] < img.shape[1]  # one column fewer without ground truth


def test_training_curves(tmp_path):
    log = [{"step": s, "time": s * 0.1, "color": 1 / s, "semantic": 2 / s, "total": 1.5 / s, "psnr": 10 + s}
           for s in range(1, 11)]
    log += [{"step": 5, "eval": {"psnr": 13.0, "miou": 0.3, "pq_scene": 0.2, "against": "gt"}},
            {"step": 10, "eval": {"psnr": 16.0, "miou": 0.5, "pq_scene": 0.4, "against": "gt"}, "final": True}]
    train, evals, against = vrun.training_series(log)
    assert train["step"].tolist() == list(range(1, 11)) and "total" in train and against == "gt"
    assert evals["miou"].tolist() == [0.3, 0.5]
    img = iio.imread(vrun.plot_curves(log, tmp_path / "curves.png"))
    assert _not_blank(img)[0] > 0.05
    with pytest.raises(InputError, match="no training records"):
        vrun.plot_curves([{"step": 1, "eval": {"miou": 0.1}}], tmp_path / "c.png")


def test_plot_run_end_to_end(tiny_scene, tmp_path):
    """A tiny trained run → views.png (6 columns: the scene has GT) and curves.png, through the CLI."""
    from lift3d.train.trainer import train

    overrides = {
        "field": {"grid": {"resolution_cap": 16, "min_resolution": 8, "head_hidden_dim": 16}},
        "sampling": {"proposal_resolutions": [16], "proposal_samples": [16], "num_samples": 8},
        "data": {"images_per_batch": 2, "rays_per_image": 32, "patch_size": 4},
        "optim": {"steps": 4, "warmup_steps": 1},
        "trainer": {"eval_every": 2, "eval_images": 1, "checkpoint_every": 0, "log_every": 1},
        "losses": {"feature": 0},
    }
    result = train(tiny_scene, preset="fast", output_dir=tmp_path / "runs", overrides=overrides, progress=False,
                   print_summary=False)
    out = tmp_path / "plots"
    assert main(["plot", "--run", str(result.run.path), "--output-dir", str(out), "--device", "cpu", "--quiet",
                 "--frames", "2"]) == 0
    views, curves = iio.imread(out / "views.png"), iio.imread(out / "curves.png")
    assert _not_blank(views)[0] > 0.2 and _not_blank(curves)[0] > 0.05
    assert views.shape[1] > 2.4 * views.shape[0]  # one row (the test split has 1 frame), six columns
    # The pseudo-label's chair is drawn in the colour of its per-frame id (tiny_scene: 11 + 100 k + 7).
    assert (views[..., :3] == instance_color(11 + 100 * 5 + 7)[0]).all(-1).sum() > 100


# ------------------------------------------------------------------------------------------ benchmark
def _results():
    runs = []
    for preset, t, r, q in (("fast", 60, 30, 0.40), ("balanced", 300, 60, 0.50), ("quality", 1200, 120, 0.55)):
        for seed in (0, 1):
            runs.append({"scene": "room", "preset": preset, "seed": seed, "variant": "full", "train_seconds": t + seed,
                         "peak_rss_mb": 900, "render_ms_per_2048_rays": r, "psnr": 20 + 10 * q, "miou": q + 0.1,
                         "pq_scene": q, "sq_scene": 0.7, "rq_scene": 0.6, "pq_scene_strict": q - 0.05,
                         "points3d": {"fscore": 0.8, "miou": 0.5}, "pseudo_labels": {"miou": 0.45, "pq_scene": 0.3}})
    scaling = [{"factor": f, "value": v, "step_ms": 10 * v ** 0.5, "render_ms": 2 * v, "peak_rss_mb": 100 + v}
               for f in ("resolution", "views") for v in (16, 32, 64)]
    return {"machine": {"cpu": "test cpu", "threads": 1}, "runs": runs, "scaling": scaling}


def test_pareto_and_scaling_charts_through_the_cli(tmp_path):
    assert vbench.pareto_front([60, 300, 1200, 500], [0.4, 0.5, 0.55, 0.45]) == [0, 1, 2]
    assert vbench.power_law_exponent([16, 32, 64], [2 * 16, 2 * 32, 2 * 64]) == pytest.approx(1.0)
    bench = tmp_path / "bench"
    bench.mkdir()
    (bench / "results.json").write_text(json.dumps(_results()))
    assert main(["plot", "--bench", str(bench)]) == 0  # default output: beside results.json
    for name in ("pareto.png", "scaling.png"):
        covered, spread = _not_blank(iio.imread(bench / name))
        assert covered > 0.05 and spread > 20
    # The pseudo-label baseline is drawn (the crimson dotted line's colour is in the Pareto chart).
    img = iio.imread(bench / "pareto.png")[..., :3].astype(int)
    assert (np.abs(img - np.array([220, 20, 60])).sum(-1) < 30).sum() > 50
    assert not (bench / "noise_curves.png").exists()  # no curve runs: not drawn
    with pytest.raises(InputError, match="'runs' is missing"):
        vbench.plot_pareto({"runs": []}, tmp_path / "x.png")
    with pytest.raises(InputError, match=r"scaling\[0\]"):
        vbench.plot_scaling({"scaling": [{"value": 3}]}, tmp_path / "x.png")


def test_noise_curves_chart(tmp_path):
    def run(seed, noise="moderate", pose=(0.0, 0.0), variant="all", pq=0.6):
        return {"seed": seed, "noise": noise, "pose_noise": list(pose), "variant": variant, "miou": pq + 0.2,
                "pq_scene": pq + 0.02 * seed, "pseudo_labels": {"miou": 0.5, "pq_scene": 0.3}}
    curves = {"label_noise": [run(s, n, pq=q) for n, q in (("hard", 0.5), ("clean", 0.8), ("moderate", 0.6))
                              for s in (0, 1)],
              "pose_noise": [run(s, pose=p, variant=v, pq=0.6 - 0.1 * p[0] + (0.05 if v != "all" else 0))
                             for p in ((0.0, 0.0), (1.0, 5.0)) for v in ("all", "pose-refinement") for s in (0, 1)]}
    path = vbench.plot_noise_curves({"machine": {"cpu": "test cpu"}, "curves": curves}, tmp_path / "curves.png")
    covered, spread = _not_blank(iio.imread(path))
    assert covered > 0.05 and spread > 20
    img = iio.imread(path)[..., :3].astype(int)
    for color in ([220, 20, 60], [44, 160, 44]):  # the pseudo-label and the pose-refinement lines
        assert (np.abs(img - np.array(color)).sum(-1) < 30).sum() > 50, color
    only_labels = vbench.plot_noise_curves({"curves": {"label_noise": curves["label_noise"]}}, tmp_path / "l.png")
    assert _not_blank(iio.imread(only_labels))[0] > 0.03
    with pytest.raises(InputError, match="no label_noise or pose_noise runs"):
        vbench.plot_noise_curves({"curves": {}}, tmp_path / "x.png")


# ------------------------------------------------------------------------------------------ CLI
def test_cli_file(export_dir, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["plot", str(export_dir / "points.ply"), "--output-dir", str(out), "--views", "iso,top",
                 "--window-size", "320", "160", "--boxes", "--turntable", "--turntable-frames", "2"]) == 0
    for v in ("iso", "top"):
        assert iio.imread(out / f"points_{v}.png").shape[:2] == (160, 320)
    assert iio.imread(out / "points_turntable.gif", index=None).shape[:3] == (2, 160, 320)
    assert "points_top.png" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["plot"], "exactly one of"),
    (["plot", "missing.ply"], "file not found"),
    (["plot", "{ply}", "--views", "sideways"], "unknown view 'sideways'"),
    (["plot", "{ply}", "--run", "somewhere"], "exactly one of"),
    (["plot", "{ply}", "--window-size", "0", "10"], "--window-size"),
    (["plot", "{ply}", "--up", "w"], "--up"),
    (["plot", "--bench", "{tmp}"], "results.json: benchmark results not found"),
])
def test_cli_bad_input_is_one_line_exit_2(argv, message, export_dir, tmp_path, capsys):
    argv = [a.format(ply=export_dir / "points.ply", tmp=tmp_path) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_show_without_display_is_refused(export_dir, capsys, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    assert main(["plot", str(export_dir / "points.ply"), "--show"]) == 2
    assert "no display" in capsys.readouterr().err


def test_show_opens_a_window(export_dir, monkeypatch):
    import pyvista as pv

    require_display()

    shown = []

    def fake_show(self, *args, **kwargs):  # render once instead of blocking in the event loop
        self.render()
        shown.append(self.off_screen)

    monkeypatch.setattr(pv.Plotter, "show", fake_show)
    assert main(["plot", str(export_dir / "points.ply"), "--show", "--window-size", "300", "150"]) == 0
    assert shown == [False]


def test_headless_linux_renders_through_egl_without_probing_x(monkeypatch):
    """No display + libEGL: EGL is chosen (no "bad X server connection" warning); a display or the user's own
    choice of window class is left alone."""
    import ctypes.util
    import sys

    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: "libEGL.so.1" if name == "EGL" else None)
    for var in ("DISPLAY", "WAYLAND_DISPLAY", "VTK_DEFAULT_OPENGL_WINDOW"):
        monkeypatch.delenv(var, raising=False)
    assert points.prefer_headless_egl()
    assert os.environ["VTK_DEFAULT_OPENGL_WINDOW"] == "vtkEGLRenderWindow"
    monkeypatch.setenv("VTK_DEFAULT_OPENGL_WINDOW", "vtkOSOpenGLRenderWindow")
    assert not points.prefer_headless_egl()
    assert os.environ["VTK_DEFAULT_OPENGL_WINDOW"] == "vtkOSOpenGLRenderWindow"
    monkeypatch.delenv("VTK_DEFAULT_OPENGL_WINDOW")
    monkeypatch.setenv("DISPLAY", ":0")
    assert not points.prefer_headless_egl() and "VTK_DEFAULT_OPENGL_WINDOW" not in os.environ
    monkeypatch.delenv("DISPLAY")
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: None)
    assert not points.prefer_headless_egl()


def test_plot_takes_the_up_axis_the_export_recorded(tmp_path):
    from lift3d.viz.points import resolve_plot_up, up_beside

    ply = tmp_path / "points.ply"
    assert up_beside(ply)[0] == "z" and resolve_plot_up("auto", ply) == "z"
    (tmp_path / "metadata.json").write_text(json.dumps({"up": {"axis": [0.0, -1.0, 0.0], "reason": "cameras"}}))
    assert up_beside(ply)[0] == "-y" and resolve_plot_up("auto", ply) == "-y"
    assert resolve_plot_up("x", ply) == "x"  # the user's choice wins
    (tmp_path / "metadata.json").write_text(json.dumps({"up": {"axis": "sideways"}}))
    assert up_beside(ply)[0] == "z"
