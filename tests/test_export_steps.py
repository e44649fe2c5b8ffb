"""The export's point steps one by one, on small synthetic points (lift3d.export.steps)."""

from __future__ import annotations

import argparse
import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from lift3d.errors import InputError
from lift3d.export.points import LabelledPoints
from lift3d.export.steps import (
    POINT_STEPS,
    BoxFill,
    ConfidenceFilter,
    Crop,
    ExportStep,
    FilledJoin,
    FrameConversion,
    InstanceAssignment,
    InstanceCleanup,
    LabelHeads,
    LinkRadius,
    OutlierRemoval,
    PointState,
    StepContext,
    StuffCorners,
    StuffOrientation,
    ThingFill,
    ViewVote,
    VoxelDownsample,
    run_point_steps,
)
from lift3d.export.steps.options import add_step_flags, configure_steps, keyword_settings, steps_from_args
from lift3d.export.steps.premises import run_premises
from lift3d.model.profiles import PREMISES

SCALE = 2.0  # normalised = 2 x world (and no shift)


def _context(source="surface", stuff=(1, 2), **scene):
    norm = SimpleNamespace(scale=SCALE, matrix=np.diag([SCALE, SCALE, SCALE, 1.0]), bounded=True,
                           aabb_world=np.array([[-1.0] * 3, [1.0] * 3]))
    loaded = SimpleNamespace(norm=norm, model=SimpleNamespace(bounded=True), cfg=SimpleNamespace(scene={}))
    scene = SimpleNamespace(stuff_ids=list(stuff), split=lambda name: np.arange(3), **scene)
    return StepContext(loaded, scene, source, grid_link=0.1)


def _labelled(xyz, semantic, channel=None, **arrays):
    n = len(xyz)
    return LabelledPoints(np.asarray(xyz, np.float64), rgb=np.zeros((n, 3), np.uint8),
                          semantic=np.asarray(semantic, np.int32), confidence=np.ones(n, np.float32),
                          channel=np.zeros(n, np.int64) if channel is None else np.asarray(channel),
                          filled=np.zeros(n, bool), frame="world", **arrays)


def _plane(origin, u, v, nu, nv, step=0.05):
    a, b = np.meshgrid(np.arange(nu) * step, np.arange(nv) * step)
    return np.asarray(origin) + a.reshape(-1, 1) * np.asarray(u) + b.reshape(-1, 1) * np.asarray(v)


# ------------------------------------------------------------------------------------------ the step list
def test_every_step_is_a_documented_dataclass_with_a_unique_name():
    from lift3d.export.steps.options import step_docs

    names = [cls.name for cls in POINT_STEPS]
    assert len(set(names)) == len(names) and all(n == n.lower() and " " not in n for n in names)
    for cls in POINT_STEPS:
        assert issubclass(cls, ExportStep) and dataclasses.is_dataclass(cls) and cls.__doc__
        assert set(cls.needs) <= set(PREMISES)
        assert not cls.needs or cls.why_needed, f"{cls.name}: say why it needs {sorted(cls.needs)}"
        docs = step_docs(cls)
        assert all(docs.get(f.name) for f in dataclasses.fields(cls)), cls.name


def test_run_point_steps_records_what_ran_and_why_not():
    state = PointState(_labelled(np.zeros((4, 3)), [1, 1, 2, 2]))
    steps = [ConfidenceFilter(), StuffCorners(), ConfidenceFilter(enabled=False), ConfidenceFilter(min_confidence=0.5)]
    records = run_point_steps(steps, state, _context(), premises=frozenset())
    assert [(r.ran, r.why) for r in records] == [
        (False, "min_confidence 0: every point stays"), (False, "premise not shown: room"), (False, "off"),
        (True, "on")]
    assert records[-1].counts == {"removed": 0, "points_after": 4}
    empty = PointState(_labelled(np.zeros((0, 3)), []))
    assert ViewVote().skip(empty, _context()) == StuffCorners().skip(empty, _context()) == "no points"


# ------------------------------------------------------------------------------------------ premises
def test_premises_come_from_the_profile_the_run_recorded_or_else_from_boundedness():
    def run(scene, bounded):
        return SimpleNamespace(cfg=SimpleNamespace(scene=scene), model=SimpleNamespace(bounded=bounded))

    assert run_premises(run({}, True))[0] == {"room", "manhattan", "box"}
    assert run_premises(run(None, False))[0] == frozenset()
    recorded = run({"profile": {"name": "room", "premises": ["room"]}}, True)
    assert run_premises(recorded) == (frozenset({"room"}), "the run's profile (config.yml: scene.profile.premises)")
    assert run_premises(run({"profile": {"premises": []}}, True))[0] == frozenset()
    assert run_premises(recorded, "manhattan-room")[0] == {"room", "manhattan", "box"}
    assert run_premises(run({}, True), "outdoor") == (frozenset(), "--profile outdoor")
    with pytest.raises(InputError, match="--profile"):
        run_premises(recorded, "street")


# ------------------------------------------------------------------------------------------ flags and keywords
def test_every_setting_is_a_flag_and_the_older_flags_still_set_them():
    parser = argparse.ArgumentParser()
    add_step_flags(parser)
    flags = {a for action in parser._actions for a in action.option_strings}
    for cls in POINT_STEPS:
        for f in dataclasses.fields(cls):
            if f.name == "box" or (f.name == "enabled" and not cls.switchable):
                continue
            assert f"--{cls.name}.{f.name.replace('_', '-')}" in flags
    old = {"--no-box-fill", "--no-thing-fill", "--min-confidence", "--frame", "--obb-center", "--obb-rotation",
           "--obb-scale", "--remove-outliers", "--std-ratio", "--voxel-size", "--no-view-vote", "--no-orient-stuff",
           "--no-complete-corners", "--min-points", "--no-merge-fragments", "--crumb-points",
           "--min-instance-confidence", "--min-support-views"}
    assert old <= flags
    args = parser.parse_args(["--voxel-size", "0.05", "--no-complete-corners", "--remove-outliers", "--obb-scale",
                              "1", "2", "3", "--stuff-orientation.cone-degrees", "20", "--view-vote.enabled", "false",
                              "--frame", "normalized", "--crumb-points", "0"])
    steps = {s.name: s for s in steps_from_args(args)}
    assert steps["voxel-downsample"].voxel_size == 0.05 and not steps["stuff-corners"].enabled
    assert steps["outlier-removal"].enabled and steps["crop"].scale == (1.0, 2.0, 3.0)
    assert steps["stuff-orientation"].cone_degrees == 20.0 and not steps["view-vote"].enabled
    assert steps["frame-conversion"].frame == "normalized" and steps["instance-cleanup"].crumb_points == 0
    untouched = {s.name: s for s in steps_from_args(parser.parse_args([]))}
    assert untouched == {cls.name: cls() for cls in POINT_STEPS}


def test_python_keywords_are_the_older_flags_names():
    assert keyword_settings()["complete_corners"] == ("stuff-corners", "enabled")
    assert keyword_settings()["obb"] == ("crop", "box")
    steps = {s.name: s for s in configure_steps(min_support_views=0, merge_fragments=False, obb={"scale": (1, 1, 1)})}
    assert steps["instance-cleanup"].min_support_views == 0 and not steps["instance-cleanup"].merge
    assert steps["crop"].oriented_box().scale.tolist() == [1, 1, 1]
    with pytest.raises(TypeError, match="voxel"):
        configure_steps(voxel=0.1)
    with pytest.raises(TypeError, match="min_angl"):
        configure_steps({"stuff-corners": {"min_angl": 3}})


# ------------------------------------------------------------------------------------------ each step
def test_fills_append_their_points_flagged_and_only_on_the_surface_source(monkeypatch):
    import lift3d.export.steps.fills as fills

    calls = []

    def fake(loaded, scene, x, cams, *, cache, min_gap, rules, margin=None):
        calls.append((len(x), min_gap, rules.spacings))
        return np.ones((2, 3)), np.zeros((2, 3), np.float32), {"points": 2}

    monkeypatch.setattr(fills, "box_face_fill", fake)
    monkeypatch.setattr(fills, "thing_surface_fill", fake)
    state = PointState(LabelledPoints(np.zeros((3, 3)), filled=np.zeros(3, bool), dirs=np.zeros((3, 3), np.float32)))
    assert BoxFill().apply(state, _context()) == {"points": 2}
    ThingFill(spacings=2.0).apply(state, _context())
    assert calls == [(3, 0.1, 3.0), (5, 0.05, 2.0)]
    assert state.points.filled.tolist() == [False] * 5 + [True] * 2 and len(state.points.dirs) == 7
    assert BoxFill().skip(state, _context("tsdf")) == "the tsdf source: the surface source only"


def test_heads_label_every_point_and_keep_a_source_colour():
    class Model:
        def query_labels(self, x, dirs, progress=False):
            assert x.dtype == np.float32
            n = len(x)
            return SimpleNamespace(rgb=np.full((n, 3), 7, np.uint8), semantic=np.full(n, 2, np.int32),
                                   channel=np.arange(n), confidence=np.full(n, 0.5, np.float32))

    context = _context()
    context.loaded.model = Model()
    state = PointState(LabelledPoints(np.zeros((3, 3)), dirs=np.zeros((3, 3), np.float32)))
    assert LabelHeads().apply(state, context) == {"labelled": 3}
    assert state.points.rgb[0].tolist() == [7, 7, 7] and state.points.channel.tolist() == [0, 1, 2]
    assert state.points.dirs is None
    fused = PointState(LabelledPoints(np.zeros((2, 3)), rgb=np.ones((2, 3), np.uint8)))
    LabelHeads().apply(fused, context)
    assert fused.points.rgb.tolist() == [[1, 1, 1]] * 2


def test_confidence_filter_drops_unsure_points():
    state = PointState(_labelled(np.zeros((3, 3)), [1, 1, 1]))
    state.points.confidence = np.array([0.2, 0.6, 0.9], np.float32)
    assert ConfidenceFilter(min_confidence=0.5).apply(state, _context()) == {"removed": 1}
    assert state.points.confidence.tolist() == pytest.approx([0.6, 0.9])
    with pytest.raises(InputError, match="--min-confidence"):
        ConfidenceFilter(min_confidence=1.5).check()


def test_frame_conversion_moves_the_points_into_the_output_frame():
    state = PointState(LabelledPoints(np.array([[2.0, 0.0, -1.0]])))
    FrameConversion().apply(state, _context())
    assert state.points.frame == "world" and state.points.xyz.tolist() == [[1.0, 0.0, -0.5]]
    kept = PointState(LabelledPoints(np.array([[2.0, 0.0, -1.0]])))
    FrameConversion(frame="normalized").apply(kept, _context())
    assert kept.points.xyz.tolist() == [[2.0, 0.0, -1.0]]
    with pytest.raises(InputError, match="--frame"):
        FrameConversion(frame="camera").check()


def test_crop_keeps_the_points_inside_and_remembers_its_box():
    state = PointState(_labelled([[0, 0, 0], [0.6, 0.6, 0], [0.6, -0.6, 0]], [1, 1, 1]))
    step = Crop(scale=(2.0, 1.0, 1.0), rotation=(0.0, 0.0, np.pi / 4))
    assert step.apply(state, _context())["removed"] == 1
    assert state.points.xyz[:, 1].tolist() == [0.0, 0.6] and state.crop is not None
    assert Crop().skip(state, _context()) == "no crop box"
    with pytest.raises(InputError, match="--obb-scale"):
        Crop(center=(0.0, 0.0, 1.0)).check()


def test_outlier_removal_drops_a_stray_point():
    xyz = np.r_[_plane([0, 0, 0], [1, 0, 0], [0, 1, 0], 10, 10), [[5.0, 5.0, 5.0]]]
    state = PointState(_labelled(xyz, np.ones(len(xyz))))
    assert OutlierRemoval(enabled=True).apply(state, _context()) == {"removed": 1}
    assert len(state.points) == 100
    assert OutlierRemoval(enabled=True).skip(PointState(_labelled(xyz[:5], [1] * 5)), _context())


def test_voxel_downsample_keeps_one_point_per_voxel_and_which_were_filled():
    xyz = np.array([[0.1, 0, 0], [0.2, 0, 0], [1.5, 0, 0]])
    state = PointState(_labelled(xyz, [3, 3, 4]))
    state.points.filled = np.array([False, False, True])
    assert VoxelDownsample(voxel_size=1.0).apply(state, _context()) == {"voxels": 2}
    assert state.points.filled.tolist() == [False, True] and state.voxel_size == 1.0
    with pytest.raises(InputError, match="--voxel-size"):
        VoxelDownsample(voxel_size=-1.0).check()


def test_link_radius_is_the_largest_of_grid_spacing_and_voxel():
    state = PointState(_labelled(_plane([0, 0, 0], [1, 0, 0], [0, 1, 0], 10, 10, step=0.2), np.ones(100)))
    counts = LinkRadius().apply(state, _context())
    assert counts["grid"] == pytest.approx(0.1 / SCALE) and counts["spacing"] == pytest.approx(0.2)
    assert state.link_radius == pytest.approx(0.3)
    assert state.points.thresholds["instance_link_radius"] == state.link_radius
    state.voxel_size = 0.5
    LinkRadius().apply(state, _context())
    assert state.link_radius == 0.5


def test_view_vote_moves_points_to_stuff_and_out_of_their_instance_channel(monkeypatch):
    import lift3d.export.views as views

    seen = {}

    def vote(xyz_world, semantic, scene, frames, render, abs_tolerance, *, targets, rules):
        seen.update(tolerance=abs_tolerance, min_views=rules.min_views)
        return np.array([1, 1, 3]), {"changed": 1}

    monkeypatch.setattr(views, "vote_point_labels", vote)
    monkeypatch.setattr(views, "rendered_depth", lambda loaded, scene, cache: None)
    state = PointState(_labelled(np.zeros((3, 3)), [1, 3, 3], channel=[0, 2, 2]))
    assert ViewVote(min_views=3).apply(state, _context()) == {"changed": 1}
    assert state.points.semantic.tolist() == [1, 1, 3] and state.points.channel.tolist() == [0, 0, 2]
    assert seen == {"tolerance": pytest.approx(0.25 * 0.1 / SCALE), "min_views": 3}


def test_stuff_orientation_gives_a_floor_strip_back_to_the_floor():
    floor = _plane([0.02, 0, 0], [1, 0, 0], [0, 1, 0], 21, 21)
    wall = _plane([0, 0, 0.02], [0, 0, 1], [0, 1, 0], 41, 21)
    xyz = np.r_[floor, wall]
    sem = np.r_[np.where(floor[:, 0] < 0.1, 1, 2), np.ones(len(wall), int)]
    state = PointState(_labelled(xyz, sem), link_radius=0.1)
    counts = StuffOrientation().apply(state, _context())
    assert counts["moved"] > 0 and set(counts["moves"]) == {"1->2"} and counts["radius"] == pytest.approx(0.2)
    assert (state.points.semantic[len(floor):] == 1).all()


def test_stuff_corners_replace_a_rounded_edge_by_two_surfaces_inside_the_crop(monkeypatch):
    import lift3d.export.steps.stuff as stuff

    monkeypatch.setattr(stuff, "plane_fit_up", lambda cameras: (np.array([0.0, 0.0, 1.0]), 10.0))
    g = np.linspace(0.2, 2.0, 37)
    a, b = np.meshgrid(g, np.linspace(0.0, 2.0, 41))
    floor = np.c_[a.ravel(), b.ravel(), np.zeros(a.size)]
    wall = np.c_[np.zeros(a.size), b.ravel(), a.ravel()]
    t = np.linspace(0.0, np.pi / 2, 9)[1:-1]
    arc = np.array([[0.2 - 0.2 * np.cos(s), y, 0.2 - 0.2 * np.sin(s)] for s in t for y in b[:, 0]])
    xyz = np.r_[floor, wall, arc]
    sem = np.r_[np.full(len(floor), 2), np.full(len(wall), 1), np.full(len(arc), 1)]
    context = _context(cameras=np.zeros(3))  # the up direction is given above
    state = PointState(_labelled(xyz, sem), link_radius=0.125)
    # a plane threshold of 0.02 in a box of diagonal 2 sqrt(3)
    counts = StuffCorners(plane_threshold=0.02 / (2 * np.sqrt(3))).apply(state, context)
    assert counts["corner_planes"] == 2 and counts["points_before"] == len(xyz)
    assert len(state.points) == len(xyz) - counts["corner_points"] + counts["added"]
    cropped = PointState(_labelled(xyz, sem), link_radius=0.125, voxel_size=0.1)
    cropped.crop = Crop(center=(1.0, 1.0, 1.0), scale=(2.0, 2.0, 2.0)).oriented_box()
    StuffCorners(plane_threshold=0.02 / (2 * np.sqrt(3))).apply(cropped, context)
    keys = np.floor(cropped.points.xyz / 0.1).astype(np.int64)
    assert cropped.crop.contains(cropped.points.xyz).all() and len(np.unique(keys, axis=0)) == len(keys)


def test_instances_get_contiguous_ids_and_filled_patches_join_them():
    xyz = np.array([[0.0, 0, 0], [0.05, 0, 0], [0.2, 0, 0], [2.0, 0, 0]])
    state = PointState(_labelled(xyz, [5, 5, 5, 1], channel=[1, 1, 1, 0]), link_radius=0.1)
    state.points.filled = np.array([False, False, True, False])
    InstanceAssignment().apply(state, _context())
    assert state.points.instance.tolist() == [1, 1, 2, 0]
    assert FilledJoin().apply(state, _context()) == {"joined": 1}
    assert state.points.instance.tolist() == [1, 1, 1, 0]
    # A filled piece the field puts on another instance channel is another object: it joins only when asked to
    # ignore the channels.
    for same_channel, joined in ((True, 0), (False, 1)):
        state = PointState(_labelled(xyz, [5, 5, 5, 1], channel=[1, 1, 2, 0]), link_radius=0.1)
        state.points.filled = np.array([False, False, True, False])
        InstanceAssignment().apply(state, _context())
        assert FilledJoin(same_channel=same_channel).apply(state, _context()) == {"joined": joined}
    assert FilledJoin().skip(PointState(_labelled(xyz, [5, 5, 5, 1])), _context()) == "no filled points"
    with pytest.raises(InputError, match="--min-points"):
        InstanceAssignment(min_points=-1).check()


def test_instance_cleanup_folds_a_crumb_into_its_object():
    obj = _plane([0, 0, 0], [1, 0, 0], [0, 1, 0], 20, 20, step=0.02)
    crumb = obj[:3] + [0, 0, 0.001]
    xyz = np.r_[obj, crumb]
    state = PointState(_labelled(xyz, [5] * len(xyz)), link_radius=0.05)
    state.points.instance = np.r_[np.ones(len(obj), np.int32), np.full(3, 2, np.int32)]
    context = _context(cameras=None, pseudo_labels=None)
    step = InstanceCleanup(merge=False, min_support_views=0, keep_confirmed_views=0, crumb_points=10)
    counts = step.apply(state, context)
    assert counts["crumbs_folded"] == 1 and (state.points.instance == 1).all()
    with pytest.raises(InputError, match="--crumb-points"):
        InstanceCleanup(crumb_points=-1).check()


def test_view_surface_keeps_what_the_views_render_and_drops_what_they_see_through(monkeypatch):
    import lift3d.export.steps.filters as filters
    from lift3d.data.cameras import Cameras
    from lift3d.export.steps import ViewSurface

    # One camera at the origin looking down -z at a wall 2 units away (world = normalised / 2); its rendered
    # depth: the wall, except a hole where no ray reached opacity 0.5.
    cams = Cameras(c2w=np.eye(4)[None], fx=10.0, fy=10.0, cx=10.0, cy=10.0, width=20, height=20)
    depth = np.full((20, 20), 2.0, np.float32)
    depth[:, :5] = 0.0
    monkeypatch.setattr(filters, "view_depths", lambda scene, frames, render, own_depth: {0: (depth, 1)})
    monkeypatch.setattr(filters, "rendered_depth", lambda loaded, scene, cache: None)
    monkeypatch.setattr(filters, "train_frames", lambda scene: np.array([0]))
    on_wall, behind, in_front, in_hole = [0.0, 0.0, -2.0], [0.0, 0.0, -2.6], [0.0, 0.0, -1.2], [-1.4, 0.0, -2.5]
    world = np.array([on_wall, behind, in_front, in_hole])
    pts = _labelled(world * SCALE, [1, 1, 1, 1])  # still in normalised coordinates
    pts = dataclasses.replace(pts, frame="normalized")
    state = PointState(pts)
    ctx = _context(cameras=cams)  # grid_link 0.1 normalised: a voxel is 0.05 normalised, 0.025 world
    counts = ViewSurface(tolerance_voxels=4.0).apply(state, ctx)  # within 0.1 world units of the wall
    assert counts["removed"] == 2 and counts["tolerance"] == pytest.approx(0.1)
    np.testing.assert_allclose(state.points.xyz / SCALE, [on_wall, in_hole])  # the hole: nothing says it is wrong
    assert ViewSurface().skip(PointState(pts), _context(source="tsdf")) == "the tsdf source draws the views' surfaces already"


def test_sensor_surface_keeps_what_the_depth_maps_saw_and_their_holes():
    from lift3d.data.cameras import Cameras
    from lift3d.export.steps import SensorSurface

    # Three cameras at the origin looking down -z at a wall 2 world units away; only frame 0 has a depth map
    # (with a hole on the left), frame 1 has none and frame 2's is kept for evaluation only.
    cams = Cameras(c2w=np.repeat(np.eye(4)[None], 3, 0), fx=10.0, fy=10.0, cx=10.0, cy=10.0, width=20, height=20)
    depth = np.full((20, 20), 2.0, np.float32)
    depth[:, :5] = 0.0
    frames = [SimpleNamespace(depth_path="d0.png"), SimpleNamespace(depth_path=None),
              SimpleNamespace(depth_path=None, gt_depth_path="gt2.png")]
    ctx = _context(cameras=cams, frames=frames, depth=lambda i: depth if i == 0 else None)
    on_wall, behind, in_front, in_hole = [0.0, 0.0, -2.0], [0.0, 0.0, -2.6], [0.0, 0.0, -1.2], [-1.4, 0.0, -2.5]
    state = PointState(_labelled([on_wall, behind, in_front, in_hole], [1, 1, 1, 1]))  # world frame
    counts = SensorSurface(tolerance_voxels=4.0).apply(state, ctx)  # within 0.1 world units of the wall
    assert counts["removed"] == 2 and counts["depth_maps"] == 1 and counts["uncovered"] == 1
    assert counts["tolerance"] == pytest.approx(0.1)
    np.testing.assert_allclose(state.points.xyz, [on_wall, in_hole])  # the hole: nothing says it is wrong
    no_depth = _context(cameras=cams, frames=frames[1:] * 2, depth=lambda i: None)
    assert SensorSurface().skip(PointState(state.points), no_depth) == "no training frame has a depth map"
    with pytest.raises(InputError, match="--sensor-surface"):
        SensorSurface(min_views=0).check()
