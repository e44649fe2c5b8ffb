"""The scene folder contract (docs/scene-format.md): SceneWriter → load_scene round trips, the default
split rule, and one test per validation error, each checking that the message names the file and field."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

from lift3d.data.cameras import look_at
from lift3d.data.images import write_label_map, write_panoptic_png
from lift3d.data.scene import (Category, Frame, FrameGroundTruth, FramePseudoLabels, SceneWriter, Segment, _splits,
                               load_scene)
from lift3d.errors import InputError

H, W = 12, 16
CATEGORIES = [
    Category(1, "wall", False, (10, 20, 30)),
    Category(2, "floor", False, (40, 50, 60)),
    Category(5, "chair", True, (70, 80, 90)),  # ids need not be contiguous
    Category(9, "lamp", True, (100, 110, 120)),
]
THINGS = (5, 9)


def _pose(k: int) -> np.ndarray:
    """A camera-to-world matrix with non-trivial decimals in every entry (an exact JSON round trip)."""
    angle = 0.7 * k + 0.123
    return look_at(np.array([2.5 * np.cos(angle), 2.5 * np.sin(angle), 0.8 + 0.1 * k]), np.array([0.1, -0.2, 0.3]))


def _intrinsics(k: int) -> tuple[float, float, float, float]:
    return (15.25 + k, 14.75 + k, 7.9, 6.1 + 0.01 * k)


def _semantic_map(k: int) -> np.ndarray:
    """wall on top, floor below, a chair and a lamp; one void column."""
    sem = np.full((H, W), 1, np.int64)
    sem[H // 2 :] = 2
    sem[3:7, 2 + k : 6 + k] = 5
    sem[2:9, 10:12] = 9
    sem[:, 15] = 0
    return sem


def _read_meta(root: Path) -> dict:
    return json.loads((root / "transforms.json").read_text())


def _edit_json(path: Path, edit: Callable[[dict], None]) -> None:
    meta = json.loads(path.read_text())
    edit(meta)
    path.write_text(json.dumps(meta))  # allow_nan: NaN/Infinity poses must reach the reader


def _expect_error(call: Callable[[], object], path: Path, *fragments: str) -> InputError:
    """``call`` raises InputError whose one-line message starts with ``path`` and mentions ``fragments``."""
    with pytest.raises(InputError) as info:
        call()
    message = str(info.value)
    assert message.startswith(f"{path}: "), message
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"
    return info.value


# ------------------------------------------------------------------------------------------ round trips
def test_panoptic_layout_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    root = tmp_path / "scene"
    written: list[dict] = []
    with SceneWriter(root, CATEGORIES, depth_unit_scale_factor=1e-3) as writer:
        for k in range(3):
            sem = _semantic_map(k)
            # Per-frame arbitrary segment ids, some above 65535 to exercise the G and B channels.
            seg_of_class = {1: 70000 + k, 2: 3 + k, 5: 2**23 + 17 * k, 9: 256 + k}
            pan = np.zeros((H, W), np.int64)
            for cid, sid in seg_of_class.items():
                pan[sem == cid] = sid
            # Scores with more digits than a rounded JSON float would keep.
            segments = [Segment(sid, cid, score=float(rng.random()), iscrowd=int(cid == 9))
                        for cid, sid in seg_of_class.items()]
            gt = np.where(sem == 5, 1005, np.where(sem == 9, 1009, sem))  # scene-consistent ids
            gt_segments = [Segment(1, 1), Segment(2, 2), Segment(1005, 5, 0.25), Segment(1009, 9)]
            frame = dict(
                image=rng.integers(0, 256, (H, W, 3), dtype=np.uint8), c2w=_pose(k), intrinsics=_intrinsics(k),
                panoptic=pan, segments=segments, gt_panoptic=gt, gt_segments=gt_segments,
                depth=rng.uniform(0.2, 20.0, (H, W)),
            )
            frame["file_path"] = writer.add_frame(
                f"f{k}", frame["image"], frame["c2w"], frame["intrinsics"], labels=FramePseudoLabels(pan, segments),
                gt=FrameGroundTruth(gt, gt_segments), depth=frame["depth"],
            )
            written.append(frame)
        paths = [f["file_path"] for f in written]
        writer.set_splits(train=paths[:2], val=paths[2:], test=paths[1:])
        writer.set_scene_box("unbounded", np.array([[-1.5, -2.25, 0.125], [1.0, 2.0, 3.0]]))
        gt_xyz = rng.normal(size=(40, 3)).astype(np.float32)
        gt_sem = rng.choice([1, 2, 5, 9], 40)
        gt_inst = np.where(np.isin(gt_sem, THINGS), rng.integers(1, 2**31 - 1, 40), 0)
        writer.write_gt_points(gt_xyz, gt_sem, gt_inst)

    scene = load_scene(root)
    scene.validate()
    assert len(scene) == 3 and [f.name for f in scene.frames] == ["f0", "f1", "f2"]
    assert scene.categories == CATEGORIES
    assert scene.thing_ids == [5, 9] and scene.stuff_ids == [1, 2]
    assert {k: v.tolist() for k, v in scene.splits.items()} == {"train": [0, 1], "val": [2], "test": [1, 2]}
    assert scene.scene_box is not None and scene.scene_box.type == "unbounded"
    np.testing.assert_array_equal(scene.scene_box.aabb, [[-1.5, -2.25, 0.125], [1.0, 2.0, 3.0]])
    assert scene.has_gt and scene.has_depth
    cams = scene.cameras
    assert cams.camera_model == "PINHOLE" and not cams.has_distortion
    for k, frame in enumerate(written):
        np.testing.assert_array_equal(scene.image(k), frame["image"])
        np.testing.assert_array_equal(cams.c2w[k], frame["c2w"])  # JSON keeps float64 exactly
        assert (cams.fx[k], cams.fy[k], cams.cx[k], cams.cy[k]) == frame["intrinsics"]
        assert (cams.width[k], cams.height[k]) == (W, H)
        assert scene.frames[k].segments == {s.id: s for s in frame["segments"]}
        assert scene.frames[k].gt_segments == {s.id: s for s in frame["gt_segments"]}

        pan, sem = frame["panoptic"], _semantic_map(k)
        labels = scene.pseudo_labels(k)
        np.testing.assert_array_equal(labels.segment, pan)
        np.testing.assert_array_equal(labels.semantic, sem)
        np.testing.assert_array_equal(labels.instance, np.where(np.isin(sem, THINGS), pan, 0))
        score = {s.id: s.score for s in frame["segments"]}
        expected_conf = np.vectorize(lambda sid: score.get(sid, 0.0))(pan).astype(np.float32)
        np.testing.assert_array_equal(labels.confidence, expected_conf)
        assert all(a.dtype == np.int32 for a in (labels.semantic, labels.instance, labels.segment))
        assert labels.confidence.dtype == np.float32

        gt = scene.gt_labels(k)
        np.testing.assert_array_equal(gt.semantic, sem)
        np.testing.assert_array_equal(gt.instance, np.where(np.isin(sem, THINGS), frame["gt_panoptic"], 0))
        np.testing.assert_array_equal(gt.segment, frame["gt_panoptic"])
        np.testing.assert_array_equal(gt.confidence, np.where(sem == 5, 0.25, np.where(sem > 0, 1.0, 0.0)))

        depth = scene.depth(k)
        assert depth.dtype == np.float32
        # uint16 millimetres: off by at most half a unit (plus float32 rounding at 20 m).
        np.testing.assert_allclose(depth, frame["depth"], rtol=0, atol=0.5e-3 + 2e-6)
    points = scene.gt_points()
    np.testing.assert_array_equal(points["xyz"], gt_xyz)
    np.testing.assert_array_equal(points["semantic"], gt_sem)
    np.testing.assert_array_equal(points["instance"], gt_inst)


def test_two_png_layout_round_trip_with_confidence(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    root = tmp_path / "scene"
    written = []
    with SceneWriter(root, CATEGORIES, camera_model="OPENCV") as writer:
        for k in range(2):
            sem = _semantic_map(k)
            instance = np.zeros((H, W), np.int64)
            instance[sem == 5] = 300 + k
            instance[sem == 9] = 65535  # the largest id a 16-bit PNG holds
            instance[0, :4] = 42  # an id on stuff pixels, which the reader must drop
            confidence = rng.random((H, W))
            # Frame 1 is a low-confidence frame: every 16-bit value is ≤ 255, which must not be read
            # as an 8-bit map.
            if k == 1:
                confidence *= 0.003
            distortion = {"k1": -0.05 * (k + 1), "k2": 0.01, "p1": 0.001, "p2": -0.002, "k3": 0.0}
            writer.add_frame(f"g{k}", rng.integers(0, 256, (H, W, 3), dtype=np.uint8), _pose(k), _intrinsics(k),
                             labels=FramePseudoLabels(semantic=sem, instance=instance, confidence=confidence),
                             distortion=distortion)
            written.append((sem, instance, confidence, distortion))

    scene = load_scene(root)
    scene.validate()
    assert scene.frames[0].semantic_path is not None and scene.frames[0].panoptic_path is None
    assert scene.cameras.camera_model == "OPENCV"
    for k, (sem, instance, confidence, distortion) in enumerate(written):
        np.testing.assert_array_equal(scene.cameras.distortion[k], [distortion[n] for n in ("k1", "k2", "p1", "p2", "k3")])
        labels = scene.pseudo_labels(k)
        np.testing.assert_array_equal(labels.semantic, sem)
        is_thing = np.isin(sem, THINGS)
        np.testing.assert_array_equal(labels.instance, np.where(is_thing, instance, 0))
        # Segment ids are arbitrary, but one per (class, instance) pair and 0 exactly on void.
        assert np.array_equal(labels.segment == 0, sem == 0)
        pairs = {(int(s), int(i), int(g)) for s, i, g in zip(sem.ravel(), labels.instance.ravel(), labels.segment.ravel())}
        assert len({p[:2] for p in pairs}) == len(pairs) == len({p[2] for p in pairs})
        # 16-bit confidence maps hold round(c * 65535).
        np.testing.assert_allclose(labels.confidence, np.round(confidence * 65535) / 65535, rtol=0, atol=1e-7)


def test_panoptic_scores_multiply_with_confidence_map(tmp_path: Path) -> None:
    """λ_p = segment score × per-pixel confidence (DESIGN: ``PanopticLabels.confidence``)."""
    root = tmp_path / "scene"
    sem = _semantic_map(0)
    with SceneWriter(root, CATEGORIES) as writer:
        segments = [Segment(1, 1, 0.5), Segment(2, 2, 1.0), Segment(5, 5, 0.8), Segment(9, 9, 0.1)]
        writer.add_frame("a", np.zeros((H, W, 3), np.uint8), _pose(0), _intrinsics(0),
                         labels=FramePseudoLabels(sem, segments, confidence=np.full((H, W), 0.5)))
    labels = load_scene(root).pseudo_labels(0)
    score = np.select([sem == 1, sem == 2, sem == 5, sem == 9], [0.5, 1.0, 0.8, 0.1], 0.0)
    np.testing.assert_allclose(labels.confidence, score * 32768 / 65535, rtol=1e-6)


def test_tiny_scene_fixture_is_valid(tiny_scene: Path) -> None:
    scene = load_scene(tiny_scene)
    scene.validate()
    assert len(scene) == 6 and scene.has_gt and scene.has_depth and scene.gt_points() is not None
    assert [len(scene.split(s)) for s in ("train", "val", "test")] == [4, 1, 1]
    _expect_error(lambda: scene.split("holdout"), tiny_scene / "transforms.json", "unknown split 'holdout'")


# --------------------------------------------------------------------------------------- default splits
def _frames(n: int) -> list[Frame]:
    return [Frame(name=f"{k:04d}", file_path=f"images/{k:04d}.png", image_path=Path(f"{k:04d}.png")) for k in range(n)]


def _split_lists(meta: dict, n: int) -> dict[str, list[int]]:
    return {k: v.tolist() for k, v in _splits(meta, _frames(n), Path("transforms.json")).items()}


def test_default_split_holds_out_every_8th_frame() -> None:
    assert "every 8th frame" in (_splits.__doc__ or "")
    out = _split_lists({}, 17)
    assert out["test"] == [0, 8, 16] == out["val"]
    assert out["train"] == [k for k in range(17) if k not in (0, 8, 16)]


def test_default_split_rules_for_partial_lists() -> None:
    assert _split_lists({"test_filenames": ["images/0001.png", "images/0003.png"]}, 5)["train"] == [0, 2, 4]
    given_train = _split_lists({"train_filenames": ["images/0000.png", "images/0001.png"]}, 4)
    assert given_train["test"] == [2, 3] == given_train["val"]
    # Train holds every frame: test falls back to every len(train)//8-th train frame.
    everything = _split_lists({"train_filenames": [f"images/{k:04d}.png" for k in range(16)]}, 16)
    assert everything["test"] == [0, 2, 4, 6, 8, 10, 12, 14]
    assert _split_lists({}, 1) == {"train": [0], "test": [0], "val": [0]}
    # Entries that match no file_path are matched by stem (e.g. another extension).
    assert _split_lists({"val_filenames": ["0002.jpg"]}, 3)["val"] == [2]


def test_default_split_on_a_loaded_scene(tiny_scene: Path) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: [m.pop(f"{s}_filenames") for s in ("train", "val", "test")])
    scene = load_scene(tiny_scene)
    assert scene.split("test").tolist() == [0] and scene.split("train").tolist() == [1, 2, 3, 4, 5]


# ----------------------------------------------------------------------------------- validation errors
def test_missing_transforms_json(tiny_scene: Path) -> None:
    (tiny_scene / "transforms.json").unlink()
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", "file not found")


def test_scene_folder_not_found(tmp_path: Path) -> None:
    _expect_error(lambda: load_scene(tmp_path / "nowhere"), tmp_path / "nowhere", "scene folder not found")


def test_transforms_json_not_json(tiny_scene: Path) -> None:
    (tiny_scene / "transforms.json").write_text('{"frames": [\n  {"file_path": images/a.png}\n')
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", "not valid JSON", "line 2")


def test_transforms_json_not_an_object(tiny_scene: Path) -> None:
    (tiny_scene / "transforms.json").write_text("[1, 2]")
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", "JSON object")


@pytest.mark.parametrize("frames", ["missing", [], {"file_path": "x"}])
def test_frames_missing_or_empty(tiny_scene: Path, frames) -> None:
    def edit(meta: dict) -> None:
        if frames == "missing":
            del meta["frames"]
        else:
            meta["frames"] = frames

    _edit_json(tiny_scene / "transforms.json", edit)
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", "frames: missing or empty")


def test_missing_image_file(tiny_scene: Path) -> None:
    (tiny_scene / "images" / "frame_002.png").unlink()
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "images" / "frame_002.png",
                  "file not found", "frames[2].file_path")


@pytest.mark.parametrize("field", ["panoptic_file_path", "gt_panoptic_file_path", "depth_file_path"])
def test_missing_label_file(tiny_scene: Path, field: str) -> None:
    rel = _read_meta(tiny_scene)["frames"][3][field]
    (tiny_scene / rel).unlink()
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / rel, "file not found", f"frames[3].{field}")


def test_frame_without_file_path(tiny_scene: Path) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: m["frames"][1].pop("file_path"))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", "frames[1].file_path")


@pytest.mark.parametrize("damage", ["garbage", "truncated", "empty"])
def test_unreadable_image(tiny_scene: Path, damage: str) -> None:
    path = tiny_scene / "images" / "frame_001.png"
    data = path.read_bytes()
    path.write_bytes({"garbage": b"\x89PNG not really" * 10, "truncated": data[: len(data) // 2], "empty": b""}[damage])
    scene = load_scene(tiny_scene)  # pixels are decoded lazily
    _expect_error(lambda: scene.image(1), path, "not a readable image")
    _expect_error(scene.validate, path, "not a readable image")


def test_truncated_panoptic_png(tiny_scene: Path) -> None:
    path = tiny_scene / "panoptic" / "frame_004.png"
    path.write_bytes(path.read_bytes()[:-20])  # cut inside the image data / end chunk
    scene = load_scene(tiny_scene)
    _expect_error(lambda: scene.pseudo_labels(4), path, "not a readable image")


def test_truncated_gt_panoptic_png(tiny_scene: Path) -> None:
    path = tiny_scene / "gt" / "panoptic" / "frame_000.png"
    path.write_bytes(path.read_bytes()[:60])
    _expect_error(lambda: load_scene(tiny_scene).gt_labels(0), path, "not a readable image")


def test_panoptic_png_must_be_rgb(tiny_scene: Path) -> None:
    path = tiny_scene / "panoptic" / "frame_000.png"
    write_label_map(path, np.ones((12, 16), np.int64))
    _expect_error(lambda: load_scene(tiny_scene).pseudo_labels(0), path, "8-bit RGB")


def test_label_size_differs_from_image(tiny_scene: Path) -> None:
    path = tiny_scene / "panoptic" / "frame_002.png"
    write_panoptic_png(path, np.full((8, 10), 208, np.int64))  # a valid id of frame 2, wrong size
    _expect_error(lambda: load_scene(tiny_scene).pseudo_labels(2), path, "panoptic PNG is 10x8", "16x12")


def test_gt_and_depth_size_differs_from_image(tiny_scene: Path) -> None:
    gt_path = tiny_scene / "gt" / "panoptic" / "frame_001.png"
    write_panoptic_png(gt_path, np.ones((12, 15), np.int64))
    depth_path = tiny_scene / "depth" / "frame_001.png"
    write_label_map(depth_path, np.full((13, 16), 1000))
    scene = load_scene(tiny_scene)
    _expect_error(lambda: scene.gt_labels(1), gt_path, "GT panoptic PNG is 15x12")
    _expect_error(lambda: scene.depth(1), depth_path, "depth map is 16x13")


def test_depth_that_a_float_file_marks_unknown_reads_as_zero(tiny_scene: Path) -> None:
    """NaN, ±inf and negative markers of a float depth map (a TIFF here) are unknown, as 0 is: nothing downstream
    (scene space, depth loss, export, eval) sees them as a depth."""
    import cv2

    depth = np.full((12, 16), 2000.0, np.float32)  # the scene's unit is mm
    depth[0, :4] = [np.nan, np.inf, -np.inf, -1.0]
    cv2.imwrite(str(tiny_scene / "depth" / "frame_001.tiff"), depth)
    _edit_json(tiny_scene / "transforms.json",
               lambda m: m["frames"][1].__setitem__("depth_file_path", "depth/frame_001.tiff"))
    d = load_scene(tiny_scene).depth(1)
    assert d.dtype == np.float32 and d[0, :4].tolist() == [0.0] * 4
    assert np.isfinite(d).all() and d[1:].min() == pytest.approx(2.0)


def test_image_size_differs_from_intrinsics(tiny_scene: Path) -> None:
    def edit(meta: dict) -> None:
        meta["frames"][0]["w"] = 20

    _edit_json(tiny_scene / "transforms.json", edit)
    scene = load_scene(tiny_scene)
    _expect_error(lambda: scene.image(0), tiny_scene / "images" / "frame_000.png", "image is 16x12", "w=20, h=12")


def test_segment_ids_missing_from_segments_info(tiny_scene: Path) -> None:
    def edit(coco: dict) -> None:
        # frame_000 uses ids 8, 9, 18, 19; forget the chair (18).
        coco["annotations"][0]["segments_info"] = [s for s in coco["annotations"][0]["segments_info"] if s["id"] != 18]

    _edit_json(tiny_scene / "panoptic.json", edit)
    _expect_error(lambda: load_scene(tiny_scene).pseudo_labels(0), tiny_scene / "panoptic" / "frame_000.png",
                  "segment ids [18]", "segments_info")


def test_unknown_category_in_segments_info(tiny_scene: Path) -> None:
    def edit(coco: dict) -> None:
        coco["annotations"][1]["segments_info"][2]["category_id"] = 77

    _edit_json(tiny_scene / "panoptic.json", edit)
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "panoptic.json",
                  "annotations[1].segments_info[2].category_id", "unknown category id 77")


def test_unknown_category_in_gt_segments_info(tiny_scene: Path) -> None:
    _edit_json(tiny_scene / "gt" / "panoptic.json",
               lambda coco: coco["annotations"][0]["segments_info"][0].update(category_id=0))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "gt" / "panoptic.json",
                  "annotations[0].segments_info[0].category_id", "unknown category id 0")


def test_unknown_category_in_two_png_semantic_map(tmp_path: Path) -> None:
    root = tmp_path / "scene"
    sem = _semantic_map(0)
    sem[0, 0] = 3  # not a category (ids are 1, 2, 5, 9)
    with SceneWriter(root, CATEGORIES) as writer:
        writer.add_frame("a", np.zeros((H, W, 3), np.uint8), _pose(0), _intrinsics(0),
                         labels=FramePseudoLabels(semantic=sem))
    _expect_error(lambda: load_scene(root).pseudo_labels(0), root / "semantics" / "a.png", "unknown category ids [3]")


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), None])
def test_non_finite_pose(tiny_scene: Path, bad) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: m["frames"][2]["transform_matrix"][1].__setitem__(3, bad))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json",
                  "frames[2].transform_matrix", "not finite")


@pytest.mark.parametrize("distortion", ["scaled", "sheared", "mirrored", "bottom_row"])
def test_non_rigid_pose(tiny_scene: Path, distortion: str) -> None:
    def edit(meta: dict) -> None:
        m = np.asarray(meta["frames"][4]["transform_matrix"])
        if distortion == "scaled":
            m[:3, :3] *= 1.1
        elif distortion == "sheared":
            m[:3, :3] = m[:3, :3] @ np.array([[1.0, 0.2, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        elif distortion == "mirrored":
            m[:3, 0] *= -1
        else:
            m[3] = [0.0, 0.0, 0.1, 1.0]
        meta["frames"][4]["transform_matrix"] = m.tolist()

    _edit_json(tiny_scene / "transforms.json", edit)
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json",
                  "frames[4].transform_matrix", "not a rigid transform")


@pytest.mark.parametrize("matrix", [[[1, 0], [0, 1]], [[1, 0, 0, 0], [0, 1, 0]], "eye"])
def test_malformed_pose(tiny_scene: Path, matrix) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: m["frames"][0].__setitem__("transform_matrix", matrix))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", "frames[0].transform_matrix")


def test_three_by_four_pose_is_accepted(tiny_scene: Path) -> None:
    c2w = np.asarray(_read_meta(tiny_scene)["frames"][0]["transform_matrix"])
    _edit_json(tiny_scene / "transforms.json", lambda m: m["frames"][0].__setitem__("transform_matrix", c2w[:3].tolist()))
    np.testing.assert_array_equal(load_scene(tiny_scene).cameras.c2w[0], c2w)


@pytest.mark.parametrize("key, value", [("cx", 40.0), ("cy", -1.0)])
def test_principal_point_outside_image(tiny_scene: Path, key: str, value: float) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: m["frames"][3].__setitem__(key, value))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", "cx/cy", "outside the 16x12 image")


@pytest.mark.parametrize("key, value, fragment", [
    ("fl_x", "abc", "frames[1].fl_x: not a number"),
    ("fl_y", -3.0, "fl_x/fl_y: focal lengths must be positive"),
    ("w", 15.5, "w/h: image size must be positive integers"),
])
def test_bad_intrinsics(tiny_scene: Path, key: str, value, fragment: str) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: m["frames"][1].__setitem__(key, value))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", fragment)


def test_missing_intrinsics(tiny_scene: Path) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: [f.pop("fl_x") for f in m["frames"]])
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", "fl_x: missing")


def test_top_level_intrinsics(tiny_scene: Path) -> None:
    def edit(meta: dict) -> None:
        for f in meta["frames"]:
            for key in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
                meta[key] = f.pop(key)

    _edit_json(tiny_scene / "transforms.json", edit)
    cams = load_scene(tiny_scene).cameras
    assert cams.fx.tolist() == [14.0] * 6 and cams.width.tolist() == [16] * 6 and cams.cy.tolist() == [6.0] * 6


@pytest.mark.parametrize("split", ["train", "val", "test"])
def test_empty_split(tiny_scene: Path, split: str) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: m.__setitem__(f"{split}_filenames", []))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", f"{split}_filenames: empty split")


@pytest.mark.parametrize("entry", ["images/frame_099.png", 3, ["images/frame_000.png"]])
def test_split_names_unknown_frame(tiny_scene: Path, entry) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: m["test_filenames"].append(entry))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", "test_filenames", repr(entry))


def test_duplicate_frames(tiny_scene: Path) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: m["frames"].append(dict(m["frames"][1])))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json",
                  "frames[6].file_path", "duplicate frame 'images/frame_001.png'", "frames[1]")


def test_frames_sharing_a_stem(tiny_scene: Path) -> None:
    shutil.copy(tiny_scene / "images" / "frame_001.png", tiny_scene / "images" / "frame_001.jpg")

    def edit(meta: dict) -> None:
        meta["frames"].append(dict(meta["frames"][1], file_path="images/frame_001.jpg"))

    _edit_json(tiny_scene / "transforms.json", edit)
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", "frames", "share a file name stem")


@pytest.mark.parametrize("edit, fragment", [
    (lambda cats: cats[0].update(id=0), "categories[0].id: must be >= 1"),
    (lambda cats: cats[3].update(id=2), "categories[3].id: duplicate id 2"),
    (lambda cats: cats[1].update(id="two"), "categories[1].id: not an integer"),
    (lambda cats: cats.clear(), "categories: must be a non-empty list"),
])
def test_bad_categories(tiny_scene: Path, edit, fragment: str) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: edit(m["categories"]))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", fragment)


def test_categories_fall_back_to_panoptic_json(tiny_scene: Path) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: m.pop("categories"))
    assert [c.name for c in load_scene(tiny_scene).categories] == ["wall", "floor", "chair", "table"]
    _edit_json(tiny_scene / "panoptic.json", lambda c: c["categories"][2].update(id=0))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "panoptic.json", "categories[2].id: must be >= 1")


@pytest.mark.parametrize("score", [1.5, -0.1, float("nan"), "high"])
def test_score_outside_unit_interval(tiny_scene: Path, score) -> None:
    _edit_json(tiny_scene / "panoptic.json", lambda c: c["annotations"][5]["segments_info"][1].update(score=score))
    field = "annotations[5].segments_info[1]"
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "panoptic.json", field,
                  "needs integer id" if score == "high" else "score")


def test_segment_id_zero_is_rejected(tiny_scene: Path) -> None:
    _edit_json(tiny_scene / "panoptic.json", lambda c: c["annotations"][0]["segments_info"][0].update(id=0))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "panoptic.json",
                  "annotations[0].segments_info[0].id", "0 is void")


def test_missing_panoptic_json(tiny_scene: Path) -> None:
    (tiny_scene / "panoptic.json").unlink()
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "panoptic.json", "file not found", "panoptic PNGs")


def test_missing_gt_panoptic_json(tiny_scene: Path) -> None:
    (tiny_scene / "gt" / "panoptic.json").unlink()
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "gt" / "panoptic.json", "file not found", "GT")


def test_panoptic_json_without_the_frame(tiny_scene: Path) -> None:
    _edit_json(tiny_scene / "panoptic.json", lambda c: c["annotations"].pop(3))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "panoptic.json",
                  "no annotation with file_name 'frame_003.png'", "frames[3]")


def test_panoptic_json_not_coco(tiny_scene: Path) -> None:
    (tiny_scene / "panoptic.json").write_text('{"images": []}')
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "panoptic.json", "annotations: missing")


def test_no_pseudo_labels_at_all(tiny_scene: Path) -> None:
    """A scene written to be labelled afterwards loads (images, poses, depth); reading labels names the frame."""
    (tiny_scene / "panoptic.json").unlink()
    shutil.rmtree(tiny_scene / "panoptic")
    _edit_json(tiny_scene / "transforms.json", lambda m: [f.pop("panoptic_file_path") for f in m["frames"]])
    scene = load_scene(tiny_scene)
    assert not scene.has_pseudo_labels and scene.has_gt and scene.depth(0) is not None
    scene.validate()
    _expect_error(lambda: scene.pseudo_labels(1), tiny_scene / "transforms.json",
                  "frame 'images/frame_001.png' has no pseudo-labels")
    # Without ground truth either, it needs no categories.
    shutil.rmtree(tiny_scene / "gt")
    _edit_json(tiny_scene / "transforms.json", lambda m: [f.pop("gt_panoptic_file_path") for f in m["frames"]])
    for categories in ([], None):
        _edit_json(tiny_scene / "transforms.json",
                   lambda m: m.__setitem__("categories", categories) if categories is not None else m.pop("categories"))
        assert load_scene(tiny_scene).categories == []


def test_labels_without_categories(tiny_scene: Path) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: m.__setitem__("categories", []))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", "categories: must be a non-empty")
    _edit_json(tiny_scene / "transforms.json", lambda m: m.pop("categories"))
    _edit_json(tiny_scene / "panoptic.json", lambda c: c.pop("categories"))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", "categories: missing")


@pytest.mark.parametrize("box, fragment", [
    ({"type": "bounded", "aabb": [[0, 0, 0], [1, 1, -1]]}, "scene_box.aabb"),
    ({"type": "sphere", "aabb": [[0, 0, 0], [1, 1, 1]]}, "scene_box.type: 'sphere'"),
    ({"type": "bounded"}, "scene_box: needs 'aabb'"),
])
def test_bad_scene_box(tiny_scene: Path, box: dict, fragment: str) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: m.__setitem__("scene_box", box))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", fragment)


def test_unknown_camera_model(tiny_scene: Path) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: m.__setitem__("camera_model", "FISHEYE_624"))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", "camera_model: 'FISHEYE_624'")


def test_distortion_without_camera_model_is_opencv_with_a_note(tiny_scene: Path, capsys) -> None:
    """nerfstudio applies k1..p2 to any perspective camera: coefficients without a model must not vanish."""
    from lift3d.data import scene as scene_module

    def edit(meta: dict) -> None:
        meta.pop("camera_model", None)
        meta["k1"] = -0.08  # shared, and one frame with its own tangential term
        meta["frames"][2].update(p1=0.002, k2=0.01)

    _edit_json(tiny_scene / "transforms.json", edit)
    scene_module._NOTED_DEFAULT_MODEL.clear()
    cams = load_scene(tiny_scene).cameras
    assert cams.camera_model == "OPENCV" and cams.has_distortion
    np.testing.assert_array_equal(cams.distortion[0], [-0.08, 0, 0, 0, 0])  # k1 k2 p1 p2 k3
    np.testing.assert_array_equal(cams.distortion[2], [-0.08, 0.01, 0.002, 0, 0])
    # The model really is used: the image centre ray is unchanged, a corner ray is bent by k1 < 0.
    pinhole = dataclasses.replace(cams, camera_model="PINHOLE")
    centre, corner = (np.array([7.5]), np.array([5.5])), (np.array([0]), np.array([0]))
    np.testing.assert_allclose(cams.rays(0, *centre)[1], pinhole.rays(0, *centre)[1], atol=2e-3)
    assert not np.allclose(cams.rays(0, *corner)[1], pinhole.rays(0, *corner)[1], atol=1e-3)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "camera_model is missing but k1, k2, p1 are non-zero" in err and "OPENCV" in err
    load_scene(tiny_scene)  # noted once per scene, not on every load
    assert capsys.readouterr().err == ""


def test_zero_coefficients_without_camera_model_stay_pinhole(tiny_scene: Path, capsys) -> None:
    _edit_json(tiny_scene / "transforms.json",
               lambda m: (m.pop("camera_model", None), m.update(k1=0.0, k2=0, p1=0.0, p2=0.0)))
    assert load_scene(tiny_scene).cameras.camera_model == "PINHOLE"
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("model, frame_key, problem", [
    (None, "k4", "frames[3].k4: 0.01 is non-zero, but camera_model OPENCV has no k4 (it uses k1 k2 p1 p2 k3)"),
    ("OPENCV", "k4", "frames[3].k4: 0.01 is non-zero, but camera_model OPENCV has no k4"),
    ("OPENCV_FISHEYE", "p2", "frames[3].p2: 0.01 is non-zero, but camera_model OPENCV_FISHEYE has no p2"),
    ("PINHOLE", "k1", "frames[3].k1: 0.01 is non-zero, but camera_model PINHOLE has no k1 (it uses no distortion)"),
])
def test_a_coefficient_the_model_does_not_use_is_an_error(tiny_scene: Path, model, frame_key: str, problem: str) -> None:
    def edit(meta: dict) -> None:
        meta.pop("camera_model", None)
        if model is not None:
            meta["camera_model"] = model
        meta["frames"][3][frame_key] = 0.01

    _edit_json(tiny_scene / "transforms.json", edit)
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", problem)


def test_unnamed_distortion_params_are_refused(tiny_scene: Path) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: m.__setitem__("distortion_params", [0.1, 0, 0, 0, 0, 0]))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", "distortion_params: not read")


@pytest.mark.parametrize("values, fragment", [
    (np.full((12, 16), 1.5, np.float32), "confidence must lie in [0, 1]"),
    (np.full((12, 16), np.nan, np.float32), "confidence must lie in [0, 1]"),
    (np.ones((6, 16), np.float32), "confidence map is 16x6"),
])
def test_bad_confidence_map(tiny_scene: Path, values: np.ndarray, fragment: str) -> None:
    path = tiny_scene / "confidence.npy"
    np.save(path, values)
    _edit_json(tiny_scene / "transforms.json", lambda m: m["frames"][0].__setitem__("confidence_file_path", path.name))
    _expect_error(lambda: load_scene(tiny_scene).pseudo_labels(0), path, fragment)


def test_gt_points_without_labels(tiny_scene: Path) -> None:
    from lift3d.data.ply import write_labelled_ply

    path = tiny_scene / "gt" / "points.ply"
    write_labelled_ply(path, np.zeros((3, 3)), semantic=np.ones(3))
    _expect_error(load_scene(tiny_scene).gt_points, path, "'instance'")


@pytest.mark.parametrize("value, fragment", [(0, "must be positive"), (-1e-3, "must be positive"), ("mm", "not a number")])
def test_bad_depth_unit_scale_factor(tiny_scene: Path, value, fragment: str) -> None:
    _edit_json(tiny_scene / "transforms.json", lambda m: m.__setitem__("depth_unit_scale_factor", value))
    _expect_error(lambda: load_scene(tiny_scene), tiny_scene / "transforms.json", "depth_unit_scale_factor", fragment)


def test_eight_bit_confidence_png_and_mask(tiny_scene: Path) -> None:
    """External tools write 8-bit confidence maps (value / 255) and nerfstudio masks (0 = ignore)."""
    import cv2

    confidence = np.tile(np.arange(16, dtype=np.uint8) * 17, (12, 1))  # 0 .. 255
    mask = np.zeros((12, 16), np.uint8)
    mask[:, 8:] = 255
    cv2.imwrite(str(tiny_scene / "conf8.png"), confidence)
    cv2.imwrite(str(tiny_scene / "mask.png"), mask)

    def edit(meta: dict) -> None:
        meta["frames"][1].update(confidence_file_path="conf8.png", mask_path="mask.png")

    _edit_json(tiny_scene / "transforms.json", edit)
    scene = load_scene(tiny_scene)
    labels = scene.pseudo_labels(1)
    score = {s.id: s.score for s in scene.frames[1].segments.values()}
    expected = np.vectorize(lambda sid: score.get(sid, 0.0))(labels.segment) * confidence / 255.0
    np.testing.assert_allclose(labels.confidence, expected, rtol=1e-6)
    np.testing.assert_array_equal(scene.mask(1), mask > 0)
    assert scene.mask(0) is None


def test_a_category_colour_that_is_not_rgb_is_a_one_line_error(tmp_path):
    """Both the scene loader and `lift3d convert --categories` validate categories with one parser."""
    from lift3d.convert.predictions import parse_categories as convert_categories
    from lift3d.data.scene import parse_categories

    bad = [{"id": 1, "name": "wall", "color": "red"}]
    for parse in (parse_categories, convert_categories):
        with pytest.raises(InputError, match=r"categories\[0\]\.color: expected \[r, g, b\]"):
            parse(bad, tmp_path / "transforms.json")
    ok = [{"id": 3, "name": "chair", "isthing": 1}]
    assert parse_categories(ok, tmp_path)[0].color == parse_categories(ok, tmp_path)[0].color  # seeded by id
    assert convert_categories(ok, tmp_path)[0].isthing


def test_true_poses_replace_the_written_ones_and_their_error_is_measured(tiny_scene: Path) -> None:
    from scipy.spatial.transform import Rotation

    path = tiny_scene / "transforms.json"
    meta = json.loads(path.read_text())
    # The written poses of frames 1 and 5 are the true ones turned by 2 degrees (about different axes, in the
    # camera frame) and moved by 3 cm; the others have no true pose.
    written = {}
    for k, axis in ((1, [0, 0, 1]), (5, [1, 0, 0])):
        true = np.asarray(meta["frames"][k]["transform_matrix"], float)
        noisy = true.copy()
        noisy[:3, :3] = true[:3, :3] @ Rotation.from_rotvec(np.radians(2.0) * np.asarray(axis, float)).as_matrix()
        noisy[:3, 3] += [0.03, 0.0, 0.0] if k == 1 else [0.0, 0.0, -0.03]
        meta["frames"][k]["gt_transform_matrix"] = true.tolist()
        meta["frames"][k]["transform_matrix"] = noisy.tolist()
        written[k] = noisy
    path.write_text(json.dumps(meta))
    scene = load_scene(tiny_scene)
    assert scene.true_pose_frames() == [1, 5] and scene.true_pose_frames([0, 5]) == [5]
    err = scene.pose_error()
    assert err["frames"] == 2 and err["rms_deg"] == pytest.approx(2.0, abs=1e-6)
    assert err["rms_translation"] == pytest.approx(0.03, abs=1e-9)
    assert scene.pose_error([0, 2]) is None
    fixed = scene.at_true_poses([5])
    assert np.allclose(fixed.cameras.c2w[5], scene.frames[5].gt_c2w)
    assert np.array_equal(fixed.cameras.c2w[1], written[1])  # not asked for: keeps its written pose
    assert np.array_equal(scene.cameras.c2w[5], written[5])  # the scene itself is unchanged
    assert np.allclose(scene.at_true_poses().cameras.c2w[1], scene.frames[1].gt_c2w)
