"""``lift3d label --geometric``: structure-only labels from depth, checked against a synthetic room's GT.

The room is made here with ``lift3d.synth`` (an orbit path, so walls, floor and ceiling are all in view;
sensor depth with noise and holes). Its GT uses the scene's own classes: structure-only labels cannot tell
a rug from the floor it lies on or a window from its wall, so those GT classes count as floor and wall.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lift3d.cli.main import main as cli_main
from lift3d.data.cameras import look_at
from lift3d.data.scene import load_scene
from lift3d.errors import InputError
from lift3d.label import STAGING_DIR, label_geometric, read_label_scene, write_labels
from lift3d.label.geometric import (GEOMETRIC_CATEGORIES, GeometricSettings, camera_up_prior, fit_structure,
                                    frame_geometry)

# Measured on this room (seed 4, 12 orbit views, 96 px, sensor depth): IoU on the pixels with depth 0.972
# wall, 0.978 floor, 0.965 ceiling; 94 % of the GT objects covering >= 1 % of a frame have at least half of
# their pixels in one object segment. The same numbers in all three world orientations.
MIN_STUFF_IOU = 0.9
MIN_OBJECTS_FOUND = 0.85
#: GT classes that are the same structure as a stuff class (a rug is floor, a window is wall).
SAME_STRUCTURE = {"wall": ("wall", "window"), "floor": ("floor", "rug"), "ceiling": ("ceiling",)}


@pytest.fixture(scope="module")
def room_template(tmp_path_factory) -> Path:
    from lift3d.synth import SynthOptions, make_scene

    root = tmp_path_factory.mktemp("geometric") / "room"
    make_scene(root, SynthOptions(seed=4, n_views=12, width=96, height=96, camera_path="orbit"), progress=False)
    return root


@pytest.fixture
def room(room_template, tmp_path) -> Path:
    dst = tmp_path / "room"
    shutil.copytree(room_template, dst)
    return dst


def structure_agreement(root: Path) -> tuple[dict[str, float], float]:
    """Per stuff class IoU with the GT (pixels with input depth), and the share of GT objects of at least 1 %
    of a frame that have at least half of their pixels in one object segment."""
    scene = load_scene(root)
    ids = {c.name: c.id for c in scene.categories}
    inter = dict.fromkeys(SAME_STRUCTURE, 0)
    union = dict.fromkeys(SAME_STRUCTURE, 0)
    found = []
    for i in range(len(scene.frames)):
        gt, ours = scene.gt_labels(i), scene.pseudo_labels(i)
        has_depth = scene.depth(i) > 0
        for kind, gt_names in SAME_STRUCTURE.items():
            g = np.isin(gt.semantic, [ids[n] for n in gt_names])
            p = ours.semantic == ids[kind]
            inter[kind] += int((g & p & has_depth).sum())
            union[kind] += int(((g | p) & has_depth).sum())
        objects = (ours.semantic == ids["object"]) & (ours.instance > 0)
        for inst in np.unique(gt.instance[gt.instance > 0]):
            mask = gt.instance == inst
            if mask.sum() < 0.01 * mask.size:
                continue
            segs, counts = np.unique(ours.instance[mask & objects], return_counts=True)
            found.append(counts.max(initial=0) >= 0.5 * mask.sum())
    return {k: inter[k] / max(union[k], 1) for k in inter}, float(np.mean(found))


def rotate_world(root: Path, rotation: np.ndarray) -> None:
    """Turn the whole capture: every pose (and the true ones) left-multiplied by ``rotation``."""
    meta = json.loads((root / "transforms.json").read_text())
    turn = np.eye(4)
    turn[:3, :3] = rotation
    for fr in meta["frames"]:
        for key in ("transform_matrix", "gt_transform_matrix"):
            if key in fr:
                fr[key] = (turn @ np.asarray(fr[key])).tolist()
    meta.pop("scene_box", None)  # an axis-aligned box does not turn with the scene; nothing here reads it
    (root / "transforms.json").write_text(json.dumps(meta))


# --------------------------------------------------------------------------------------------- end to end
def test_geometric_labels_agree_with_the_rooms_structure(room, capsys):
    gt_before = {p: p.read_bytes() for p in (room / "gt").rglob("*") if p.is_file()}
    rc = cli_main(["label", "--data", str(room), "--geometric"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "(from level surfaces)" in out and "pixels: void" in out
    scene = load_scene(room)
    scene.validate()
    assert {p: p.read_bytes() for p in (room / "gt").rglob("*") if p.is_file()} == gt_before
    assert not (room / STAGING_DIR).exists()

    # The scene has GT, so its 21 categories are kept (wall/floor/ceiling matched by name) and object added.
    names = {c.name: c for c in scene.categories}
    assert [names[n].id for n in ("wall", "floor", "ceiling")] == [1, 2, 3] and names["object"].isthing
    assert names["object"].id == max(c.id for c in scene.categories) == 22
    meta = json.loads((room / "transforms.json").read_text())
    lab = meta["labeller"]
    assert lab["method"] == "geometric" and lab["structure_only"] and lab["depth"] == "depth_file_path"
    assert lab["categories"] == {"wall": 1, "floor": 2, "ceiling": 3, "object": 22}
    assert lab["settings"] == GeometricSettings().to_json()
    assert np.degrees(np.arccos(np.clip(np.dot(lab["up"], [0, 0, 1]), -1, 1))) < 1.0
    kinds = [p["kind"] for p in lab["planes"]]
    assert kinds.count("floor") == 1 and kinds.count("ceiling") == 1 and kinds.count("wall") >= 4

    used = set()
    coco = json.loads((room / "panoptic.json").read_text())
    for ann in coco["annotations"]:
        stuff = [s["category_id"] for s in ann["segments_info"] if s["category_id"] != 22]
        assert len(stuff) == len(set(stuff))  # one segment per stuff class and frame
        assert all(0.0 <= s["score"] <= 1.0 for s in ann["segments_info"])
        used |= {s["category_id"] for s in ann["segments_info"]}
    assert used == {1, 2, 3, 22}

    iou, objects_found = structure_agreement(room)
    assert min(iou.values()) >= MIN_STUFF_IOU, iou
    assert objects_found >= MIN_OBJECTS_FOUND, objects_found


def test_exact_depth_kept_for_evaluation_is_used_when_there_is_no_input_depth(room):
    meta = json.loads((room / "transforms.json").read_text())
    for fr in meta["frames"]:
        fr.pop("depth_file_path")
    (room / "transforms.json").write_text(json.dumps(meta))
    report = label_geometric(room, progress=False)
    assert report["labeller"]["depth"] == "gt_depth_file_path"
    assert json.loads((room / "transforms.json").read_text())["labeller"]["depth"] == "gt_depth_file_path"
    assert report["class_shares"]["void"] < 0.01  # exact depth has no holes


@pytest.mark.parametrize("up", [(0, 0, 1), (0, 1, 0), (0, -1, 0)], ids=["z-up", "y-up", "minus-y-up"])
def test_up_direction_is_recovered_whatever_the_worlds_axes(room, up):
    rotation = Rotation.align_vectors([up], [[0, 0, 1]])[0].as_matrix()
    rotate_world(room, rotation)
    report = label_geometric(room, progress=False)
    found = np.asarray(report["labeller"]["up"])
    assert np.degrees(np.arccos(np.clip(found @ np.asarray(up, float), -1, 1))) < 1.0, found
    assert report["labeller"]["up_source"] == "level surfaces"
    iou, _ = structure_agreement(room)
    assert min(iou.values()) >= MIN_STUFF_IOU, iou


def test_given_up_direction_is_used(room):
    report = label_geometric(room, GeometricSettings(up=(0.0, 0.0, 2.0)), progress=False)
    assert report["labeller"]["up"] == [0.0, 0.0, 1.0] and report["labeller"]["up_source"] == "given"


# --------------------------------------------------------------------------------------------- errors
def test_a_frame_without_depth_is_a_one_line_error(room, capsys):
    meta = json.loads((room / "transforms.json").read_text())
    meta["frames"][2].pop("depth_file_path")
    meta["frames"][2].pop("gt_depth_file_path")
    (room / "transforms.json").write_text(json.dumps(meta))
    before = {p: p.read_bytes() for p in room.rglob("*") if p.is_file()}
    rc = cli_main(["label", "--data", str(room), "--geometric"])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "frames[2]" in err and "depth_file_path" in err
    assert {p: p.read_bytes() for p in room.rglob("*") if p.is_file()} == before


def test_depth_of_the_wrong_size_is_an_error(room):
    from lift3d.data.images import write_depth

    write_depth(room / "depth" / "frame_0003.png", np.ones((10, 10)), 1e-3)
    with pytest.raises(InputError, match="frame_0003.png: depth map is 10x10 but the image is 96x96"):
        label_geometric(room, progress=False)


def test_ground_truth_with_a_conflicting_class_is_refused(room, capsys):
    meta = json.loads((room / "transforms.json").read_text())
    for c in meta["categories"]:
        if c["name"] == "wall":
            c["isthing"] = 1
    (room / "transforms.json").write_text(json.dumps(meta))
    rc = cli_main(["label", "--data", str(room), "--geometric"])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "'wall' is thing in the scene" in err


def test_without_ground_truth_the_vocabulary_is_replaced(room):
    shutil.rmtree(room / "gt")
    meta = json.loads((room / "transforms.json").read_text())
    for fr in meta["frames"]:
        fr.pop("gt_panoptic_file_path", None)
        fr.pop("gt_depth_file_path", None)
    (room / "transforms.json").write_text(json.dumps(meta))
    label_geometric(room, progress=False)
    scene = load_scene(room)
    assert scene.categories == list(GEOMETRIC_CATEGORIES)


def test_cli_flags_cover_every_setting_with_its_default():
    from lift3d.cli.label import GEOMETRIC_FLAGS

    defaults = GeometricSettings().to_json()
    assert {name: default for name, default, *_ in GEOMETRIC_FLAGS.values()} == \
        {k: v for k, v in defaults.items() if k != "up"}  # --up is its own flag


def test_settings_are_checked():
    with pytest.raises(InputError, match="--normal-angle: must be a number in"):
        GeometricSettings(normal_angle=0.0).check()
    with pytest.raises(InputError, match="--up"):
        GeometricSettings(up=(0.0, 0.0, 0.0)).check()


def test_another_source_drops_the_geometric_record(room):
    label_geometric(room, progress=False)
    assert "labeller" in json.loads((room / "transforms.json").read_text())
    scene = read_label_scene(room)
    old = load_scene(room)

    def same_labels():
        from lift3d.data.images import read_rgb
        from lift3d.label import FrameLabels

        for frame in scene.frames:
            lab = old.pseudo_labels(frame.index)
            yield frame, read_rgb(frame.image_path), FrameLabels(
                lab.segment.astype(np.int64), list(old.frames[frame.index].segments.values()))

    write_labels(scene, old.categories, same_labels(), progress=False)
    assert "labeller" not in json.loads((room / "transforms.json").read_text())


# --------------------------------------------------------------------------------------------- pieces
def test_camera_up_prior_survives_a_downward_tilt():
    # Cameras looking 40 degrees down at points around them: their own up axes lean 40 degrees.
    eyes = [np.array([np.cos(a), np.sin(a), 1.5]) for a in np.linspace(0, 2 * np.pi, 7)[:-1]]
    c2w = np.stack([look_at(e, e + np.array([-np.cos(a), -np.sin(a), -np.tan(np.radians(40))]))
                    for e, a in zip(eyes, np.linspace(0, 2 * np.pi, 7)[:-1])])
    assert np.degrees(np.arccos(c2w[:, 2, 1].mean())) > 35  # the mean up axis is far off
    assert np.allclose(camera_up_prior(c2w), [0, 0, 1], atol=1e-6)
    # All looking the same way: the right axes say nothing, so the mean up axis is used.
    same = np.stack([look_at(e, e + np.array([1.0, 0, 0])) for e in eyes])
    assert np.allclose(camera_up_prior(same), [0, 0, 1], atol=1e-6)


def wall_scene(cabinet_top: float, window: bool):
    """Points of a room corner seen from cameras at 1.5 m: floor, a wall at x = 3 (2.5 m high), a cabinet
    front at x = 2.5 (1 m wide, ``cabinet_top`` high) and optionally a window in the wall through which
    a wall 2 m farther out is seen."""
    rng = np.random.default_rng(0)

    def patch(n, x, y, z, normal):
        pts = np.c_[np.broadcast_to(x, n) if np.isscalar(x) else x, y, z]
        return pts, np.tile(normal, (n, 1))

    floor = patch(6000, rng.uniform(-1, 3, 6000), rng.uniform(-3, 3, 6000), np.zeros(6000), [0, 0, 1.0])
    y, z = rng.uniform(-3, 3, 8000), rng.uniform(0, 2.5, 8000)
    hidden = (np.abs(y) < 0.5) & (z < cabinet_top)  # behind the cabinet
    if window:
        hidden |= (y > 1) & (y < 2) & (z > 0.8) & (z < 2.0)
    wall = patch(int((~hidden).sum()), 3.0, y[~hidden], z[~hidden], [-1.0, 0, 0])
    cabinet = patch(2000, 2.5, rng.uniform(-0.5, 0.5, 2000), rng.uniform(0, cabinet_top, 2000), [-1.0, 0, 0])
    parts = [floor, wall, cabinet]
    if window:
        parts.append(patch(1000, 5.0, rng.uniform(1.2, 1.8, 1000), rng.uniform(0.9, 1.9, 1000), [-1.0, 0, 0]))
    points = np.concatenate([p for p, _ in parts])
    normals = np.concatenate([n for _, n in parts])
    angles = np.linspace(-0.6, 0.6, 5)
    c2w = np.stack([look_at(np.array([0, 0, 1.5]), np.array([np.cos(a), np.sin(a), 1.5])) for a in angles])
    return points, normals, np.full(len(points), 3.0), c2w


def test_tall_cabinet_is_not_a_wall_but_a_wall_with_a_window_is():
    points, normals, depth, c2w = wall_scene(cabinet_top=2.0, window=True)
    s = fit_structure(points, normals, depth, c2w, GeometricSettings())
    walls = [round(p.offset, 2) for p in s.planes if p.kind == "wall"]
    assert -3.0 in walls and -2.5 not in walls  # the wall, with its window; not the cabinet
    assert s.rejected["behind"] == 1
    # A low cabinet stays below the cameras: not a wall either, for another reason.
    points, normals, depth, c2w = wall_scene(cabinet_top=1.0, window=False)
    s = fit_structure(points, normals, depth, c2w, GeometricSettings())
    assert [round(p.offset, 2) for p in s.planes if p.kind == "wall"] == [-3.0] and s.rejected["low"] == 1


def test_a_surface_at_a_grazing_angle_stays_connected():
    # A camera 1 m above an endless floor looking at the horizon: far rows differ by far more than 5 %.
    c2w = look_at(np.array([0, 0, 1.0]), np.array([0, 10, 1.0]))[None]
    from lift3d.data.cameras import Cameras

    cams = Cameras(c2w=c2w, fx=30.0, fy=30.0, cx=20.0, cy=15.0, width=40, height=30)
    rows, cols = np.mgrid[0:30, 0:40]
    o, d = cams.rays(0, cols.ravel(), rows.ravel())
    t = np.where(d[:, 2] < -1e-3, -1.0 / np.minimum(d[:, 2], -1e-3), 0.0)
    depth = (t * (d @ -c2w[0, :3, 2])).reshape(30, 40)
    depth[depth > 50] = 0.0
    geom = frame_geometry(cams, 0, depth, GeometricSettings())
    pairs = (depth[1:] > 0) & (depth[:-1] > 0)
    assert (np.abs(np.diff(depth, axis=0))[pairs] > 0.05 * depth[1:][pairs]).any()
    # Every step of a column's run is linked but its first and last (no step beyond to agree with).
    inner = pairs & np.roll(pairs, 1, axis=0) & np.roll(pairs, -1, axis=0)
    inner[[0, -1]] = False
    assert inner.sum() > 0.8 * pairs.sum() and geom.linked_down[inner].all()
    assert geom.has_normal[depth > 0].mean() > 0.9
    # A box's face 3 m away (the floor is seen from row 16 on): its top edge against the floor behind it
    # is still a discontinuity.
    boxed = depth.copy()
    boxed[18:24, 15:25] = 3.0
    cut = frame_geometry(cams, 0, boxed, GeometricSettings()).linked_down
    assert not cut[17, 15:25].any() and cut[18:23, 15:25].all() and cut[17, :10].all()
