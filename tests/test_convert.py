"""``lift3d convert``: COLMAP (text and binary), Panoptic Lifting and ScanNet-style inputs.

Every input is made here, in ``tmp_path``, from cameras whose poses are known independently of lift3d's
own conversion code: the expected pixel of a 3D point is computed with each source's own projection
formula (COLMAP's camera models, Panoptic Lifting's ray generation) and compared with
:meth:`lift3d.data.cameras.Cameras.project` on the converted scene.
"""

from __future__ import annotations

import json
import pickle
import struct
from pathlib import Path

import cv2
import numpy as np
import pytest

from lift3d.cli.main import main as cli_main
from lift3d.convert import WriteOptions
from lift3d.convert import colmap as colmap_convert
from lift3d.convert import panoptic_lifting, scannet
from lift3d.convert.predictions import PredictionFolder
from lift3d.data.images import id_to_rgb
from lift3d.data.scene import Category, load_scene
from lift3d.errors import InputError

W, H = 48, 36
QUIET = WriteOptions(progress=False)
CATEGORIES = [
    {"id": 1, "name": "wall", "isthing": 0, "color": [200, 200, 200]},
    {"id": 2, "name": "chair", "isthing": 1, "color": [220, 20, 60]},
    {"id": 3, "name": "floor", "isthing": 0, "color": [90, 60, 30]},
]
TARGET = np.array([0.1, -0.2, 0.3])


# --------------------------------------------------------------------------------------------- cameras
def opencv_camera(eye, target, up=(0.0, 0.0, 1.0)):
    """Camera-to-world rotation (columns: right, down, forward) and centre of a camera at ``eye`` looking
    at ``target``, built directly in OpenCV axes (independent of lift3d's axis conversion)."""
    eye = np.asarray(eye, float)
    fwd = np.asarray(target, float) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    return np.stack([right, down, fwd], 1), eye


EYES = [(2.0, 0.5, 1.0), (-1.5, 1.8, 0.4), (0.3, -2.2, 1.6), (-0.8, -0.6, 2.5), (1.1, 1.9, -0.7)]


def camera_rigs():
    return [opencv_camera(e, TARGET) for e in EYES]


def rotmat_to_qvec(r):
    """Unit quaternion (w, x, y, z) of a rotation matrix (Shepperd's method, all four branches)."""
    m = r
    tr = np.trace(m)
    if tr > 0:
        s = 2 * np.sqrt(tr + 1)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2 * np.sqrt(1 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2 * np.sqrt(1 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2 * np.sqrt(1 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    return q if q[0] >= 0 else -q


def colmap_pixel(model, params, r_w2c, t_w2c, x_world):
    """Where COLMAP's own camera model puts a world point (pixel-corner origin), written from its docs."""
    p = r_w2c @ x_world + t_w2c
    x, y = p[0] / p[2], p[1] / p[2]
    r2 = x * x + y * y
    if model == "SIMPLE_PINHOLE":
        f, cx, cy = params
        return np.array([f * x + cx, f * y + cy])
    if model == "PINHOLE":
        fx, fy, cx, cy = params
        return np.array([fx * x + cx, fy * y + cy])
    if model in ("SIMPLE_RADIAL", "RADIAL"):
        f, cx, cy, *k = params
        radial = k[0] * r2 + (k[1] * r2 * r2 if len(k) > 1 else 0.0)
        return np.array([f * x * (1 + radial) + cx, f * y * (1 + radial) + cy])
    if model in ("OPENCV", "FULL_OPENCV"):
        fx, fy, cx, cy, k1, k2, p1, p2 = params[:8]
        k3 = params[8] if model == "FULL_OPENCV" else 0.0
        radial = k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
        xd = x * (1 + radial) + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * (1 + radial) + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)
        return np.array([fx * xd + cx, fy * yd + cy])
    if model == "OPENCV_FISHEYE":
        fx, fy, cx, cy, k1, k2, k3, k4 = params
        r = np.sqrt(r2)
        theta = np.arctan(r)
        thetad = theta * (1 + k1 * theta ** 2 + k2 * theta ** 4 + k3 * theta ** 6 + k4 * theta ** 8)
        return np.array([fx * x * thetad / r + cx, fy * y * thetad / r + cy])
    raise AssertionError(model)


MODEL_PARAMS = {
    "SIMPLE_PINHOLE": [40.0, 24.0, 18.0],
    "PINHOLE": [41.0, 39.0, 23.5, 18.5],
    "SIMPLE_RADIAL": [40.0, 24.0, 18.0, -0.05],
    "RADIAL": [40.0, 24.0, 18.0, -0.05, 0.02],
    "OPENCV": [41.0, 39.0, 23.5, 18.5, -0.05, 0.01, 0.001, -0.002],
    "OPENCV_FISHEYE": [30.0, 30.0, 24.0, 18.0, 0.02, -0.01, 0.03, -0.02],
    "FULL_OPENCV": [41.0, 39.0, 23.5, 18.5, -0.05, 0.01, 0.001, -0.002, 0.004, 0.0, 0.0, 0.0],
}
MODEL_IDS = {name: mid for mid, (name, _) in colmap_convert.COLMAP_CAMERA_MODELS.items()}


# --------------------------------------------------------------------------------------------- writers
def write_colmap_text(model_dir, cameras, images, points=None):
    """cameras: [(id, model, w, h, params)]; images: [(id, qvec, tvec, cam_id, name, keypoints)] with keypoints
    [(x, y, point3D_id)]; points: [(id, xyz, rgb, error, track [(image_id, point2D_idx)])]."""
    model_dir.mkdir(parents=True, exist_ok=True)
    lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    lines += [" ".join([str(cid), model, str(w), str(h)] + [repr(float(p)) for p in params])
              for cid, model, w, h, params in cameras]
    (model_dir / "cameras.txt").write_text("\n".join(lines) + "\n")
    lines = ["# Image list with two lines of data per image:"]
    for iid, q, t, cid, name, kps in images:
        lines.append(" ".join([str(iid)] + [repr(float(v)) for v in (*q, *t)] + [str(cid), name]))
        lines.append(" ".join(f"{x!r} {y!r} {pid}" for x, y, pid in kps))  # may be empty, as in real files
    (model_dir / "images.txt").write_text("\n".join(lines) + "\n")
    if points is not None:
        body = [" ".join([str(pid), *(repr(float(v)) for v in xyz), *(str(int(c)) for c in rgb), repr(err)]
                         + [f"{iid} {idx}" for iid, idx in track]) for pid, xyz, rgb, err, track in points]
        (model_dir / "points3D.txt").write_text("# 3D point list\n" + "\n".join(body) + "\n")


def write_colmap_binary(model_dir, cameras, images, points=None):
    model_dir.mkdir(parents=True, exist_ok=True)
    buf = struct.pack("<Q", len(cameras))
    for cid, model, w, h, params in cameras:
        buf += struct.pack("<IiQQ", cid, MODEL_IDS[model], w, h) + struct.pack(f"<{len(params)}d", *params)
    (model_dir / "cameras.bin").write_bytes(buf)
    buf = struct.pack("<Q", len(images))
    for iid, q, t, cid, name, kps in images:
        buf += struct.pack("<I7dI", iid, *q, *t, cid) + name.encode() + b"\0"
        buf += struct.pack("<Q", len(kps)) + b"".join(struct.pack("<ddq", x, y, pid) for x, y, pid in kps)
    (model_dir / "images.bin").write_bytes(buf)
    if points is not None:
        buf = struct.pack("<Q", len(points))
        for pid, xyz, rgb, err, track in points:
            buf += struct.pack("<Q3d3BdQ", pid, *xyz, *rgb, err, len(track))
            buf += b"".join(struct.pack("<II", iid, idx) for iid, idx in track)
        (model_dir / "points3D.bin").write_bytes(buf)


def observe_points(images, points, model, params):
    """Keypoints and tracks of world ``points`` seen by ``images`` (COLMAP's own projection; points outside
    an image or behind it are not seen), with an unmatched keypoint first in every other image so that
    POINT2D_IDX differs from the point's index. Returns images with keypoints and COLMAP point records."""
    tracks = {k: [] for k in range(len(points))}
    out = []
    for n, (iid, q, t, cid, name) in enumerate(images):
        r_w2c = colmap_convert.qvec_to_rotmat(q)
        kps = [(3.25, 4.5, -1)] if n % 2 else []
        for k, x in enumerate(points):
            if (r_w2c @ x + t)[2] <= 0:
                continue
            u, v = colmap_pixel(model, params, r_w2c, t, np.asarray(x, float))
            if 0 <= u < W and 0 <= v < H:
                tracks[k].append((iid, len(kps)))
                kps.append((float(u), float(v), k + 1))
        out.append((iid, q, t, cid, name, kps))
    records = [(k + 1, tuple(points[k]), (10 * k % 256, 20, 30), 0.25 + 0.01 * k, tracks[k])
               for k in range(len(points))]
    return out, records


def label_maps(k):
    """Semantic and instance maps of frame ``k``: wall on top, floor below, two chairs, a void strip."""
    sem = np.ones((H, W), np.int32)
    sem[H // 2:] = 3
    inst = np.zeros((H, W), np.int32)
    sem[8:20, 4 + k:14 + k] = 2
    inst[8:20, 4 + k:14 + k] = 10 + k  # per-frame ids, different in every frame
    sem[10:30, 30:40] = 2
    inst[10:30, 30:40] = 50 + 7 * k
    sem[:, -3:] = 0
    return sem, inst


def write_two_png_predictions(root, stems, confidence=False):
    for d in ("semantic", "instance") + (("confidence",) if confidence else ()):
        (root / d).mkdir(parents=True, exist_ok=True)
    for k, stem in enumerate(stems):
        sem, inst = label_maps(k)
        cv2.imwrite(str(root / "semantic" / f"{stem}.png"), sem.astype(np.uint16))
        cv2.imwrite(str(root / "instance" / f"{stem}.png"), inst.astype(np.uint16))
        if confidence:
            conf = np.full((H, W), 0.25 + 0.1 * k)
            cv2.imwrite(str(root / "confidence" / f"{stem}.png"), np.round(conf * 65535).astype(np.uint16))


def write_coco_predictions(root, stems, with_categories=True):
    """COCO panoptic layout holding the same segments as :func:`label_maps`, with scores."""
    (root / "panoptic").mkdir(parents=True, exist_ok=True)
    annotations = []
    for k, stem in enumerate(stems):
        sem, inst = label_maps(k)
        seg = np.zeros((H, W), np.int64)
        infos = []
        keys = sorted({(int(s), int(i)) for s, i in zip(sem.ravel(), inst.ravel()) if s > 0})
        for j, (s, i) in enumerate(keys):
            sid = 1000 * (j + 1) + 7 * k  # arbitrary, large (uses the G channel), per-frame ids
            seg[(sem == s) & (inst == i)] = sid
            infos.append({"id": sid, "category_id": s, "iscrowd": 0, "score": round(0.5 + 0.1 * j, 3)})
        cv2.imwrite(str(root / "panoptic" / f"{stem}.png"), cv2.cvtColor(id_to_rgb(seg), cv2.COLOR_RGB2BGR))
        annotations.append({"image_id": k, "file_name": f"{stem}.png", "segments_info": infos})
    doc = {"annotations": annotations, "images": [{"id": k, "file_name": f"{s}.jpg"} for k, s in enumerate(stems)]}
    if with_categories:
        doc["categories"] = CATEGORIES
    (root / "panoptic.json").write_text(json.dumps(doc))


def write_images(folder, stems, ext=".png", size=(W, H)):
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    for stem in stems:
        cv2.imwrite(str(folder / f"{stem}{ext}"), rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8))


def colmap_capture(root, fmt="txt", model="PINHOLE", n=5, predictions="two-png", points=None):
    """A COLMAP workspace ``root/{images, sparse/0}`` with known poses, plus predictions in ``root/pred``."""
    stems = [f"img_{k:02d}" for k in range(n)]
    write_images(root / "images", stems, ".jpg")
    rigs = camera_rigs()[:n]
    cams = [(1, model, W, H, MODEL_PARAMS[model])]
    images = []
    # Image ids deliberately not in name order: frames must come out sorted by name, matched by name.
    for k, (r_c2w, eye) in enumerate(rigs):
        r_w2c = r_c2w.T
        images.append((100 - k, rotmat_to_qvec(r_w2c), -r_w2c @ eye, 1, f"{stems[k]}.jpg"))
    records = None
    if points is not None:
        images, records = observe_points(images, points, model, MODEL_PARAMS[model])
    else:
        # Images without points: an empty keypoint line and one with an untriangulated keypoint (both occur).
        images = [(*im, [(10.5, 12.25, -1)] if k % 2 else []) for k, im in enumerate(images)]
    writer = write_colmap_text if fmt == "txt" else write_colmap_binary
    writer(root / "sparse" / "0", cams, images[::-1], records)
    if predictions == "two-png":
        write_two_png_predictions(root / "pred", stems)
        (root / "categories.json").write_text(json.dumps(CATEGORIES))
    else:
        write_coco_predictions(root / "pred", stems)
    return stems, rigs


def convert_colmap(root, out, **kw):
    cats = None
    if (root / "categories.json").is_file():
        from lift3d.convert.predictions import load_categories

        cats = load_categories(root / "categories.json")
    return colmap_convert.convert(root, out, predictions=root / "pred", categories=cats, options=QUIET, **kw)


# --------------------------------------------------------------------------------------------- COLMAP
def test_colmap_text_and_binary_give_the_known_projection(tmp_path):
    results = {}
    for fmt in ("txt", "bin"):
        stems, rigs = colmap_capture(tmp_path / fmt, fmt)
        scene = convert_colmap(tmp_path / fmt, tmp_path / f"out_{fmt}")
        assert [f.name for f in scene.frames] == stems
        assert scene.cameras.camera_model == "PINHOLE"
        x_world = np.array([[0.25, 0.05, 0.4], TARGET])
        fx, fy, cx, cy = MODEL_PARAMS["PINHOLE"]
        for i, (r_c2w, eye) in enumerate(rigs):
            # The pixel by COLMAP's definition: world → camera with (R, t), then K.
            p = (x_world - eye) @ r_c2w
            expected = np.stack([fx * p[:, 0] / p[:, 2] + cx, fy * p[:, 1] / p[:, 2] + cy], -1)
            uv, depth = scene.cameras.project(i, x_world)
            np.testing.assert_allclose(uv, expected, atol=1e-6)
            np.testing.assert_allclose(depth, p[:, 2], atol=1e-9)
            # transforms.json is OpenGL: x right, y up (= -down), z backwards (= -forward).
            np.testing.assert_allclose(scene.cameras.c2w[i][:3, :3], r_c2w * [1, -1, -1], atol=1e-9)
            np.testing.assert_allclose(scene.cameras.c2w[i][:3, 3], eye, atol=1e-9)
        # The look-at target lies on the optical axis: it projects to the principal point.
        uv, _ = scene.cameras.project(0, TARGET[None])
        np.testing.assert_allclose(uv[0], [cx, cy], atol=1e-6)
        results[fmt] = json.loads((tmp_path / f"out_{fmt}" / "transforms.json").read_text())
    for key in ("frames", "categories", "train_filenames", "test_filenames", "camera_model"):
        assert results["txt"][key] == results["bin"][key], key
    assert results["txt"]["test_filenames"] == ["images/img_00.png"]  # every 8th frame, from the first


@pytest.mark.parametrize("model", list(MODEL_PARAMS))
def test_colmap_camera_models_project_like_colmap(tmp_path, model):
    stems, rigs = colmap_capture(tmp_path, "bin", model=model, n=2)
    scene = convert_colmap(tmp_path, tmp_path / "out")
    expected_model = {"SIMPLE_PINHOLE": "PINHOLE", "PINHOLE": "PINHOLE", "OPENCV_FISHEYE": "OPENCV_FISHEYE"}
    assert scene.cameras.camera_model == expected_model.get(model, "OPENCV")
    params = MODEL_PARAMS[model]
    for i, (r_c2w, eye) in enumerate(rigs):
        # Points towards the image corners, where every distortion coefficient matters.
        rays = np.array([[0.5, 0.4, 1.0], [-0.55, 0.35, 1.0], [0.3, -0.42, 1.0], [0.0, 0.0, 1.0]])
        x_world = eye + (rays * [[1.5], [2.0], [0.7], [1.0]]) @ r_c2w.T
        expected = np.stack([colmap_pixel(model, params, r_c2w.T, -r_c2w.T @ eye, x) for x in x_world])
        uv, _ = scene.cameras.project(i, x_world)
        np.testing.assert_allclose(uv, expected, atol=1e-5)


def test_colmap_unsupported_model_names_the_cameras_file(tmp_path):
    root = tmp_path / "ws"
    colmap_capture(root, "txt")
    txt = root / "sparse" / "0" / "cameras.txt"
    txt.write_text(f"1 FOV {W} {H} 40 40 24 18 0.9\n")
    with pytest.raises(InputError) as err:
        convert_colmap(root, tmp_path / "out")
    assert err.value.where == str(txt) and "FOV" in err.value.problem


def test_colmap_layouts_and_scene_box(tmp_path):
    # nerfstudio's layout: data/colmap/sparse/0 + data/images, found from `data` alone.
    root = tmp_path / "data"
    stems, _ = colmap_capture(root, "bin", points=[(0.0, 0.0, 0.0), (1.0, 1.0, 1.0)] * 30)
    (root / "sparse").rename(tmp_path / "sparse_tmp")
    (root / "colmap").mkdir()
    (tmp_path / "sparse_tmp").rename(root / "colmap" / "sparse")
    scene = convert_colmap(root, tmp_path / "out", scene_box=True)
    assert len(scene) == len(stems)
    box = scene.scene_box.aabb
    centers = scene.cameras.centers
    assert np.all(box[0] <= np.minimum(centers.min(0), 0.0)) and np.all(box[1] >= np.maximum(centers.max(0), 1.0))
    # The model folder itself as SRC, images given explicitly.
    scene2 = colmap_convert.convert(root / "colmap" / "sparse" / "0", tmp_path / "out2", images=root / "images",
                                    predictions=root / "pred", options=QUIET,
                                    categories=[Category(c["id"], c["name"], bool(c["isthing"])) for c in CATEGORIES])
    np.testing.assert_allclose(scene2.cameras.c2w, scene.cameras.c2w)


POINTS = [tuple(TARGET + d) for d in np.random.default_rng(3).uniform(-0.4, 0.4, (25, 3))]


@pytest.mark.parametrize("fmt,model", [("txt", "PINHOLE"), ("bin", "PINHOLE"), ("bin", "OPENCV")])
def test_colmap_points3d_are_kept_as_sparse_points(tmp_path, fmt, model):
    stems, _ = colmap_capture(tmp_path / "ws", fmt, model=model, points=POINTS)
    scene = convert_colmap(tmp_path / "ws", tmp_path / "out")
    meta = json.loads((tmp_path / "out" / "transforms.json").read_text())
    assert meta["sparse_points"]["source"] == "colmap"
    assert meta["sparse_points"]["points"] == "sparse/points3D.ply"
    sp = scene.sparse_points()
    assert len(sp) == len(POINTS)  # every point is seen by at least two of the five cameras
    np.testing.assert_allclose(sp.xyz, POINTS, atol=1e-6)  # float32 in the PLY
    np.testing.assert_allclose(sp.error, [0.25 + 0.01 * k for k in range(len(POINTS))], atol=1e-6)
    assert sp.rgb[:, 1].tolist() == [20] * len(POINTS)
    assert sp.frame_names == [f.name for f in scene.frames] == stems
    for k in range(len(scene)):
        obs = sp.frame_observations(k)
        # The stored pixel is where the converted camera sees the point; depth is its z in that camera.
        uv, z = scene.cameras.project(k, sp.xyz[obs["point"]])
        np.testing.assert_allclose(obs["uv"], uv, atol=2e-4)
        np.testing.assert_allclose(obs["depth"], z, rtol=1e-5)
    assert np.all(sp.obs_sigma > 0) and np.all(np.bincount(sp.obs_point) == sp.track_length)


@pytest.mark.parametrize("n", [2, 5])  # 48x36 is not a multiple of 5: the last columns and rows are dropped
def test_colmap_points3d_follow_a_downscale(tmp_path, n):
    colmap_capture(tmp_path / "ws", "txt", points=POINTS)
    scene = colmap_convert.convert(tmp_path / "ws", tmp_path / "out", predictions=tmp_path / "ws" / "pred",
                                   categories=[Category(c["id"], c["name"], bool(c["isthing"])) for c in CATEGORIES],
                                   options=WriteOptions(progress=False, downscale=n))
    assert scene.image(0).shape[:2] == (H // n, W // n)
    sp = scene.sparse_points()
    for k in range(len(scene)):
        obs = sp.frame_observations(k)
        uv, _ = scene.cameras.project(k, sp.xyz[obs["point"]])
        np.testing.assert_allclose(obs["uv"], uv, atol=2e-4)


def test_colmap_points3d_not_matching_the_images_is_one_error(tmp_path):
    for fmt in ("txt", "bin"):
        root = tmp_path / fmt
        colmap_capture(root, fmt, points=POINTS)
        model = colmap_convert.read_model(root / "sparse" / "0")
        points = model.points()
        images, records = [], []
        for im in model.images.values():
            kps = [(float(x), float(y), int(p)) for (x, y), p in zip(im.xys, im.point3d_ids)]
            images.append((im.id, im.qvec, im.tvec, im.camera_id, im.name, kps))
        for k in range(len(points.ids)):
            a, b = points.offsets[k], points.offsets[k + 1]
            records.append((int(points.ids[k]), tuple(points.xyz[k]), tuple(points.rgb[k]), float(points.error[k]),
                            list(zip(points.track_image[a:b].tolist(), points.track_point2d[a:b].tolist()))))
        writer = write_colmap_text if fmt == "txt" else write_colmap_binary
        cams = [(c.id, c.model, c.width, c.height, c.params) for c in model.cameras.values()]
        pfile = root / "sparse" / "0" / f"points3D.{fmt}"
        for broken, problem in [
            (lambda r: r[0][4].__setitem__(0, (42, 0)), "image id 42"),
            (lambda r: r[1][4].__setitem__(0, (r[1][4][0][0], 99)), "POINT2D_IDX 99 is out of range"),
            (lambda r: r[2][4].__setitem__(0, r[3][4][0]), "belongs to point 4"),
        ]:
            bad = [(pid, xyz, rgb, err, list(track)) for pid, xyz, rgb, err, track in records]
            broken(bad)
            writer(root / "sparse" / "0", cams, images, bad)
            out = tmp_path / f"out_{fmt}"
            with pytest.raises(InputError) as err:
                convert_colmap(root, out)
            assert err.value.where == str(pfile) and problem in err.value.problem, err.value
            assert not (out / "transforms.json").exists()  # checked before anything is written
        # --no-points ignores them (the broken file is not read at all).
        scene = convert_colmap(root, tmp_path / f"ok_{fmt}", keep_points=False)
        assert scene.sparse_points() is None


# --------------------------------------------------------------------------------------------- predictions
def test_predictions_in_both_layouts_give_the_same_labels(tmp_path):
    colmap_capture(tmp_path / "a", "txt", n=3, predictions="two-png")
    colmap_capture(tmp_path / "b", "txt", n=3, predictions="coco")
    sa = convert_colmap(tmp_path / "a", tmp_path / "out_a")
    sb = convert_colmap(tmp_path / "b", tmp_path / "out_b")
    assert sb.thing_ids == [2] and [c.name for c in sb.categories] == ["wall", "chair", "floor"]
    for i in range(3):
        la, lb = sa.pseudo_labels(i), sb.pseudo_labels(i)
        sem, inst = label_maps(i)
        np.testing.assert_array_equal(la.semantic, sem)
        np.testing.assert_array_equal(lb.semantic, sem)
        for lab in (la, lb):
            # Same partition into objects as the source's instance ids (ids themselves are per-frame).
            for src_id in (10 + i, 50 + 7 * i):
                ids = np.unique(lab.instance[inst == src_id])
                assert ids.size == 1 and ids[0] != 0
            assert np.all(lab.instance[sem != 2] == 0)
            assert len(np.unique(lab.instance[sem == 2])) == 2
        # COCO scores reach the confidence map; the two-PNG layout has none (1).
        # Scores were 0.5, 0.6, 0.7, 0.8 for wall, first chair, second chair, floor.
        for region, score in ((sem == 1, 0.5), (inst == 10 + i, 0.6), (inst == 50 + 7 * i, 0.7), (sem == 3, 0.8)):
            np.testing.assert_allclose(lb.confidence[region], score, atol=1e-6)
        np.testing.assert_array_equal(la.confidence[sem > 0], 1.0)


def test_two_png_confidence_and_generic_categories(tmp_path):
    stems = ["a", "b"]
    write_two_png_predictions(tmp_path / "pred", stems, confidence=True)
    preds = PredictionFolder(tmp_path / "pred", things=[2])
    cats = preds.resolve_categories(stems, progress=False)
    assert [(c.id, c.name, c.isthing) for c in cats] == [(1, "class_1", False), (2, "class_2", True),
                                                         (3, "class_3", False)]
    fr = preds.labels("b")
    np.testing.assert_allclose(fr.confidence, 0.35, atol=1e-4)
    with pytest.raises(InputError, match="--categories"):
        PredictionFolder(tmp_path / "pred").resolve_categories(stems, progress=False)


# --------------------------------------------------------------------------------------------- Panoptic Lifting
def panoptic_lifting_folder(root, n=4):
    """A Panoptic Lifting scene: OpenCV c2w poses, integer-centred K, m2f labels, rs ground truth."""
    stems = [str(k) for k in range(n)]
    write_images(root / "color", stems, ".jpg")
    (root / "pose").mkdir()
    rigs = camera_rigs()[:n]
    for stem, (r_c2w, eye) in zip(stems, rigs):
        c2w = np.eye(4)
        c2w[:3, :3], c2w[:3, 3] = r_c2w, eye
        (root / "pose" / f"{stem}.txt").write_text("\n".join(" ".join(f"{v:.12f}" for v in row) for row in c2w))
    (root / "intrinsic").mkdir()
    k4 = np.array([[40.0, 0, 23.0, 0], [0, 42.0, 17.0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    (root / "intrinsic" / "intrinsic_color.txt").write_text("\n".join(" ".join(map(str, r)) for r in k4))
    for d in ("m2f_semantics", "m2f_instance", "m2f_probabilities", "rs_semantics", "rs_instance", "invalid"):
        (root / d).mkdir()
    for k, stem in enumerate(stems):
        sem, inst = label_maps(k)
        cv2.imwrite(str(root / "m2f_semantics" / f"{stem}.png"), sem.astype(np.uint16))
        cv2.imwrite(str(root / "m2f_instance" / f"{stem}.png"), (inst + 100 * k).astype(np.uint16))
        # Confidence at half resolution, as segmenters often store it: it is resized on conversion.
        np.savez_compressed(root / "m2f_probabilities" / f"{stem}.npz", probability=np.zeros((H // 2, W // 2, 4)),
                            confidence=np.full((H // 2, W // 2), 0.2 + 0.1 * k, np.float32))
        gt_inst = np.where(sem == 2, np.where(np.arange(W)[None] < 20, 1, 2), 0)  # two objects, same ids always
        cv2.imwrite(str(root / "rs_semantics" / f"{stem}.png"), sem.astype(np.uint8))
        cv2.imwrite(str(root / "rs_instance" / f"{stem}.png"), gt_inst.astype(np.uint16))
        invalid = np.zeros((H, W), np.uint8)
        invalid[:2] = 255
        cv2.imwrite(str(root / "invalid" / f"{stem}.png"), invalid)
    (root / "splits.json").write_text(json.dumps({"train": stems[1:], "test": [0]}))  # numbers occur too
    with open(root / "segmentation_data.pkl", "wb") as fh:
        pickle.dump({"num_semantic_classes": 4, "fg_classes": [2], "bg_classes": [0, 1, 3],
                     "gt_bboxes": {0: {"position": np.zeros(3), "class": np.int64(2)}}}, fh)
    return stems, rigs, k4


def test_panoptic_lifting_folder(tmp_path):
    stems, rigs, k4 = panoptic_lifting_folder(tmp_path / "pl")
    scene = panoptic_lifting.convert(tmp_path / "pl", tmp_path / "out", options=QUIET)
    assert [f.name for f in scene.frames] == stems
    assert [c.id for c in scene.categories] == [1, 2, 3] and scene.thing_ids == [2]
    assert [scene.frames[i].name for i in scene.split("train")] == ["1", "2", "3"]
    assert [scene.frames[i].name for i in scene.split("test")] == ["0"]
    # Panoptic Lifting's ray through pixel (i, j) is ((i - cx)/fx, (j - cy)/fy, 1): integer pixel centres.
    # The same world point must land at the centre (+0.5) of that pixel in lift3d.
    fx, fy, cx, cy = k4[0, 0], k4[1, 1], k4[0, 2], k4[1, 2]
    for f, (r_c2w, eye) in enumerate(rigs):
        for i, j, depth in ((5, 7, 1.3), (30, 20, 2.0)):
            x_world = eye + r_c2w @ (depth * np.array([(i - cx) / fx, (j - cy) / fy, 1.0]))
            uv, z = scene.cameras.project(f, x_world[None])
            np.testing.assert_allclose(uv[0], [i + 0.5, j + 0.5], atol=1e-6)
            np.testing.assert_allclose(z[0], depth, atol=1e-9)
    # Ground truth keeps one id per object across frames; pseudo-labels stay per frame.
    ids_left, ids_right = set(), set()
    for f in range(len(stems)):
        gt = scene.gt_labels(f)
        sem, _ = label_maps(f)
        assert np.all(gt.instance[sem != 2] == 0)
        ids_left.update(np.unique(gt.instance[(sem == 2) & (np.arange(W)[None] < 20)]).tolist())
        ids_right.update(np.unique(gt.instance[(sem == 2) & (np.arange(W)[None] >= 20)]).tolist())
        np.testing.assert_array_equal(gt.semantic, sem)
        pl = scene.pseudo_labels(f)
        np.testing.assert_allclose(pl.confidence[sem > 0], 0.2 + 0.1 * f, atol=1e-4)
        assert not scene.mask(f)[:2].any() and scene.mask(f)[2:].all()
    assert len(ids_left) == 1 and len(ids_right) == 1 and ids_left != ids_right and 0 not in ids_left


def test_panoptic_lifting_things_flag_and_no_gt(tmp_path):
    panoptic_lifting_folder(tmp_path / "pl")
    (tmp_path / "pl" / "segmentation_data.pkl").unlink()
    with pytest.raises(InputError, match="--things"):
        panoptic_lifting.convert(tmp_path / "pl", tmp_path / "out", options=QUIET)
    scene = panoptic_lifting.convert(tmp_path / "pl", tmp_path / "out", things=[2, 3], use_gt=False,
                                     use_confidence=False, options=QUIET)
    assert scene.thing_ids == [2, 3] and not scene.has_gt
    sem, _ = label_maps(0)
    np.testing.assert_array_equal(scene.pseudo_labels(0).confidence[sem > 0], 1.0)


def test_panoptic_lifting_pickle_cannot_run_code(tmp_path):
    panoptic_lifting_folder(tmp_path / "pl")

    class Evil:
        def __reduce__(self):
            return (Path.touch, (tmp_path / "pwned",))

    with open(tmp_path / "pl" / "segmentation_data.pkl", "wb") as fh:
        pickle.dump({"fg_classes": [2], "x": Evil()}, fh)
    with pytest.raises(InputError, match="plain-data"):
        panoptic_lifting.convert(tmp_path / "pl", tmp_path / "out", options=QUIET)
    assert not (tmp_path / "pwned").exists()


# --------------------------------------------------------------------------------------------- ScanNet
def scannet_folder(root, n=4):
    stems = [str(k) for k in (0, 2, 10, 11)][:n]  # natural order 0, 2, 10, 11 (not 0, 10, 11, 2)
    write_images(root / "color", stems, ".jpg")
    (root / "pose").mkdir()
    rigs = camera_rigs()[:n]
    for stem, (r_c2w, eye) in zip(stems, rigs):
        c2w = np.eye(4)
        c2w[:3, :3], c2w[:3, 3] = r_c2w, eye
        np.savetxt(root / "pose" / f"{stem}.txt", c2w)
    (root / "intrinsic").mkdir()
    np.savetxt(root / "intrinsic" / "intrinsic_color.txt",
               np.array([[40.0, 0, 23.0, 0], [0, 40.0, 17.5, 0], [0, 0, 1, 0], [0, 0, 0, 1]]))
    (root / "depth").mkdir()
    for k, stem in enumerate(stems):
        cv2.imwrite(str(root / "depth" / f"{stem}.png"), np.full((H, W), 1500 + 10 * k, np.uint16))
    write_coco_predictions(root / "pred", stems)
    return stems, rigs


def test_scannet_folder(tmp_path):
    stems, rigs = scannet_folder(tmp_path / "sn")
    # A frame with lost tracking (ScanNet writes -inf) is skipped, not an error.
    write_images(tmp_path / "sn" / "color", ["12"], ".jpg")
    (tmp_path / "sn" / "pose" / "12.txt").write_text("\n".join(["-inf -inf -inf -inf"] * 4))
    scene = scannet.convert(tmp_path / "sn", tmp_path / "out", predictions=tmp_path / "sn" / "pred",
                            test_every=2, options=QUIET)
    assert [f.name for f in scene.frames] == stems
    assert [scene.frames[i].name for i in scene.split("test")] == ["0", "10"]
    assert scene.has_depth
    np.testing.assert_allclose(scene.depth(2), 1.52, atol=1e-6)
    np.testing.assert_allclose([scene.cameras.cx[0], scene.cameras.cy[0]], [23.5, 18.0])
    r_c2w, eye = rigs[1]
    x_world = eye + r_c2w @ np.array([0.1, -0.2, 1.0])
    uv, _ = scene.cameras.project(1, x_world[None])
    np.testing.assert_allclose(uv[0], [40 * 0.1 + 23.5, 40 * -0.2 + 18.0], atol=1e-6)


def test_scannet_without_predictions_is_a_scene_to_label(tmp_path):
    from lift3d.train.trainer import train

    stems, _ = scannet_folder(tmp_path / "sn")
    scene = scannet.convert(tmp_path / "sn", tmp_path / "out", predictions=None, options=QUIET)
    assert not scene.has_pseudo_labels and scene.categories == [] and scene.has_depth
    assert [f.name for f in scene.frames] == stems
    assert not (tmp_path / "out" / "panoptic.json").exists() and not (tmp_path / "out" / "panoptic").exists()
    with pytest.raises(InputError) as err:
        train(tmp_path / "out", preset="fast", output_dir=tmp_path / "runs", progress=False, print_summary=False)
    assert err.value.where == str(tmp_path / "out") and "no pseudo-labels: run lift3d label" in err.value.problem
    assert not (tmp_path / "runs").exists()  # refused before a run folder is made
    with pytest.raises(InputError, match="--categories"):
        scannet.convert(tmp_path / "sn", tmp_path / "out2", predictions=None, options=QUIET,
                        categories=[Category(1, "wall", False)])


def test_depth_as_gt_is_for_evaluation_only(tmp_path, monkeypatch):
    """--depth-as-gt: training never reads the capture's depth; lift3d eval scores rendered depth against it."""
    import lift3d.data.scene as scene_module
    from lift3d.eval.evaluate import EvalOptions, evaluate_run
    from lift3d.train.trainer import train

    scannet_folder(tmp_path / "sn")
    scene = scannet.convert(tmp_path / "sn", tmp_path / "out", predictions=tmp_path / "sn" / "pred",
                            test_every=2, options=WriteOptions(depth_as_gt=True, progress=False))
    assert not scene.has_depth and all(f.depth_path is None for f in scene.frames)
    assert [f.gt_depth_path.relative_to(tmp_path / "out").as_posix() for f in scene.frames] == \
        [f"gt/depth/{f.name}.png" for f in scene.frames]
    np.testing.assert_allclose(scene.gt_depth(2), 1.52, atol=1e-6)  # the source's depth, unchanged

    depth_reads = []
    real_read_depth = scene_module.read_depth
    monkeypatch.setattr(scene_module, "read_depth", lambda path, *a: depth_reads.append(Path(path)) or
                        real_read_depth(path, *a))
    result = train(tmp_path / "out", preset="fast", output_dir=tmp_path / "runs", progress=False,
                   print_summary=False,
                   overrides={"optim": {"steps": 3}, "losses": {"feature": 0.0},
                              "field": {"grid": {"resolution_cap": 16}},
                              "data": {"rays_per_image": 32, "patch_size": 0},
                              "trainer": {"eval_every": 0, "eval_images": 0, "checkpoint_every": 0}})
    assert depth_reads == [] and result.summary["depth_supervision"] is False
    m = evaluate_run(result.run.path, EvalOptions(with_points3d=False, timing_repeats=0, instances="field"),
                     progress=False, write=False)
    assert m["depth"]["reference"] == "gt_depth" and m["depth"]["n_valid"] == 2 * W * H
    assert {p.name for p in depth_reads} == {"0.png", "10.png"}  # the two test frames' gt/depth maps
    assert all(p.parent == tmp_path / "out" / "gt" / "depth" for p in depth_reads)


def block_mode_reference(labels, n):
    """Most frequent value of each n x n block (smallest on ties), one block at a time."""
    out = np.zeros((labels.shape[0] // n, labels.shape[1] // n), labels.dtype)
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            values, counts = np.unique(labels[i * n:(i + 1) * n, j * n:(j + 1) * n], return_counts=True)
            out[i, j] = values[np.argmax(counts)]  # np.unique sorts: the first maximum is the smallest value
    return out


def test_downscale_keeps_rays_and_ids(tmp_path):
    scannet_folder(tmp_path / "sn", n=2)
    full = scannet.convert(tmp_path / "sn", tmp_path / "full", predictions=tmp_path / "sn" / "pred", options=QUIET)
    half = scannet.convert(tmp_path / "sn", tmp_path / "half", predictions=tmp_path / "sn" / "pred",
                           options=WriteOptions(downscale=2, progress=False))
    assert half.image(0).shape == (H // 2, W // 2, 3)
    x_world = np.array([[0.3, 0.1, 0.2]])
    np.testing.assert_allclose(half.cameras.project(0, x_world)[0], full.cameras.project(0, x_world)[0] / 2)
    for f in range(2):
        np.testing.assert_array_equal(half.pseudo_labels(f).segment,
                                      block_mode_reference(full.pseudo_labels(f).segment, 2))
    assert half.depth(0).shape == (H // 2, W // 2)


# --------------------------------------------------------------------------------------------- Open3D
O3D_K = (40.0, 42.0, 23.0, 17.5)  # fx, fy, cx, cy in Open3D's convention (integer pixel centres)


def open3d_folder(root, n=5, colour="image", poses="log", predictions=True):
    """An Open3D RGB-D dataset folder whose pose and intrinsic files are written by Open3D itself."""
    import open3d as o3d

    stems = [f"{k:05d}" for k in range(n)]
    write_images(root / colour, stems, ".jpg")
    (root / "depth").mkdir(parents=True)
    rng = np.random.default_rng(1)
    for stem in stems:
        depth = rng.integers(800, 3000, (H, W)).astype(np.uint16)
        depth[:3, :5] = 0  # a hole
        cv2.imwrite(str(root / "depth" / f"{stem}.png"), depth)
    intrinsic = o3d.camera.PinholeCameraIntrinsic(W, H, *O3D_K)
    o3d.io.write_pinhole_camera_intrinsic(str(root / "intrinsic.json"), intrinsic)
    rigs = camera_rigs()[:n]
    c2ws = []
    for r_c2w, eye in rigs:
        c2w = np.eye(4)
        c2w[:3, :3], c2w[:3, 3] = r_c2w, eye
        c2ws.append(c2w)
    if poses == "posegraph":
        graph = o3d.pipelines.registration.PoseGraph()
        for c2w in c2ws:
            graph.nodes.append(o3d.pipelines.registration.PoseGraphNode(c2w))
        pose_file = root / "poses.json"
        o3d.io.write_pose_graph(str(pose_file), graph)
    else:
        trajectory = o3d.camera.PinholeCameraTrajectory()
        params = []
        for c2w in c2ws:
            p = o3d.camera.PinholeCameraParameters()
            p.intrinsic, p.extrinsic = intrinsic, np.linalg.inv(c2w)  # Open3D's extrinsic: world-to-camera
            params.append(p)
        trajectory.parameters = params
        pose_file = root / "scene" / "trajectory.log" if poses == "log" else root / "trajectory.json"
        pose_file.parent.mkdir(exist_ok=True)
        o3d.io.write_pinhole_camera_trajectory(str(pose_file), trajectory)
    if predictions:
        write_coco_predictions(root / "pred", stems)
    return stems, c2ws, pose_file


def convert_open3d(root, out, **kw):
    from lift3d.convert import open3d_rgbd

    kw.setdefault("options", QUIET)
    return open3d_rgbd.convert(root, out, intrinsic=kw.pop("intrinsic", None), **kw)


@pytest.mark.parametrize("poses", ["log", "posegraph", "trajectory-json"])
def test_open3d_poses_and_intrinsics_round_trip(tmp_path, poses):
    import open3d as o3d

    root = tmp_path / "o3d"
    stems, c2ws, pose_file = open3d_folder(root, poses=poses)
    scene = convert_open3d(root, tmp_path / "out", predictions=root / "pred",
                           poses=None if poses == "log" else pose_file)
    assert [f.name for f in scene.frames] == stems and scene.has_depth and scene.has_pseudo_labels
    exact = 1e-7 if poses == "log" else 1e-12  # the .log holds 8 decimals
    np.testing.assert_allclose(scene.cameras.centers, [c[:3, 3] for c in c2ws], atol=exact)
    np.testing.assert_allclose(scene.cameras.c2w_opencv, c2ws, atol=exact)  # same world frame, OpenCV axes
    fx, fy, cx, cy = O3D_K
    np.testing.assert_allclose([scene.cameras.fx[0], scene.cameras.fy[0], scene.cameras.cx[0], scene.cameras.cy[0]],
                               [fx, fy, cx + 0.5, cy + 0.5])
    # Open3D's own reading of the same files back-projects every depth pixel where lift3d's cameras do.
    intrinsic = o3d.io.read_pinhole_camera_intrinsic(str(root / "intrinsic.json"))
    if poses == "posegraph":
        extrinsics = [np.linalg.inv(node.pose) for node in o3d.io.read_pose_graph(str(pose_file)).nodes]
    else:
        extrinsics = [p.extrinsic for p in o3d.io.read_pinhole_camera_trajectory(str(pose_file)).parameters]
    rows, cols = (a.ravel() for a in np.mgrid[0:H, 0:W])
    for i, stem in enumerate(stems):
        depth_png = o3d.io.read_image(str(root / "depth" / f"{stem}.png"))
        theirs = np.asarray(o3d.geometry.PointCloud.create_from_depth_image(
            depth_png, intrinsic, extrinsics[i], depth_scale=1000.0, depth_trunc=1e9,
            project_valid_depth_only=False).points)  # row-major over pixels, NaN where there is no depth
        z = scene.depth(i).ravel()
        ok = z > 0
        np.testing.assert_array_equal(ok, np.isfinite(theirs[:, 0]))
        mine = scene.cameras.unproject(i, cols[ok], rows[ok], z[ok])
        np.testing.assert_allclose(mine, theirs[ok], atol=1e-5)


def test_frame_step_keeps_every_nth_frame_before_the_test_split(tmp_path):
    import dataclasses

    root = tmp_path / "o3d"
    stems, c2ws, _ = open3d_folder(root, n=5)
    scene = convert_open3d(root, tmp_path / "out", predictions=root / "pred", test_every=2,
                           options=dataclasses.replace(QUIET, frame_step=2))
    assert [f.name for f in scene.frames] == stems[::2]  # frames 0, 2, 4
    np.testing.assert_allclose(scene.cameras.c2w_opencv, c2ws[::2], atol=1e-7)  # each keeps its own pose
    np.testing.assert_allclose(scene.depth(1), cv2.imread(str(root / "depth" / f"{stems[2]}.png"),
                                                          cv2.IMREAD_UNCHANGED) / 1000.0, atol=1e-6)
    # the test split is every 2nd of the frames kept, not of the source's
    assert [scene.frames[i].name for i in scene.split("test")] == [stems[0], stems[4]]
    with pytest.raises(InputError, match="--frame-step"):
        convert_open3d(root, tmp_path / "out2", predictions=root / "pred",
                       options=dataclasses.replace(QUIET, frame_step=0))


def test_open3d_primesense_only_by_name(tmp_path):
    root = tmp_path / "o3d"
    open3d_folder(root)
    (root / "intrinsic.json").unlink()
    with pytest.raises(InputError) as err:
        convert_open3d(root, tmp_path / "out")
    assert err.value.where == "--intrinsic" and "primesense" in err.value.problem
    assert not (tmp_path / "out").exists()
    # 48x36 frames have PrimeSense's 4:3 shape: its 640x480 intrinsics are scaled to them.
    scene = convert_open3d(root, tmp_path / "out", intrinsic="primesense")
    s = W / 640
    np.testing.assert_allclose([scene.cameras.fx[0], scene.cameras.cx[0], scene.cameras.cy[0]],
                               [525 * s, (319.5 + 0.5) * s, (239.5 + 0.5) * s])
    assert not scene.has_pseudo_labels and scene.categories == []


def test_open3d_colour_folder_names_and_depth_as_gt(tmp_path):
    root = tmp_path / "o3d"
    stems, _, _ = open3d_folder(root, colour="color")
    scene = convert_open3d(root, tmp_path / "out", predictions=root / "pred", test_every=0,
                           options=WriteOptions(depth_as_gt=True, progress=False))
    assert not scene.has_depth and len(scene.split("train")) == len(stems)
    source = cv2.imread(str(root / "depth" / f"{stems[3]}.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_allclose(scene.gt_depth(3), source / 1000.0, atol=1e-6)


def test_open3d_without_predictions_is_labelled_afterwards(tmp_path):
    from lift3d.label import label_from_predictions

    root = tmp_path / "o3d"
    stems, _, _ = open3d_folder(root, predictions=False)
    scene = convert_open3d(root, tmp_path / "out")
    assert not scene.has_pseudo_labels and scene.has_depth
    (tmp_path / "d2").mkdir()
    for stem in stems:  # detectron2-style predictions: COCO's contiguous class 0 is "person", 43 "table"
        seg = np.ones((H, W), np.int32)
        seg[:, W // 2:] = 2
        np.savez(tmp_path / "d2" / f"{stem}.npz", panoptic_seg=seg, segments_info=json.dumps(
            [{"id": 1, "category_id": 0, "isthing": True, "score": 0.9},
             {"id": 2, "category_id": 43, "isthing": True, "score": 0.8}]))
    label_from_predictions(tmp_path / "out", tmp_path / "d2", progress=False)
    labelled = load_scene(tmp_path / "out")
    assert labelled.has_pseudo_labels and len(labelled.categories) > 0 and labelled.has_depth
    labelled.validate()


def test_open3d_bad_input_is_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("LIFT3D_NO_PROGRESS", "1")
    root = tmp_path / "o3d"
    stems, _, log = open3d_folder(root)

    def fails(where, fragment, *flags):
        rc = cli_main(["convert", "--from", "open3d", str(root), "--out", str(tmp_path / "out"), *flags])
        lines = capsys.readouterr().err.strip().splitlines()
        errors = [line for line in lines if ": error: " in line]
        assert rc == 2 and len(errors) == 1 and all(line.startswith("lift3d convert: ") for line in lines), lines
        assert errors[0].startswith(f"lift3d convert: error: {where}: ") and fragment in errors[0], errors
        assert not (tmp_path / "out").exists()  # checked before anything is written

    original = log.read_text()
    # Poses: missing, count mismatch, not rigid, truncated, several candidates.
    log.rename(tmp_path / "elsewhere.log")
    fails(root, "no poses")
    fails(tmp_path / "nope.log", "file not found", "--poses", str(tmp_path / "nope.log"))
    log.write_text(original)
    (root / "image" / f"{stems[-1]}.jpg").unlink()
    (root / "depth" / f"{stems[-1]}.png").unlink()
    fails(log, f"has {len(stems)} poses but {root / 'image'} has {len(stems) - 1} colour frames")
    write_images(root / "image", stems[-1:], ".jpg")
    fails(root / "depth", f"has {len(stems) - 1} depth frames but image/ has {len(stems)} colour frames")
    cv2.imwrite(str(root / "depth" / "00009.png"), np.zeros((H, W), np.uint16))  # stems match, order does not
    fails(root / "depth", "colour frame '00004' pairs with depth frame '00009'")
    (root / "depth" / "00009.png").rename(root / "depth" / f"{stems[-1]}.png")
    lines = original.splitlines()
    lines[6] = "2 0 0 0"  # frame 1's first row: a scaled rotation
    log.write_text("\n".join(lines) + "\n")
    fails(log, "line 6: the pose of frame 1 is not a rigid transform")
    log.write_text("\n".join(original.splitlines()[:-2]) + "\n")
    fails(log, "the file ends before this frame's 4x4 matrix is complete")
    log.write_text("\n".join(original.splitlines()[:1] + ["1.0 x 0 0"] + original.splitlines()[2:]) + "\n")
    fails(log, "line 2: expected a row of four numbers")
    log.write_text(original)
    for folder in ("test_scene", "other"):  # no DIR/trajectory.log, no DIR/scene/trajectory.log: which one?
        (root / folder).mkdir(exist_ok=True)
        (root / folder / "trajectory.log").write_text(original)
    log.unlink()
    fails(root, "several trajectory.log files (other/trajectory.log, test_scene/trajectory.log)")
    (root / "other" / "trajectory.log").unlink()
    log = root / "test_scene" / "trajectory.log"  # the only one left is found
    # Intrinsics: not JSON, no size, row-major matrix, depth unit contradicting --depth-scale.
    good = json.loads((root / "intrinsic.json").read_text())
    (root / "intrinsic.json").write_text('{"width": 48,')
    fails(root / "intrinsic.json", "not valid JSON")
    (root / "intrinsic.json").write_text(json.dumps({**good, "width": None}))
    fails(root / "intrinsic.json", "width/height")
    fx, fy, cx, cy = O3D_K
    (root / "intrinsic.json").write_text(json.dumps({**good, "intrinsic_matrix": [fx, 0, cx, 0, fy, cy, 0, 0, 1]}))
    fails(root / "intrinsic.json", "written row by row")
    (root / "intrinsic.json").write_text(json.dumps({**good, "depth_scale": 4000.0}))
    fails(root / "intrinsic.json", "pass --depth-scale 0.00025")
    intrinsic = tmp_path / "k.json"
    intrinsic.write_text(json.dumps(good))
    # A pose graph with one node per fragment instead of per frame.
    graph = {"class_name": "PoseGraph", "nodes": [{"pose": np.eye(4).ravel().tolist()}] * 2, "edges": []}
    (tmp_path / "scene_graph.json").write_text(json.dumps(graph))
    fails(tmp_path / "scene_graph.json", "one node per fragment", "--intrinsic", str(intrinsic),
          "--poses", str(tmp_path / "scene_graph.json"))
    fails("--intrinsic", "is not used with --from scannet", "--intrinsic", "primesense", "--from", "scannet")
    fails("--depth-as-gt", "--no-depth", "--depth-as-gt", "--no-depth")
    # All fixed: the one */trajectory.log left is used, and said so.
    (root / "intrinsic.json").write_text(json.dumps(good))
    assert cli_main(["convert", "--from", "open3d", str(root), "--out", str(tmp_path / "ok")]) == 0
    assert f"poses from {log}" in capsys.readouterr().err
    assert load_scene(tmp_path / "ok").cameras.c2w.shape == (len(stems), 4, 4)
    # Unreadable pixels are found while writing; the message names the file all the same.
    for broken in (root / "image" / f"{stems[2]}.jpg", root / "depth" / f"{stems[3]}.png"):
        good_bytes = broken.read_bytes()
        broken.write_bytes(good_bytes[:40])
        rc = cli_main(["convert", "--from", "open3d", str(root), "--out", str(tmp_path / "bad"), "--overwrite"])
        errors = [line for line in capsys.readouterr().err.splitlines() if ": error: " in line]
        assert rc == 2 and len(errors) == 1 and f"error: {broken}: " in errors[0], errors
        broken.write_bytes(good_bytes)


# --------------------------------------------------------------------------------------------- --downscale
def write_frames(tmp_path, images, depths_mm, panoptics, confidences=None, masks=None,
                 intrinsics=(30.0, 30.0, 24.0, 18.0)):
    """write_scene's own input (the path every source takes): images, uint16 depth PNGs and label loaders."""
    from lift3d.convert import FrameInput, PanopticFrame
    from lift3d.data.scene import Segment

    src = tmp_path / "src"
    src.mkdir(exist_ok=True)
    frames = []
    for k, (img, depth, pan) in enumerate(zip(images, depths_mm, panoptics)):
        cv2.imwrite(str(src / f"f{k}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(src / f"d{k}.png"), depth.astype(np.uint16))
        mask_path = None
        if masks is not None:
            mask_path = src / f"m{k}.png"
            cv2.imwrite(str(mask_path), masks[k].astype(np.uint8) * 255)
        conf = None if confidences is None else confidences[k]
        segments = [Segment(int(i), 1 + int(i) % 2, 1.0) for i in np.unique(pan) if i != 0]
        frames.append(FrameInput(
            name=f"f{k}", image_path=src / f"f{k}.png", c2w_opencv=np.eye(4), pose_source=src,
            intrinsics=intrinsics, intrinsics_size=None, depth_path=src / f"d{k}.png", mask_path=mask_path,
            labels=lambda pan=pan, conf=conf, segments=segments: PanopticFrame(pan.copy(), segments, conf, src)))
    return frames


TWO_CLASSES = [Category(1, "wall", False), Category(2, "chair", True)]


@pytest.mark.parametrize("n", [2, 4, 5])
def test_downscaled_depth_is_the_value_at_the_block_centre(tmp_path, n):
    from lift3d.convert import write_scene

    h, w = 36, 48  # not a multiple of 5: the last columns and rows are dropped, nothing is shifted
    # A linear depth ramp sampled at pixel centres (c + 0.5, r + 0.5), in mm; whole numbers for any block.
    ramp = lambda x, y: 1000.0 + 10.0 * x + 4.0 * y  # noqa: E731
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    depth = ramp(cols, rows)
    holes = depth.copy()
    holes[:n, :n] = 0                       # a block without depth stays without depth
    holes[n:2 * n, n:2 * n:2] = 0           # a block with holes: the median of what is left
    frames = write_frames(tmp_path, [np.zeros((h, w, 3), np.uint8)] * 2, [depth, holes],
                          [np.ones((h, w), np.int64)] * 2)
    full = write_scene(tmp_path / "full", frames, TWO_CLASSES, options=QUIET)
    small = write_scene(tmp_path / "small", frames, TWO_CLASSES, options=WriteOptions(downscale=n, progress=False))
    nh, nw = h // n, w // n
    assert small.image(0).shape == (nh, nw, 3)
    col, row = (a.ravel() for a in np.meshgrid(np.arange(nw), np.arange(nh)))
    uv = np.stack([col + 0.5, row + 0.5], -1)  # output pixel centres
    # The ray through an output pixel centre is the full-size ray through its block's centre (normalized_coords
    # takes pixel indices and adds the 0.5 itself) ...
    np.testing.assert_allclose(small.cameras.normalized_coords(0, col, row),
                               full.cameras.normalized_coords(0, n * uv[:, 0] - 0.5, n * uv[:, 1] - 0.5), atol=1e-12)
    # ... and the depth there is the ramp's value at that centre (1 mm units, so exact).
    expected = ramp(n * uv[:, 0], n * uv[:, 1]).reshape(nh, nw) / 1000.0
    np.testing.assert_allclose(small.depth(0), expected, atol=1e-6)
    got = small.depth(1)
    assert got[0, 0] == 0.0
    block = holes[n:2 * n, n:2 * n]
    assert got[1, 1] == pytest.approx(np.median(block[block > 0]) / 1000.0, abs=1e-6)
    np.testing.assert_allclose(got[2:, 2:], expected[2:, 2:], atol=1e-6)


def test_downscaled_label_edges_stay_on_the_image_edges(tmp_path):
    from lift3d.convert import write_scene

    h, w, n = 32, 48, 4
    cols = np.arange(w)[None].repeat(h, 0)
    rows = np.arange(h)[:, None].repeat(w, 1)
    # A vertical edge 1 px right of a block boundary (top half) and 1 px left of one (bottom half), and a
    # horizontal one 1 px below a boundary; labels have their edges exactly where the image has its own.
    right = np.where(rows < 16, cols >= 17, cols >= 23) | (rows >= 29)
    image = np.where(right[..., None], np.uint8(200), np.uint8(20)).repeat(3, -1)
    pan = np.where(right, 41601, 7).astype(np.int64)       # ids past 8 bits stay exact
    confidence = np.where(right, 0.9, 0.1).astype(np.float32)
    ignore = np.zeros((h, w), bool)
    ignore[:, :2] = True        # whole-block halves: a tie, ignored
    ignore[:, 4:7] = True       # three of four columns: ignored
    frames = write_frames(tmp_path, [image], [np.full((h, w), 1500)], [pan], [confidence], [ignore])
    small = write_scene(tmp_path / "small", frames, TWO_CLASSES, options=WriteOptions(downscale=n, progress=False))
    img = small.image(0)[..., 0].astype(float)
    labels = small.pseudo_labels(0)
    # Each output label is the one whose colour the block's mean colour is nearer to.
    nearer_right = np.abs(img - 200) < np.abs(img - 20)
    np.testing.assert_array_equal(labels.segment, np.where(nearer_right, 41601, 7))
    assert labels.segment[0, 4] == 41601 and labels.segment[-1, 0] == 41601  # sampling top-left gives 7 here
    # Confidence is the block mean; it is multiplied by the segment's score (1 here).
    np.testing.assert_allclose(labels.confidence, block_mean_reference(confidence, n), atol=1e-4)
    # mask_path: 0 = ignore
    assert not small.mask(0)[:, 0].any() and not small.mask(0)[:, 1].any() and small.mask(0)[:, 2:].all()


def block_mean_reference(arr, n):
    h, w = arr.shape[0] // n * n, arr.shape[1] // n * n
    return arr[:h, :w].reshape(h // n, n, w // n, n).mean(axis=(1, 3))


# --------------------------------------------------------------------------------------------- bad input
def test_missing_cameras_file(tmp_path):
    colmap_capture(tmp_path / "ws", "txt")
    missing = tmp_path / "ws" / "sparse" / "0" / "cameras.txt"
    missing.unlink()
    with pytest.raises(InputError) as err:
        convert_colmap(tmp_path / "ws", tmp_path / "out")
    assert err.value.where == str(missing)


def test_image_listed_in_colmap_but_missing_on_disk(tmp_path):
    colmap_capture(tmp_path / "ws", "bin")
    gone = tmp_path / "ws" / "images" / "img_03.jpg"
    gone.unlink()
    with pytest.raises(InputError) as err:
        convert_colmap(tmp_path / "ws", tmp_path / "out")
    assert err.value.where == str(gone) and "images.bin" in err.value.problem
    assert not (tmp_path / "out" / "transforms.json").exists()


def test_prediction_missing_for_an_image(tmp_path):
    colmap_capture(tmp_path / "a", "txt", predictions="two-png")
    gone = tmp_path / "a" / "pred" / "instance" / "img_02.png"
    gone.unlink()
    with pytest.raises(InputError) as err:
        convert_colmap(tmp_path / "a", tmp_path / "out")
    assert err.value.where == str(gone) and "img_02" in err.value.problem
    colmap_capture(tmp_path / "b", "txt", predictions="coco")
    doc = json.loads((tmp_path / "b" / "pred" / "panoptic.json").read_text())
    doc["annotations"] = doc["annotations"][1:]
    (tmp_path / "b" / "pred" / "panoptic.json").write_text(json.dumps(doc))
    with pytest.raises(InputError) as err:
        convert_colmap(tmp_path / "b", tmp_path / "out")
    assert err.value.where.endswith("panoptic.json") and "img_00" in err.value.problem


@pytest.mark.parametrize("text, problem", [
    ("1 0 0 0\n0 1 0 0\n0 0 1 zero\n0 0 0 1", "numbers"),
    ("1 0 0 0\n0 1 0 0\n0 0 1 0", None),  # 3x4 is fine
    ("1 0 0\n0 1 0\n0 0 1", "4x4"),
    ("2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1", "rigid"),
])
def test_malformed_pose_txt(tmp_path, text, problem):
    scannet_folder(tmp_path / "sn")
    pose = tmp_path / "sn" / "pose" / "2.txt"
    pose.write_text(text)
    run = lambda: scannet.convert(tmp_path / "sn", tmp_path / "out", predictions=tmp_path / "sn" / "pred",  # noqa: E731
                                  options=QUIET)
    if problem is None:
        assert len(run()) == 4
        return
    with pytest.raises(InputError) as err:
        run()
    assert err.value.where == str(pose) and problem in err.value.problem


def test_truncated_binary_and_bad_text_lines(tmp_path):
    colmap_capture(tmp_path / "b", "bin")
    images_bin = tmp_path / "b" / "sparse" / "0" / "images.bin"
    images_bin.write_bytes(images_bin.read_bytes()[:-5])
    with pytest.raises(InputError) as err:
        convert_colmap(tmp_path / "b", tmp_path / "out")
    assert err.value.where == str(images_bin) and "truncated" in err.value.problem
    colmap_capture(tmp_path / "t", "txt")
    cams = tmp_path / "t" / "sparse" / "0" / "cameras.txt"
    cams.write_text(f"1 PINHOLE {W} {H} 40 40 24\n")  # one parameter short
    with pytest.raises(InputError) as err:
        convert_colmap(tmp_path / "t", tmp_path / "out")
    assert err.value.where == str(cams) and "line 1" in err.value.problem


def test_existing_output_needs_overwrite(tmp_path):
    colmap_capture(tmp_path / "ws", "txt", n=2)
    convert_colmap(tmp_path / "ws", tmp_path / "out")
    (tmp_path / "out" / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="--overwrite"):
        convert_colmap(tmp_path / "ws", tmp_path / "out")
    colmap_convert.convert(tmp_path / "ws", tmp_path / "out", predictions=tmp_path / "ws" / "pred",
                           categories=[Category(c["id"], c["name"], bool(c["isthing"])) for c in CATEGORIES],
                           options=WriteOptions(overwrite=True, progress=False))
    assert (tmp_path / "out" / "notes.txt").read_text() == "mine"  # only scene files are replaced


# --------------------------------------------------------------------------------------------- CLI
def test_cli_convert_and_one_line_errors(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("LIFT3D_NO_PROGRESS", "1")
    colmap_capture(tmp_path / "ws", "bin", n=3)
    rc = cli_main(["convert", "--from", "colmap", str(tmp_path / "ws"), "--predictions", str(tmp_path / "ws" / "pred"),
                   "--categories", str(tmp_path / "ws" / "categories.json"), "--out", str(tmp_path / "out"),
                   "--test-every", "0"])
    assert rc == 0
    assert "3 frames" in capsys.readouterr().out
    assert len(load_scene(tmp_path / "out").split("train")) == 3

    rc = cli_main(["convert", "--from", "colmap", str(tmp_path / "ws"), "--out", str(tmp_path / "o2")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.count("\n") == 0 and "--predictions" in err

    rc = cli_main(["convert", "--from", "scannet", str(tmp_path / "nowhere"), "--predictions", str(tmp_path),
                   "--out", str(tmp_path / "o3")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and str(tmp_path / "nowhere") in err and err.count("\n") == 0

    rc = cli_main(["convert", "--from", "panoptic-lifting", str(tmp_path / "ws"), "--images", "x",
                   "--out", str(tmp_path / "o4")])
    assert rc == 2 and "--images" in capsys.readouterr().err
