"""The training views' vote on exported labels (lift3d.export.views)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lift3d.data.scene import load_scene
from lift3d.export.views import VoteRules, view_depths, view_label_counts, vote_labels, vote_point_labels
from lift3d.synth import SynthOptions, make_scene


def test_vote_needs_enough_views_a_clear_majority_and_an_allowed_class():
    classes = np.array([1, 2, 3])
    counts = np.array([[0, 3, 0],    # 3 views: class 2
                       [0, 1, 0],    # 1 view only
                       [2, 2, 0],    # no 60 % majority
                       [0, 0, 4],    # class 3, not allowed below
                       [3, 1, 0]],   # already class 1
                      np.uint16)
    semantic = np.array([1, 1, 1, 1, 1])
    new, changed = vote_labels(semantic, counts, classes, min_views=2, share=0.6)
    assert new.tolist() == [2, 1, 1, 3, 1] and changed.tolist() == [True, False, False, True, False]
    new, changed = vote_labels(semantic, counts, classes, min_views=2, share=0.6, targets=[1, 2])
    assert new.tolist() == [2, 1, 1, 1, 1]
    assert new.dtype == semantic.dtype


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    root = tmp_path_factory.mktemp("views") / "room"
    make_scene(root, SynthOptions(kind="indoor", seed=104, noise="moderate", n_views=12, width=48, height=48),
               progress=False)
    return load_scene(root)


def test_the_views_give_the_floor_back_and_a_hidden_point_gets_no_vote(room):
    gt = room.gt_points()
    xyz, sem = np.asarray(gt["xyz"], np.float64), np.asarray(gt["semantic"]).astype(np.int64)
    floor = np.isin(sem, [c.id for c in room.categories if c.name == "floor"])
    assert floor.sum() > 100
    # The field called the whole floor wall; the views (noisy 2D labels, sensor depth) disagree.
    wrong = np.where(floor, [c.id for c in room.categories if c.name == "wall"][0], sem)
    frames = room.split("train")
    new, stats = vote_point_labels(xyz, wrong, room, frames, render=None, abs_tolerance=0.03,
                                   targets=room.stuff_ids)
    assert stats["views"] == len(frames) and stats["rendered"] == 0
    depths = view_depths(room, frames, None)
    classes = np.asarray(sorted(c.id for c in room.categories), np.int64)
    votes = view_label_counts(xyz, room, depths, classes, 0.03).sum(1)
    seen = floor & (votes >= 2)
    assert seen.sum() > 0.5 * floor.sum()
    assert np.mean(new[seen] == sem[seen]) > 0.9
    # Things are never given and never taken from points the views do not see.
    assert np.array_equal(new[~floor & np.isin(sem, room.thing_ids)], wrong[~floor & np.isin(sem, room.thing_ids)])
    # A point a metre behind the room's floor is behind what every view sees there: no view votes for it.
    below = xyz[floor][:50] - np.array([0.0, 0.0, 1.0])
    assert view_label_counts(below, room, depths, classes, 0.03).sum() == 0


def test_views_without_depth_maps_are_rendered_at_one_downscale(room):
    frames = room.split("train")[:3]
    calls = []

    def render(i, ds):
        calls.append((i, ds))
        return np.ones((48 // ds, 48 // ds), np.float32)

    scene = room
    original = scene.depth
    try:
        scene.depth = lambda i: None
        depths = view_depths(scene, frames, render, max_rays=48 * 48)  # three views, one view's rays: ds = 2
    finally:
        scene.depth = original
    assert sorted(depths) == sorted(int(i) for i in frames)
    assert {ds for _, ds in calls} == {2} and all(d.shape == (24, 24) for d, _ in depths.values())
    assert view_depths(scene, frames, None) and all(ds == 1 for _, ds in view_depths(scene, frames, None).values())


def test_export_records_the_vote_for_points_and_mesh_and_can_skip_it(tiny_run, tmp_path):
    from lift3d.cli.main import main

    for flag, out in (([], tmp_path / "on"), (["--no-view-vote"], tmp_path / "off")):
        assert main(["export", "--run", str(tiny_run), "--pointcloud", "--mesh", "--resolution", "32",
                     "--num-points", "4000", "--output-dir", str(out), "--quiet", *flag]) == 0
    on, off = (json.loads((tmp_path / k / "metadata.json").read_text()) for k in ("on", "off"))
    vote, off_vote = (next(r for r in m["steps"]["points"] if r["name"] == "view-vote") for m in (on, off))
    keys = {"changed", "changes", "views", "rendered", "median_votes", "min_views", "share", "measured"}
    assert keys <= set(vote["counts"]) and keys <= set(on["thresholds"]["mesh"]["view_vote"])
    # the mesh votes within the point cloud's tolerance, whatever its own resolution
    assert on["thresholds"]["mesh"]["view_vote"]["abs_tolerance"] == pytest.approx(vote["counts"]["abs_tolerance"],
                                                                                    rel=1e-6)
    assert off_vote["why"] == "off" and "view_vote" not in off["thresholds"]["mesh"]


def test_an_export_of_points_and_mesh_renders_each_view_once_for_the_vote(tiny_run, tmp_path, monkeypatch):
    # Without depth maps the vote renders the training views; points and mesh share those renders.
    import lift3d.export.views as views
    from lift3d.export import export_run
    from lift3d.model.run import load_run

    loaded = load_run(tiny_run, "cpu")
    scene = loaded.scene()
    for frame in scene.frames:
        monkeypatch.setattr(frame, "depth_path", None)
    assert scene.depth(0) is None
    rendered = []
    render_frame = views.render_frame

    def counting(model, rays, i, *a, **k):
        rendered.append(int(i))
        return render_frame(model, rays, i, *a, **k)

    monkeypatch.setattr(views, "render_frame", counting)
    summary = export_run(tiny_run, tmp_path / "both", pointcloud=True, mesh=True, resolution=32, num_points=4000,
                         loaded=loaded, scene=scene)
    frames = sorted(int(i) for i in scene.split("train"))
    assert sorted(rendered) == frames  # once each, not once for the points and again for the mesh
    meta = json.loads((tmp_path / "both" / "metadata.json").read_text())
    vote = next(r for r in meta["steps"]["points"] if r["name"] == "view-vote")
    assert vote["counts"]["rendered"] == meta["thresholds"]["mesh"]["view_vote"]["rendered"] == len(frames)
    assert "mesh.ply" in summary["files"]


def test_a_point_the_vote_moves_to_stuff_leaves_its_instance(tiny_run, monkeypatch):
    # The vote says "floor" everywhere: every thing point becomes floor and no instance is left behind on it.
    import lift3d.export.pointcloud as pointcloud
    import lift3d.export.views as views
    from lift3d.model.run import load_run

    loaded = load_run(tiny_run, "cpu")
    scene = loaded.scene()
    floor = [c.id for c in scene.categories if c.name == "floor"][0]
    monkeypatch.setattr(views, "vote_point_labels",
                        lambda xyz, sem, *a, **k: (np.full_like(sem, floor), {"changed": int((sem != floor).sum())}))
    pts = pointcloud.extract_labelled_points(loaded, scene, num_points=4000)
    assert (pts.semantic == floor).all() and (pts.instance == 0).all()


def test_a_subsample_gives_nearly_the_same_answer(room):
    gt = room.gt_points()
    xyz, sem = np.asarray(gt["xyz"], np.float64), np.asarray(gt["semantic"]).astype(np.int64)
    wall, floor = ([c.id for c in room.categories if c.name == n][0] for n in ("wall", "floor"))
    wrong = np.where(sem == floor, wall, sem)
    frames = room.split("train")
    full, _ = vote_point_labels(xyz, wrong, room, frames, None, 0.03, targets=room.stuff_ids)
    part, stats = vote_point_labels(xyz, wrong, room, frames, None, 0.03, targets=room.stuff_ids,
                                    rules=VoteRules(max_points=len(xyz) // 4))
    assert stats["measured"] == len(xyz) // 4
    changed = full != wrong
    assert changed.sum() > 100 and np.mean(part[changed] == full[changed]) > 0.85
    assert np.mean(part == full) > 0.95


def test_auto_source_fuses_depth_only_for_streets_with_depth_in_every_training_frame(room):
    # (here beside the vote: both decide from the scene what the export does)
    from types import SimpleNamespace

    from lift3d.export.pointcloud import resolve_point_source

    def run(bounded):
        return SimpleNamespace(model=SimpleNamespace(bounded=bounded))

    assert resolve_point_source("auto", run(True), room)[0] == "surface"
    source, why = resolve_point_source("auto", run(False), room)
    assert source == "tsdf" and "depth map in every training frame" in why
    first = int(room.split("train")[0])
    original = room.frames[first].depth_path
    try:
        room.frames[first].depth_path = None
        assert resolve_point_source("auto", run(False), room)[0] == "surface"
    finally:
        room.frames[first].depth_path = original
    assert resolve_point_source("rays", run(False), room) == ("rays", "given")
    with pytest.raises(ValueError, match="--source"):
        resolve_point_source("voxels", run(True), room)
