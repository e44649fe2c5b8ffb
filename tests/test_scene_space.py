"""The scene space from the content (not the cameras), and the pose-convention check at load."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lift3d.data.cameras import Cameras, opencv_to_opengl
from lift3d.data.scene import load_scene
from lift3d.errors import InputError
from lift3d.model.normalization import ContentPoints, content_box, infer_normalization, share_outside
from lift3d.sfm.pose_check import FIXES, check_pose_convention, with_fix
from lift3d.train.scene_space import SceneGeometry, box_warnings, check_poses, scene_content


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> Path:
    """A synthetic room (sensor depth, 3D GT) whose cameras stand well inside it."""
    from lift3d.synth import SynthOptions, make_scene

    root = tmp_path_factory.mktemp("scene_space") / "room"
    make_scene(root, SynthOptions(kind="indoor", seed=5, n_views=20, width=96, height=96), progress=False)
    return root


def _without_scene_box(src: Path, dst: Path, depth: bool = True) -> Path:
    shutil.copytree(src, dst)
    meta = json.loads((dst / "transforms.json").read_text())
    meta.pop("scene_box", None)
    if not depth:
        for f in meta["frames"]:
            f.pop("depth_file_path", None)
    (dst / "transforms.json").write_text(json.dumps(meta))
    return dst


def test_box_from_depth_holds_the_room_not_just_the_cameras(room, tmp_path):
    scene = load_scene(_without_scene_box(room, tmp_path / "nobox"))
    gt = scene.gt_points()["xyz"]
    norm, why = infer_normalization(scene)
    assert norm.bounded and why.startswith("depth maps (")
    # the room's surfaces, not the cameras' spread: at most the content quantiles' tails outside
    assert share_outside(norm.aabb_world, gt) < 0.02
    cams = scene.cameras.centers
    cam_box = np.ptp(cams, axis=0)
    assert np.all(np.ptp(norm.aabb_world, axis=0) > cam_box)
    # the camera-layout rule, which ignores the content, leaves much of the room out
    no_content = load_scene(_without_scene_box(room, tmp_path / "nobox_nodepth", depth=False))
    norm_cams, why_cams = infer_normalization(no_content)
    assert why_cams.startswith("camera layout")
    assert share_outside(norm_cams.aabb_world, gt) > 0.3


def test_box_from_triangulated_points_when_there_is_no_depth(room, tmp_path):
    from lift3d.model.config import load_config

    scene = load_scene(_without_scene_box(room, tmp_path / "nodepth", depth=False))
    geometry = scene_content(scene, load_config("fast", "indoor", None))
    content, sparse = geometry.content, geometry.sparse
    assert sparse is not None and len(sparse) > 50 and content.source.startswith("points triangulated")
    # a room: the plane sweep's depths join the points (the training will use them), one map per training frame
    assert geometry.dense is not None and len(geometry.dense.depth) == len(scene.split("train"))
    assert len(content.xyz) > 10 * len(sparse)
    norm, why = infer_normalization(scene, content=content)
    assert norm.bounded and why.startswith("points triangulated")
    assert share_outside(norm.aabb_world, scene.gt_points()["xyz"]) < 0.05
    # with depth targets off, nothing is triangulated just to size the space
    off = load_config("fast", "indoor", {"losses": {"image_depth": 0.0}})
    assert scene_content(scene, off) == SceneGeometry()
    # a source that does not sweep: the sparse points alone
    sparse_only = scene_content(scene, load_config("fast", "indoor", {"image_depth": {"source": "sparse"}}))
    assert sparse_only.dense is None and len(sparse_only.content.xyz) == len(sparse)


def test_content_that_reaches_far_is_unbounded():
    rng = np.random.default_rng(0)
    cams = np.c_[np.linspace(0, 2, 10), np.zeros(10), np.zeros(10)]
    street = np.r_[rng.uniform([-5, -2, 5], [5, 2, 15], (3000, 3)), rng.uniform([-50, -5, 80], [50, 20, 200], (300, 3))]
    box, bounded, why = content_box(ContentPoints(street, "points"), cams)
    assert not bounded and "unbounded" in why
    # the foreground box holds the near content and the cameras, not the far buildings
    assert box[1, 2] < 60 and box[0, 0] <= 0 and box[1, 0] >= 2


def test_a_scene_box_that_cuts_the_content_is_reported(room, tmp_path):
    dst = tmp_path / "small_box"
    shutil.copytree(room, dst)
    meta = json.loads((dst / "transforms.json").read_text())
    lo, hi = np.asarray(meta["scene_box"]["aabb"], float)
    meta["scene_box"]["aabb"] = [lo.tolist(), (lo + 0.5 * (hi - lo)).tolist()]
    (dst / "transforms.json").write_text(json.dumps(meta))
    scene = load_scene(dst)
    from lift3d.model.normalization import depth_content

    warnings = box_warnings(scene, depth_content(scene))
    assert len(warnings) == 1 and "outside it" in warnings[0] and "%" in warnings[0]
    assert box_warnings(load_scene(room), depth_content(load_scene(room))) == []


def _cameras(scene, c2w_opencv: np.ndarray):
    return replace(scene.cameras, c2w=np.stack([opencv_to_opengl(m) for m in c2w_opencv]))


@pytest.mark.parametrize("use_depth", [True, False])
def test_pose_check_names_the_convention_mix_up(room, use_depth):
    scene = load_scene(room)
    frames = scene.split("train")
    depth = scene.depth if use_depth else None
    good = check_pose_convention(scene.cameras, frames, scene.image, depth)
    assert good.method == ("depth" if use_depth else "epipolar")
    assert good.fits and good.likely_fix is None and len(good.pairs) >= 2
    for mix_up in FIXES:  # each fix is also a mix-up a pose file can hold
        as_read = with_fix(scene.cameras.c2w_opencv, mix_up)
        wrong = check_pose_convention(_cameras(scene, as_read), frames, scene.image, depth)
        assert not wrong.fits and wrong.likely_fix is not None, (mix_up, wrong.describe())
        # the fix named undoes the mix-up (up to a rotation of the whole world, which the images cannot see)
        again = check_pose_convention(_cameras(scene, with_fix(as_read, wrong.likely_fix)), frames, scene.image, depth)
        assert again.fits, (mix_up, wrong.likely_fix, again.describe())


def test_training_stops_on_inverted_poses_with_one_line(room, tmp_path):
    dst = tmp_path / "inverted"
    shutil.copytree(room, dst)
    meta = json.loads((dst / "transforms.json").read_text())
    for f in meta["frames"]:
        f["transform_matrix"] = np.linalg.inv(np.asarray(f["transform_matrix"])).tolist()
    (dst / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(InputError) as err:
        check_poses(load_scene(dst))
    text = str(err.value)
    # transforms.json holds OpenGL camera-to-world matrices: its own matrices inverted need only inverting
    assert "transforms.json" in text and "world-to-camera" in text and "fix: invert each" in text
    assert "\n" not in text
    assert check_poses(load_scene(room))["likely_fix"] is None


# --------------------------------------------------------------------------------------- the scene's profile
def test_a_box_room_is_a_manhattan_room_that_fills_its_box(room, tmp_path):
    from lift3d.model.normalization import depth_content
    from lift3d.train.profile import choose_profile

    scene = load_scene(room)
    norm, _ = infer_normalization(scene)
    choice = choose_profile(scene, norm, depth_content(scene))
    assert choice.name == "manhattan-room" and choice.premises == ["box", "manhattan", "room"], choice.why
    ev = choice.evidence
    assert ev["floor"] and ev["walls"] >= 3 and ev["manhattan"] > 0.9 and ev["box_faces"] > 0.8
    # without a scene box the room is the same room, but no box says where its walls are
    nobox = load_scene(_without_scene_box(room, tmp_path / "nobox"))
    choice = choose_profile(nobox, infer_normalization(nobox)[0], depth_content(nobox))
    assert choice.name == "manhattan-room" and "box" not in choice.premises and "no scene_box" in choice.why
    # the user's word wins, and is recorded as such
    forced = choose_profile(scene, norm, depth_content(scene), override="open")
    assert forced.name == "open" and forced.premises == [] and forced.why.startswith("--profile open")
    with pytest.raises(InputError, match="--profile"):
        choose_profile(scene, norm, depth_content(scene), override="street")


def test_a_capture_around_an_object_and_an_unbounded_street():
    from types import SimpleNamespace as NS

    from lift3d.data.cameras import look_at
    from lift3d.model.normalization import SceneNormalization
    from lift3d.train.profile import choose_profile, cameras_up

    rng = np.random.default_rng(0)
    # a statue 0.6 m wide on a small plinth, photographed from a ring of cameras 2 m away
    statue = rng.normal([0, 0, 0.8], [0.15, 0.15, 0.3], (4000, 3))
    eyes = [[2 * np.cos(a), 2 * np.sin(a), 1.2] for a in np.linspace(0, 2 * np.pi, 24, endpoint=False)]
    c2w = np.stack([look_at(np.array(e), np.array([0.0, 0.0, 0.8])) for e in eyes])
    assert np.allclose(cameras_up(c2w), [0, 0, 1], atol=1e-6)
    cams = Cameras(c2w=c2w, fx=50.0, fy=50.0, cx=32.0, cy=32.0, width=64, height=64)
    scene = NS(cameras=cams, categories=[], scene_box=None, has_pseudo_labels=False, split=lambda s: np.arange(24))
    norm = SceneNormalization(np.zeros(3), 1.0, True, np.array([[-1, -1, 0], [1, 1, 2.0]]))
    choice = choose_profile(scene, norm, ContentPoints(statue, "points"))
    assert choice.name == "object" and choice.premises == [], choice.why
    outdoor = choose_profile(scene, SceneNormalization(np.zeros(3), 1.0, False, norm.aabb_world),
                             ContentPoints(statue, "points"))
    assert outdoor.name == "outdoor" and "unbounded" in outdoor.why


def test_training_records_the_profile_and_its_premises_reach_the_depth_targets(room, tmp_path, monkeypatch):
    import lift3d.sfm
    from lift3d.model.config import load_yaml
    from lift3d.train.trainer import train

    sweeps = []
    sweep = lift3d.sfm.plane_sweep_scene
    monkeypatch.setattr(lift3d.sfm, "plane_sweep_scene", lambda *a, **k: sweeps.append(1) or sweep(*a, **k))
    scene_dir = _without_scene_box(room, tmp_path / "images_only", depth=False)
    result = train(scene_dir, preset="fast", output_dir=tmp_path / "runs", progress=False, print_summary=False,
                   overrides={"optim": {"steps": 2}, "losses": {"feature": 0.0},
                              "field": {"grid": {"resolution_cap": 16}}, "data": {"rays_per_image": 16, "patch_size": 0},
                              "trainer": {"eval_every": 0, "eval_images": 0, "checkpoint_every": 0}})
    saved = load_yaml(result.run.config_path)["scene"]
    profile, targets = saved["profile"], saved["image_depth"]
    assert profile["name"] in ("manhattan-room", "room") and "box" not in profile["premises"], profile
    assert targets["premises"] == sorted(profile["premises"]) and targets["source"] == "planes"
    assert saved["pose_check"]["likely_fix"] is None and saved["why_bounded"].startswith("points triangulated")
    # where the time before the first step went, stage by stage
    assert set(saved["setup_seconds"]) == {"pose_check", "triangulation", "plane_sweep", "depth_targets"}
    assert len(sweeps) == 1  # the maps that sized the space are the depth targets' maps, not swept again
    assert all(v >= 0 for v in saved["setup_seconds"].values())
