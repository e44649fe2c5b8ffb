"""``lift3d convert --from nerfstudio`` (and its other name, ``instant-ngp``): transforms.json files.

Every file is written here, in ``tmp_path``, the way instant-ngp's ``colmap2nerf.py`` and nerfstudio's
``ns-process-data`` write them: OpenGL camera-to-world ``transform_matrix`` built by hand from cameras whose
OpenCV axes are known, intrinsics top-level or per frame. Expected pixels come from each model's own
formula (``colmap_pixel`` of test_convert.py, written from COLMAP's and OpenCV's documentation), not from
lift3d's camera code; the converted scene is read back with ``load_scene``.
"""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from lift3d.cli.main import main as cli_main
from lift3d.convert import WriteOptions
from lift3d.convert import nerfstudio
from lift3d.convert.predictions import load_categories
from lift3d.data.scene import load_scene
from lift3d.errors import InputError
from test_convert import (CATEGORIES, EYES, TARGET, H, W, colmap_pixel, opencv_camera, write_images,
                          write_two_png_predictions)

QUIET = WriteOptions(progress=False)


def gl_matrix(r_c2w_cv: np.ndarray, eye: np.ndarray) -> list:
    """``transform_matrix`` as both tools store it: camera-to-world with OpenGL axes (y up, z backwards),
    i.e. the OpenCV camera's y and z columns negated."""
    m = np.eye(4)
    m[:3, :3] = r_c2w_cv * [1.0, -1.0, -1.0]
    m[:3, 3] = eye
    return m.tolist()


def capture(root, stems, meta, frame_extra=None, absent=(), file_paths=None):
    """``root/transforms.json`` + ``root/images`` + predictions in ``root/pred`` for cameras looking at
    TARGET from EYES. ``absent`` stems are listed in the JSON but have no image. Returns the rigs by stem."""
    rigs = {stem: opencv_camera(EYES[k % len(EYES)], TARGET) for k, stem in enumerate(stems)}
    present = [s for s in stems if s not in absent]
    write_images(root / "images", present, ".png")
    write_two_png_predictions(root / "pred", present)
    (root / "categories.json").write_text(json.dumps(CATEGORIES))
    frames = []
    for k, stem in enumerate(stems):
        frame = {"file_path": (file_paths or {}).get(stem, f"./images/{stem}.png"),
                 "transform_matrix": gl_matrix(*rigs[stem])}
        frame.update((frame_extra or {}).get(stem, {}))
        frames.append(frame)
    (root / "transforms.json").write_text(json.dumps({**meta, "frames": frames}))
    return rigs


def convert(root, out, **kw):
    cats = load_categories(root / "categories.json")
    return nerfstudio.convert(root, out, predictions=root / "pred", categories=cats, options=QUIET, **kw)


def expected_ray(r_c2w_cv, fx, fy, cx, cy, u, v):
    """World direction through pixel centre (u + 0.5, v + 0.5) of an undistorted OpenCV camera."""
    d = r_c2w_cv @ np.array([(u + 0.5 - cx) / fx, (v + 0.5 - cy) / fy, 1.0])
    return d / np.linalg.norm(d)


def test_instant_ngp_file_with_camera_angle_and_absent_images(tmp_path, capsys):
    """colmap2nerf / NeRF-synthetic style: one field of view for all frames, no w/h (the image decides),
    frames out of order, a file_path without extension, and two frames whose images are gone."""
    stems = ["f10", "f2", "f4", "f1", "f7", "f5", "f3"]
    angle = 2 * math.atan(W / (2 * 40.0))  # fx = 40 px
    rigs = capture(tmp_path, stems, {"camera_angle_x": angle, "aabb_scale": 1},
                   absent=("f4", "f5"), file_paths={"f2": "./images/f2"})
    scene = convert(tmp_path, tmp_path / "out", test_every=2)
    err = capsys.readouterr().err
    assert "2 of 7 frames listed in transforms.json have no image: skipped" in err
    assert [f.name for f in scene.frames] == ["f1", "f2", "f3", "f7", "f10"]  # natural order, as instant-ngp
    assert [scene.frames[i].name for i in scene.split("test")] == ["f1", "f3", "f10"]
    cams = load_scene(tmp_path / "out").cameras
    assert cams.camera_model == "PINHOLE"
    np.testing.assert_allclose(cams.fx, 40.0, rtol=1e-12)
    np.testing.assert_allclose(cams.fy, 40.0, rtol=1e-12)
    np.testing.assert_array_equal(cams.cx, W / 2)
    np.testing.assert_array_equal(cams.cy, H / 2)
    source_frames = json.loads((tmp_path / "transforms.json").read_text())["frames"]
    written = {f["file_path"]: f["transform_matrix"] for f in source_frames}
    for i, frame in enumerate(scene.frames):
        r, eye = rigs[frame.name]
        source = written["./images/f2" if frame.name == "f2" else f"./images/{frame.name}.png"]
        np.testing.assert_array_equal(cams.c2w[i], source)  # the file's pose, bit for bit
        np.testing.assert_array_equal(cams.centers[i], eye)
        u, v = np.array([0, 17, 47]), np.array([0, 30, 35])
        origins, dirs = cams.rays(i, u, v)
        np.testing.assert_array_equal(origins, np.broadcast_to(eye, origins.shape))
        for j in range(len(u)):
            np.testing.assert_allclose(dirs[j], expected_ray(r, 40.0, 40.0, W / 2, H / 2, u[j], v[j]), atol=1e-12)
    # aabb_scale 1: instant-ngp models only its unit cube, [0, 1]^3 = 0.33 x world + 0.5.
    assert scene.scene_box.type == "bounded"
    np.testing.assert_allclose(scene.scene_box.aabb, [[-0.5 / 0.33] * 3, [0.5 / 0.33] * 3])
    assert "aabb_scale 1" in err and "bounded" in err


def test_nerfstudio_file_with_per_frame_intrinsics_distortion_mask_depth_and_splits(tmp_path):
    """ns-process-data style with several cameras: camera_model and intrinsics per frame, OPENCV
    distortion, applied_transform/applied_scale, mask_path (non-zero = train), depth in millimetres, and
    the file's own split lists."""
    stems = ["f0", "f1", "f2", "f3"]
    intr = {  # per frame: fx fy cx cy k1 k2 p1 p2 k3 (f2's intrinsics are for an image twice the size)
        "f0": [41.0, 39.0, 23.5, 18.5, -0.05, 0.01, 0.001, -0.002, 0.004],
        "f1": [38.0, 38.5, 24.5, 17.0, 0.03, -0.01, 0.0, 0.0015, 0.0],
        "f2": [80.0, 80.0, 48.0, 36.0, -0.02, 0.0, 0.0, 0.0, 0.0],
        "f3": [40.0, 40.0, 24.0, 18.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    }
    extra = {}
    for stem, (fx, fy, cx, cy, k1, k2, p1, p2, k3) in intr.items():
        big = stem == "f2"
        extra[stem] = {"camera_model": "OPENCV", "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy,
                       "w": W * 2 if big else W, "h": H * 2 if big else H,
                       "k1": k1, "k2": k2, "p1": p1, "p2": p2, **({"k3": k3} if k3 else {})}
    (tmp_path / "masks").mkdir()
    mask = np.zeros((H, W), np.uint8)
    mask[:, W // 2:] = 255  # nerfstudio: train on the right half only
    cv2.imwrite(str(tmp_path / "masks" / "f1.png"), mask)
    extra["f1"]["mask_path"] = "masks/f1.png"
    (tmp_path / "depth").mkdir()
    cv2.imwrite(str(tmp_path / "depth" / "f3.png"), np.full((H, W), 2500, np.uint16))
    extra["f3"]["depth_file_path"] = "depth/f3.png"
    applied = [[0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0]]
    rigs = capture(tmp_path, stems, {"applied_transform": applied, "applied_scale": 0.25,
                                     "test_filenames": ["images/f2.png"], "ply_file_path": "sparse_pc.ply"}, extra)
    scene = convert(tmp_path, tmp_path / "out")
    cams = scene.cameras
    assert cams.camera_model == "OPENCV"
    assert [scene.frames[i].name for i in scene.split("test")] == ["f2"]
    assert [scene.frames[i].name for i in scene.split("train")] == ["f0", "f1", "f3"]
    for i, frame in enumerate(scene.frames):
        r, eye = rigs[frame.name]
        fx, fy, cx, cy, k1, k2, p1, p2, k3 = intr[frame.name]
        if frame.name == "f2":
            fx, fy, cx, cy = fx / 2, fy / 2, cx / 2, cy / 2  # scaled to the image on disk
        np.testing.assert_array_equal(cams.centers[i], eye)
        points = eye + (np.array([[0.2, -0.15, 1.0], [-0.3, 0.2, 1.2], [0.05, 0.3, 0.9]]) * 2.0) @ r.T
        params = [fx, fy, cx, cy, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]
        expected = np.stack([colmap_pixel("FULL_OPENCV", params, r.T, -r.T @ eye, x) for x in points])
        uv, _ = cams.project(i, points)
        np.testing.assert_allclose(uv, expected, atol=1e-6)
        # ... and back: the ray through that pixel passes through the point.
        _, dirs = cams.rays(i, expected[:, 0] - 0.5, expected[:, 1] - 0.5)
        toward = (points - eye) / np.linalg.norm(points - eye, axis=1, keepdims=True)
        np.testing.assert_allclose(dirs, toward, atol=1e-6)
    index = {f.name: i for i, f in enumerate(scene.frames)}
    assert cams.distortion[index["f3"]].tolist() == [0.0] * 5  # a pinhole frame in an OPENCV scene
    np.testing.assert_array_equal(scene.mask(index["f1"]), mask > 0)
    np.testing.assert_allclose(scene.depth(index["f3"]), 2.5, rtol=1e-6)
    assert scene.frames[0].depth_path is None
    meta = json.loads((tmp_path / "out" / "transforms.json").read_text())
    assert meta["converted_from"]["applied_transform"] == applied and meta["converted_from"]["applied_scale"] == 0.25
    assert "scene_box" not in meta  # no aabb_scale: training decides


def test_instant_ngp_fisheye_and_depth_path(tmp_path):
    """colmap2nerf writes OPENCV_FISHEYE as is_fisheye + k1..k4 (and zero p1 p2); depth_path maps are in
    integer_depth_scale units."""
    params = [30.0, 30.0, 24.0, 18.0, 0.02, -0.01, 0.03, -0.02]
    meta = {"fl_x": params[0], "fl_y": params[1], "cx": params[2], "cy": params[3], "w": W, "h": H,
            "k1": params[4], "k2": params[5], "k3": params[6], "k4": params[7], "p1": 0.0, "p2": 0.0,
            "is_fisheye": True, "integer_depth_scale": 0.0005}
    (tmp_path / "depth").mkdir()
    cv2.imwrite(str(tmp_path / "depth" / "a.png"), np.full((H, W), 3000, np.uint16))
    rigs = capture(tmp_path, ["a", "b", "c"], meta, {"a": {"depth_path": "depth/a.png"}})
    scene = convert(tmp_path, tmp_path / "out")
    cams = scene.cameras
    assert cams.camera_model == "OPENCV_FISHEYE"
    for i, frame in enumerate(scene.frames):
        r, eye = rigs[frame.name]
        x = eye + r @ np.array([0.4, -0.3, 1.0])
        expected = colmap_pixel("OPENCV_FISHEYE", params, r.T, -r.T @ eye, x)
        np.testing.assert_allclose(cams.project(i, x[None])[0][0], expected, atol=1e-6)
    assert scene.depth_unit_scale_factor == 0.0005
    np.testing.assert_allclose(scene.depth(0), 1.5, rtol=1e-6)  # 3000 x 0.0005 world units


def test_aabb_scale_above_one_leaves_the_space_to_training(tmp_path, capsys):
    # colmap2nerf writes 32 whatever the scene: it says only that something lies beyond instant-ngp's cube
    capture(tmp_path, ["a", "b"], {"fl_x": 40.0, "aabb_scale": 16, "scale": 0.5, "offset": [0.5, 0.6, 0.5]})
    scene = convert(tmp_path, tmp_path / "out")
    assert scene.scene_box is None
    assert "aabb_scale 16" in capsys.readouterr().err


def test_coefficients_without_camera_model_are_opencv(tmp_path):
    """nerfstudio applies k1.. to a perspective camera whatever camera_model says (absent here)."""
    capture(tmp_path, ["a", "b"], {"fl_x": 40.0, "k1": -0.04})
    cams = convert(tmp_path, tmp_path / "out").cameras
    assert cams.camera_model == "OPENCV" and cams.distortion[:, 0].tolist() == [-0.04, -0.04]


@pytest.mark.parametrize("meta, frame_b, problem", [
    ({"k4": 0.01}, {}, "k4: 0.01 is non-zero; lift3d cannot represent k4 of a perspective camera"),
    ({"is_fisheye": True}, {"p1": 0.001}, "frames[1].p1: 0.001 is non-zero; lift3d cannot represent p1 of a fisheye"),
    ({"distortion_params": [0.0] * 12}, {}, "distortion_params: expected [k1, k2, k3, k4, p1, p2]"),
    ({"camera_model": "EQUIRECTANGULAR"}, {}, "camera_model: 'EQUIRECTANGULAR' is not supported"),
    ({}, {"camera_model": "OPENCV_FISHEYE"}, "fisheye and perspective cameras are mixed"),
    ({}, {"transform_matrix": [[2.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]},
     "frames[1].transform_matrix: not a rigid transform"),
])
def test_what_lift3d_cannot_represent_is_a_one_line_error(tmp_path, meta, frame_b, problem):
    capture(tmp_path, ["a", "b"], {"fl_x": 40.0, **meta}, {"b": frame_b})
    with pytest.raises(InputError) as err:
        convert(tmp_path, tmp_path / "out")
    assert err.value.where == str(tmp_path / "transforms.json") and problem in err.value.problem
    assert "\n" not in str(err.value) and not (tmp_path / "out").exists()


def test_no_image_at_all_and_missing_predictions(tmp_path):
    capture(tmp_path, ["a", "b"], {"fl_x": 40.0}, absent=("a", "b"))
    with pytest.raises(InputError, match="none of the 2 frames listed has its image"):
        convert(tmp_path, tmp_path / "out")
    capture(tmp_path / "p", ["a", "b"], {"fl_x": 40.0})
    (tmp_path / "p" / "pred" / "semantic" / "b.png").unlink()
    with pytest.raises(InputError) as err:
        convert(tmp_path / "p", tmp_path / "out")
    assert err.value.where == str(tmp_path / "p" / "pred" / "semantic" / "b.png")


def test_cli_from_instant_ngp_names_the_same_reader(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("LIFT3D_NO_PROGRESS", "1")
    capture(tmp_path, ["a", "b", "c"], {"camera_angle_x": 1.2, "n_frames": 2})
    rc = cli_main(["convert", "--from", "instant-ngp", str(tmp_path / "transforms.json"), "--predictions",
                   str(tmp_path / "pred"), "--categories", str(tmp_path / "categories.json"),
                   "--out", str(tmp_path / "out"), "--no-depth"])
    captured = capsys.readouterr()
    assert rc == 0 and "3 frames" in captured.out
    assert "n_frames ignored" in captured.err
    rc = cli_main(["convert", "--from", "nerfstudio", str(tmp_path), "--out", str(tmp_path / "o2")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.count("\n") == 0 and "--predictions" in err
    (tmp_path / "transforms.json").rename(tmp_path / "transforms_train.json")
    rc = cli_main(["convert", "--from", "nerfstudio", str(tmp_path), "--predictions", str(tmp_path / "pred"),
                   "--out", str(tmp_path / "o3")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "transforms.json: file not found (pass one of transforms_train.json as SRC)" in err
