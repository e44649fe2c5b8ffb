"""``lift3d render`` and ``lift3d eval`` end to end on a tiny trained run, plus their building blocks.

One session-scoped run (10 views of 48×48, 30 training steps with a small grid) serves every test; each
test that needs a modified run or scene copies it first.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import shutil
import statistics
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from lift3d.cli.main import main
from lift3d.data.images import read_panoptic_png
from lift3d.data.scene import Category, load_scene
from lift3d.errors import InputError
from lift3d.eval.evaluate import (
    EvalOptions,
    LabelStack,
    RenderedSplit,
    compute_2d_metrics,
    evaluate_run,
    gt_labels,
    json_safe,
    metrics_from_arrays,
    pseudo_labels,
    time_render,
    write_metrics,
)
from lift3d.eval.metrics import miou, pq_scene
from lift3d.eval.report import format_eval_table
from lift3d.model.run import load_run
from lift3d.render.images import MIN_SEGMENT_FRACTION, FrameRender, merge_small_segments, render_frame
from lift3d.render.output import (
    RenderedOutputWriter,
    load_camera_path,
    panoptic_segment_ids,
    resolve_outputs,
)

TOP_KEYS = ["psnr", "miou", "pq_scene", "sq_scene", "rq_scene", "miou_strict", "pq_scene_strict",
            "sq_scene_strict", "rq_scene_strict", "things", "stuff", "depth", "pseudo_labels", "points3d",
            "render_ms_per_2048_rays", "split", "frames", "step", "run", "lift3d_version"]
KEYS_2D = ["miou", "pq_scene", "sq_scene", "rq_scene", "miou_strict", "pq_scene_strict", "sq_scene_strict",
           "rq_scene_strict", "things", "stuff"]
ALL_OUTPUTS = ["rgb", "depth", "semantic", "instance", "panoptic"]


# --------------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="session")
def trained(tmp_path_factory) -> dict:
    """A synthetic scene and a 30-step run on it: ``{"scene": Path, "run": Path}``."""
    from lift3d.synth import SynthOptions, make_scene
    from lift3d.train.trainer import train

    root = tmp_path_factory.mktemp("render_eval")
    scene = root / "scene"
    make_scene(scene, SynthOptions(kind="indoor", seed=103, n_views=10, width=48, height=48), progress=False)
    overrides = {"optim": {"steps": 30}, "losses": {"feature": 0.0}, "field": {"grid": {"resolution_cap": 32}},
                 "data": {"rays_per_image": 64, "patch_size": 8}, "trainer": {"eval_images": 1}}
    result = train(scene, preset="fast", output_dir=root / "outputs", overrides=overrides, progress=False,
                   print_summary=False)
    return {"scene": scene, "run": Path(result.run.path)}


@pytest.fixture(scope="session")
def evaluated(trained, tmp_path_factory) -> dict:
    """``lift3d eval --json`` on the session run: metrics dict, printed table, JSON path."""
    out = tmp_path_factory.mktemp("eval_json") / "sub" / "metrics.json"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["eval", "--run", str(trained["run"]), "--json", str(out), "--quiet", "--num-points", "20000"])
    assert rc == 0
    return {"metrics": json.loads((trained["run"] / "metrics.json").read_text()), "stdout": buf.getvalue(),
            "json": out}


@pytest.fixture(scope="session")
def rendered(trained, tmp_path_factory) -> dict:
    """``lift3d render`` of the train split (8 frames, every output) at downscale 2."""
    out = tmp_path_factory.mktemp("render") / "out"
    with contextlib.redirect_stdout(io.StringIO()):
        rc = main(["render", "--run", str(trained["run"]), "--split", "train", "--outputs", *ALL_OUTPUTS,
                   "confidence", "--output-dir", str(out), "--downscale", "2", "--chunk-size", "500", "--quiet"])
    assert rc == 0
    return {"dir": out, "downscale": 2, "split": "train"}


def _strict_json(path: Path):
    """Parse JSON refusing NaN / Infinity (which Python's json would otherwise accept)."""
    def bad(name):
        raise ValueError(f"non-standard JSON constant {name} in {path}")
    return json.loads(Path(path).read_text(), parse_constant=bad)


def _read(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None, path
    return img


# --------------------------------------------------------------------------------------- render
def test_render_writes_every_output_with_sizes_and_dtypes(trained, rendered):
    scene = load_scene(trained["scene"])
    frames = scene.split(rendered["split"])
    stems = [scene.frames[i].name for i in frames]
    ds = rendered["downscale"]
    for i, stem in zip(frames, stems):
        h, w = int(scene.cameras.height[i]) // ds, int(scene.cameras.width[i]) // ds
        expect = {"rgb": (np.uint8, (h, w, 3)), "depth": (np.uint16, (h, w)), "depth_vis": (np.uint8, (h, w, 3)),
                  "semantic": (np.uint16, (h, w)), "semantic_vis": (np.uint8, (h, w, 3)),
                  "instance": (np.uint16, (h, w)), "instance_vis": (np.uint8, (h, w, 3)),
                  "panoptic": (np.uint8, (h, w, 3)), "confidence": (np.uint16, (h, w))}
        for name, (dtype, shape) in expect.items():
            img = _read(rendered["dir"] / name / f"{stem}.png")
            assert img.dtype == dtype and img.shape == shape, (name, img.dtype, img.shape)
    # Nothing but the requested outputs (and their previews) and panoptic.json.
    assert sorted(p.name for p in rendered["dir"].iterdir()) == sorted(
        ["confidence", "depth", "depth_vis", "instance", "instance_vis", "panoptic", "panoptic.json", "rgb",
         "semantic", "semantic_vis"])
    # Atomic writes leave no temporary files behind.
    assert not [p for p in rendered["dir"].rglob(".*") if p.is_file()]


def test_render_ids_and_depth_are_exact(trained, rendered):
    """The 16-bit PNGs hold exactly what the model renders (an independent render_frame call)."""
    loaded = load_run(trained["run"], "cpu")
    scene = loaded.scene()
    rays = loaded.rays(scene)
    ds = rendered["downscale"]
    for i in scene.split(rendered["split"])[:3]:
        stem = scene.frames[i].name
        ref = render_frame(loaded.model, rays, int(i), loaded.norm.scale, downscale=ds)
        sem = _read(rendered["dir"] / "semantic" / f"{stem}.png")
        inst = _read(rendered["dir"] / "instance" / f"{stem}.png")
        depth_mm = _read(rendered["dir"] / "depth" / f"{stem}.png")
        np.testing.assert_array_equal(sem, ref.semantic)
        assert not inst[np.isin(sem, scene.stuff_ids)].any(), "instance must be 0 on stuff"
        expect_mm = np.where(ref.depth > 0, np.round(ref.depth.astype(np.float64) * 1000), 0)
        assert np.abs(depth_mm.astype(np.int64) - expect_mm).max() <= 1  # float32 round-off at .5 mm
        rgb = cv2.cvtColor(_read(rendered["dir"] / "rgb" / f"{stem}.png"), cv2.COLOR_BGR2RGB)
        assert np.abs(rgb.astype(int) - np.round(ref.rgb * 255).astype(int)).max() <= 1


def test_rendered_instance_ids_are_the_exports_objects(trained, rendered, tmp_path):
    """By default an object's id in the images is its id in ``lift3d export --pointcloud``'s instances.json;
    ``--instances field`` writes the field's channels, exactly as render_frame gives them."""
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["export", "--run", str(trained["run"]), "--pointcloud", "--output-dir", str(tmp_path / "x"),
                     "--quiet"]) == 0
    records = json.loads((tmp_path / "x" / "instances.json").read_text())
    records = records["instances"] if isinstance(records, dict) else records
    class_of = {int(r["id"]): int(r["class_id"]) for r in records}
    assert _strict_json(rendered["dir"] / "panoptic.json")["info"]["instances_from"] == "export"
    scene = load_scene(trained["scene"])
    seen = set()
    for i in scene.split(rendered["split"]):
        stem = scene.frames[i].name
        sem = _read(rendered["dir"] / "semantic" / f"{stem}.png").astype(np.int64)
        inst = _read(rendered["dir"] / "instance" / f"{stem}.png").astype(np.int64)
        for k in np.unique(inst[inst > 0]).tolist():
            assert k in class_of, (k, sorted(class_of))  # every id is an exported object...
            assert set(np.unique(sem[inst == k]).tolist()) == {class_of[k]}  # ...of the pixels' class
            seen.add(k)
    assert seen, "the run's renders show no exported object"

    loaded = load_run(trained["run"], "cpu")
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["render", "--run", str(trained["run"]), "--split", "test", "--outputs", "semantic", "instance",
                     "--instances", "field", "--no-previews", "--output-dir", str(tmp_path / "f"), "--quiet"]) == 0
    rays = loaded.rays(scene)
    for i in scene.split("test"):
        ref = render_frame(loaded.model, rays, int(i), loaded.norm.scale)
        inst = _read(tmp_path / "f" / "instance" / f"{scene.frames[i].name}.png")
        np.testing.assert_array_equal(inst, np.where(ref.semantic > 0, ref.instance, 0))


def test_frame_instance_ids_lift_each_pixel_where_its_ray_ends(trained):
    """At any downscale a pixel is lifted to the point its rendered ray reaches (built the renderer's way)."""
    from lift3d.export.instances import frame_instance_ids

    scene = load_scene(trained["scene"])
    loaded = load_run(trained["run"], "cpu")
    i = int(scene.split("test")[0])
    for ds in (1, 2, 3):
        o, d, cos, (h, w) = loaded.rays(scene).image_rays(i, ds)
        depth = np.linspace(1.0, 3.0, h * w).reshape(h, w).astype(np.float32)  # z-depth, world units
        # The renderer's depth is the ray's length in the field's frame times cos / scale (render_frame).
        t = torch.from_numpy(depth.ravel()).double() * loaded.norm.scale / cos.double()
        xyz = loaded.norm.to_world((o.double() + d.double() * t[:, None]).numpy())
        sem = np.full((h, w), 7)
        ids = frame_instance_ids(scene.cameras, i, sem, depth, xyz, np.full(h * w, 7), np.arange(1, h * w + 1),
                                 things=[7], downscale=ds)
        assert np.array_equal(ids.ravel(), np.arange(1, h * w + 1)), ds


def test_panoptic_png_and_json_agree_and_ids_are_consistent_across_frames(trained, rendered):
    doc = _strict_json(rendered["dir"] / "panoptic.json")
    div = doc["info"]["label_divisor"]
    scene = load_scene(trained["scene"])
    assert {c["id"] for c in doc["categories"]} == {c.id for c in scene.categories}
    stems = [scene.frames[i].name for i in scene.split(rendered["split"])]
    assert [a["file_name"] for a in doc["annotations"]] == [f"{s}.png" for s in stems]
    pair_to_id: dict[tuple[int, int], int] = {}
    for ann in doc["annotations"]:
        stem = Path(ann["file_name"]).stem
        ids = read_panoptic_png(rendered["dir"] / "panoptic" / ann["file_name"])
        sem = _read(rendered["dir"] / "semantic" / f"{stem}.png").astype(np.int64)
        inst = _read(rendered["dir"] / "instance" / f"{stem}.png").astype(np.int64)
        conf = _read(rendered["dir"] / "confidence" / f"{stem}.png").astype(np.float64) / 65535
        info = {s["id"]: s for s in ann["segments_info"]}
        assert set(np.unique(ids[ids > 0]).tolist()) == set(info)
        assert sum(s["area"] for s in info.values()) == int((ids > 0).sum())
        for sid, s in info.items():
            m = ids == sid
            assert s["area"] == int(m.sum())
            assert set(np.unique(sem[m]).tolist()) == {s["category_id"]}
            assert len(np.unique(inst[m])) == 1
            assert s["score"] == pytest.approx(conf[m].mean(), abs=1e-4)  # PNG confidence is 16-bit
            ys, xs = np.nonzero(m)
            x0, y0 = int(xs.min()), int(ys.min())
            assert s["bbox"] == [x0, y0, int(xs.max()) - x0 + 1, int(ys.max()) - y0 + 1]
        # Scene-consistent: every (class, instance) pair has one id in every frame.
        for c, k, sid in zip(sem.ravel().tolist(), inst.ravel().tolist(), ids.ravel().tolist()):
            assert pair_to_id.setdefault((c, k), sid) == sid
            assert sid == c * div + k
    assert len(set(pair_to_id.values())) == len(pair_to_id)


def test_writer_panoptic_ids_consistent_for_the_same_instance_in_two_frames(tmp_path):
    """Two frames that show the same things at different places and sizes get the same segment ids."""
    cats = [Category(1, "wall", False, (10, 20, 30)), Category(5, "chair", True, (200, 0, 0))]
    w = RenderedOutputWriter(tmp_path, resolve_outputs(["panoptic", "semantic", "instance"]), cats,
                             num_instance_channels=40)
    frames = []
    for shift in (0, 3):
        sem = np.ones((8, 10), np.int64)
        inst = np.zeros((8, 10), np.int64)
        sem[1 + shift:4 + shift, 2:5] = 5
        inst[1 + shift:4 + shift, 2:5] = 7
        sem[0, 6 + shift:] = 5
        inst[0, 6 + shift:] = 33
        conf = np.full((8, 10), 0.5, np.float32)
        conf[sem == 5] = 0.9
        frames.append((sem, inst))
        w.write(f"f{shift}", FrameRender(np.zeros((8, 10, 3), np.float32), np.ones((8, 10), np.float32),
                                         np.ones((8, 10), np.float32), sem, inst, conf))
    w.finish()
    doc = _strict_json(tmp_path / "panoptic.json")
    segs = [{s["id"]: s for s in a["segments_info"]} for a in doc["annotations"]]
    assert set(segs[0]) == set(segs[1]) == {1000, 5007, 5033}
    assert segs[0][5007]["area"] == 9 and segs[1][5033]["area"] == 1
    assert segs[0][5007]["score"] == pytest.approx(0.9) and segs[0][1000]["score"] == pytest.approx(0.5)
    for (sem, inst), stem in zip(frames, ("f0", "f3")):
        ids = read_panoptic_png(tmp_path / "panoptic" / f"{stem}.png")
        np.testing.assert_array_equal(ids, panoptic_segment_ids(sem, inst, 1000))
    # Instance ids ≥ 1000 need a larger divisor rather than colliding with the next class.
    assert RenderedOutputWriter(tmp_path, ["panoptic"], cats, num_instance_channels=1000).label_divisor == 10000
    with pytest.raises(ValueError):
        panoptic_segment_ids(np.array([[1]]), np.array([[1000]]), 1000)


def test_render_downscale_and_camera_path_match_split_render(trained, tmp_path):
    scene = load_scene(trained["scene"])
    test = [int(i) for i in scene.split("test")]
    cams = scene.cameras
    path = {"camera_path": [{"camera_to_world": cams.c2w[i].tolist(), "fl_x": float(cams.fx[i]),
                             "fl_y": float(cams.fy[i]), "cx": float(cams.cx[i]), "cy": float(cams.cy[i]),
                             "w": int(cams.width[i]), "h": int(cams.height[i]), "name": f"cam{k}"}
                            for k, i in enumerate(test)]}
    (tmp_path / "path.json").write_text(json.dumps(path))
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["render", "--run", str(trained["run"]), "--output-dir", str(tmp_path / "split"), "--outputs",
                     "rgb", "semantic", "--no-previews", "--downscale", "2", "--quiet"]) == 0
        assert main(["render", "--run", str(trained["run"]), "--output-dir", str(tmp_path / "path"), "--outputs",
                     "rgb", "semantic", "--no-previews", "--downscale", "2", "--quiet",
                     "--camera-path", str(tmp_path / "path.json")]) == 0
    assert sorted(p.name for p in (tmp_path / "split").iterdir()) == ["rgb", "semantic"]
    for k, i in enumerate(test):
        a = _read(tmp_path / "split" / "rgb" / f"{scene.frames[i].name}.png")
        b = _read(tmp_path / "path" / "rgb" / f"cam{k}.png")
        assert a.shape == (int(cams.height[i]) // 2, int(cams.width[i]) // 2, 3)
        np.testing.assert_array_equal(a, b)


def test_camera_path_formats_and_errors(tmp_path, trained):
    scene = load_scene(trained["scene"])
    c2w = scene.cameras.c2w[0]
    p = tmp_path / "ns.json"
    # nerfstudio viewer style: flat row-major matrix, render size and vertical fov in degrees.
    p.write_text(json.dumps({"render_width": 40, "render_height": 30,
                             "camera_path": [{"camera_to_world": c2w.ravel().tolist(), "fov": 90.0}]}))
    cp = load_camera_path(p)
    assert cp.stems == ["frame_00000"] and cp.cameras.width[0] == 40 and cp.cameras.height[0] == 30
    assert cp.cameras.fy[0] == pytest.approx(15.0) and cp.cameras.cx[0] == 20.0
    np.testing.assert_allclose(cp.cameras.c2w[0], c2w)
    # Missing intrinsics come from the scene's camera (a bare list of cameras is accepted).
    p.write_text(json.dumps([{"transform_matrix": c2w.tolist()}]))
    cp = load_camera_path(p, defaults=scene.cameras)
    assert cp.cameras.fx[0] == scene.cameras.fx[0] and cp.cameras.width[0] == scene.cameras.width[0]
    with pytest.raises(InputError, match="fl_x|size"):
        load_camera_path(p)
    bad = c2w.copy()
    bad[:3, :3] *= 2
    for doc, msg in (({"camera_path": []}, "camera_path"), ({"camera_path": [{"fov": 50}]}, "camera_to_world"),
                     ({"camera_path": [{"camera_to_world": bad.tolist(), "w": 4, "h": 4, "fov": 50}]}, "rigid")):
        p.write_text(json.dumps(doc))
        with pytest.raises(InputError, match=msg) as e:
            load_camera_path(p)
        assert str(p) in str(e.value)
    p.write_text("{not json")
    with pytest.raises(InputError, match="JSON"):
        load_camera_path(p)


# --------------------------------------------------------------------------------------- 2D metrics
def test_compute_2d_metrics_of_gt_as_prediction_is_perfect(trained):
    scene = load_scene(trained["scene"])
    frames = list(range(len(scene)))
    gt = gt_labels(scene, frames)
    r = compute_2d_metrics(gt, gt, scene.thing_ids, scene.stuff_ids)
    for k in ("miou", "pq_scene", "sq_scene", "rq_scene", "miou_strict", "pq_scene_strict", "sq_scene_strict",
              "rq_scene_strict"):
        assert r[k] == 1.0, k
    for part in ("things", "stuff"):
        assert r[part]["pq"] == r[part]["pq_strict"] == 1.0 and r[part]["n"] > 0
    assert r["n_classes_strict"] >= r["n_classes"] > 0

    # Renumbering GT instances consistently keeps PQ at 1; per-frame ids (what a 2D segmenter gives) do not,
    # and so does the metric code notice a wrong class.
    frame_of_pixel = np.repeat(np.arange(len(frames)), gt.semantic.size // len(frames))
    renumbered = LabelStack(gt.semantic, np.where(gt.instance > 0, gt.instance + 17, 0))
    assert compute_2d_metrics(renumbered, gt, scene.thing_ids, scene.stuff_ids)["pq_scene_strict"] == 1.0
    per_frame = LabelStack(gt.semantic, np.where(gt.instance > 0, gt.instance + 1000 * frame_of_pixel, 0))
    assert compute_2d_metrics(per_frame, gt, scene.thing_ids, scene.stuff_ids)["things"]["pq_strict"] < 0.5
    wrong = LabelStack(np.where(gt.semantic == scene.stuff_ids[0], scene.stuff_ids[1], gt.semantic), gt.instance)
    w = compute_2d_metrics(wrong, gt, scene.thing_ids, scene.stuff_ids)
    assert w["miou_strict"] < 1.0
    # the strict per-class table: every class the GT shows, with its GT pixels; the relabelled class scores 0
    counts = np.bincount(gt.semantic.ravel())
    assert {int(c): v["gt_pixels"] for c, v in w["per_class_iou_strict"].items()} == {
        c: int(counts[c]) for c in scene.thing_ids + scene.stuff_ids if c < len(counts) and counts[c] > 0}
    assert w["per_class_iou_strict"][str(scene.stuff_ids[0])]["iou"] == 0.0
    assert all(v["iou"] == 1.0 for v in r["per_class_iou_strict"].values())


def test_metrics_from_arrays_with_a_perfect_prediction(trained):
    """The whole 2D assembly on a prediction built from GT: PQ / mIoU 1, depth error 0, PSNR inf → null."""
    scene = load_scene(trained["scene"])
    frames = [int(i) for i in scene.split("test")]
    labs = [scene.gt_labels(i) for i in frames]
    pred = RenderedSplit(frames, [scene.image(i).astype(np.float32) / 255 for i in frames],
                         [scene.gt_depth(i) for i in frames], [x.semantic for x in labs], [x.instance for x in labs],
                         [np.ones(x.semantic.shape, np.float32) for x in labs])
    m = metrics_from_arrays(scene, frames, pred)
    assert m["pq_scene"] == m["pq_scene_strict"] == m["miou"] == 1.0
    assert m["psnr"] == math.inf and json_safe(m)["psnr"] is None
    assert m["depth"]["rmse"] == 0.0 and m["depth"]["n_valid"] > 0
    assert m["gt"] == {"panoptic": True, "depth": True, "points": True}
    assert m["pseudo_labels"]["pq_scene"] < 1.0  # the simulated segmenter is noisy


def test_pseudo_label_baseline_block_matches_independent_computation(trained, evaluated):
    scene = load_scene(trained["scene"])
    frames = [int(i) for i in scene.split("test")]
    ps = np.stack([scene.pseudo_labels(i).semantic for i in frames])
    pi = np.stack([scene.pseudo_labels(i).instance for i in frames])
    gs = np.stack([scene.gt_labels(i).semantic for i in frames])
    gi = np.stack([scene.gt_labels(i).instance for i in frames])
    base = evaluated["metrics"]["pseudo_labels"]
    for min_area, suffix in ((0.005, ""), (0.0, "_strict")):
        pq = pq_scene(ps, pi, gs, gi, scene.thing_ids, scene.stuff_ids, min_area=min_area)
        assert base["pq_scene" + suffix] == pytest.approx(pq["pq"], abs=1e-12)
        assert base["sq_scene" + suffix] == pytest.approx(pq["sq"], abs=1e-12)
        assert base["rq_scene" + suffix] == pytest.approx(pq["rq"], abs=1e-12)
        assert base["things"]["pq" + suffix] == pytest.approx(pq["things"]["pq"], abs=1e-12)
        assert base["stuff"]["pq" + suffix] == pytest.approx(pq["stuff"]["pq"], abs=1e-12)
        assert base["miou" + suffix] == pytest.approx(miou(ps, gs, min_area=min_area)["miou"], abs=1e-12)
    assert 0 < base["pq_scene"] < 1
    # And the API helper reads the same labels.
    np.testing.assert_array_equal(pseudo_labels(scene, frames).semantic, ps.ravel())


# --------------------------------------------------------------------------------------- eval end to end
def test_eval_writes_metrics_json_with_every_key(trained, evaluated):
    m = _strict_json(trained["run"] / "metrics.json")
    assert m == _strict_json(evaluated["json"])
    for key in TOP_KEYS:
        assert key in m, key
    for key in KEYS_2D:
        assert key in m["pseudo_labels"], key
    for part in ("things", "stuff"):
        assert set(m[part]) >= {"pq", "sq", "rq", "pq_strict", "sq_strict", "rq_strict"}
    scene = load_scene(trained["scene"])
    assert m["split"] == "test" and m["frames"] == len(scene.split("test"))
    assert m["min_segment_fraction"] == MIN_SEGMENT_FRACTION
    assert m["step"] == 30 and m["run"] == str(trained["run"].resolve())
    assert isinstance(m["psnr"], float) and 5 < m["psnr"] < 60
    assert set(m["depth"]) >= {"abs_rel", "rmse", "mae", "n_valid"} and m["depth"]["n_valid"] > 0
    p3 = m["points3d"]
    assert set(p3) >= {"miou", "pq", "chamfer", "fscore", "accuracy", "completeness", "tau", "source"}
    # 20 000 points are drawn; the filters only remove points, but the corner step (docs/export.md, step 8) adds
    # one point per extra plane for each point at a room's edges, about a fifth more in a room
    assert p3["n_gt"] == len(scene.gt_points()["xyz"]) and 0 < p3["n_pred"] <= 1.25 * 20000
    gt = scene.gt_points()
    objects = {(int(c), int(i)) for c, i in zip(gt["semantic"], gt["instance"]) if i and c in scene.thing_ids}
    assert p3["n_gt_objects"] == len(objects) and p3["n_gt_objects"] >= p3["n_instances"]
    assert m["render_ms_per_2048_rays"] > 0
    t = m["render_timing"]
    assert len(t["all_ms"]) == 10 and t["warmup"] == 2 and t["n_rays"] == 2048
    assert m["render_ms_per_2048_rays"] == pytest.approx(statistics.median(t["all_ms"]))
    # The printed table shows both columns, the things/stuff split and the 3D line.
    out = evaluated["stdout"]
    for text in ("lifted", "pseudo-labels", "PQ^scene", "things", "stuff", "mIoU", "PSNR", "3D (", "2048 rays",
                 "metrics.json"):
        assert text in out, text


def test_time_render_reports_median_and_threads(trained):
    loaded = load_run(trained["run"], "cpu")
    r = time_render(loaded, n_rays=300, repeats=3, warmup=1)
    assert len(r["all_ms"]) == 3 and all(x > 0 for x in r["all_ms"])
    assert r["median_ms"] == statistics.median(r["all_ms"])
    assert r["threads"] == torch.get_num_threads() and r["n_rays"] == 300
    with pytest.raises(ValueError):
        time_render(loaded, repeats=0)


def test_eval_without_gt_panoptic_computes_psnr_only(trained, tmp_path):
    scene_copy = tmp_path / "nogt"
    shutil.copytree(trained["scene"], scene_copy)
    shutil.rmtree(scene_copy / "gt" / "panoptic")
    (scene_copy / "gt" / "panoptic.json").unlink()
    meta = json.loads((scene_copy / "transforms.json").read_text())
    for f in meta["frames"]:
        f.pop("gt_panoptic_file_path", None)
    (scene_copy / "transforms.json").write_text(json.dumps(meta))
    m = evaluate_run(trained["run"], EvalOptions(with_points3d=False, timing_repeats=0), data=scene_copy,
                     progress=False, write=False)
    assert isinstance(m["psnr"], float) and m["miou"] is None and m["pq_scene"] is None
    assert m["pseudo_labels"] is None and m["depth"] is not None
    assert any("no GT panoptic" in n for n in m["notes"])
    table = format_eval_table(json_safe(m))
    assert "no GT panoptic" in table and "PQ^scene" not in table and "PSNR" in table


@pytest.mark.parametrize("damage", ["corrupt", "missing"])
def test_missing_or_corrupt_checkpoint_is_an_input_error_naming_the_path(trained, tmp_path, damage, capsys):
    run = tmp_path / "run"
    shutil.copytree(trained["run"], run)
    ckpts = sorted((run / "checkpoints").glob("*.pt"))
    for c in ckpts:
        if damage == "corrupt":
            c.write_bytes(b"not a checkpoint" * 10)
        else:
            c.unlink()
    with pytest.raises(InputError) as e:
        evaluate_run(run, progress=False)
    assert str(run / "checkpoints") in str(e.value)
    if damage == "corrupt":
        assert ckpts[-1].name in str(e.value)
    assert main(["render", "--run", str(run), "--output-dir", str(tmp_path / "r"), "--quiet"]) == 2
    assert main(["eval", "--run", str(run), "--quiet"]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 2 and all(str(run / "checkpoints") in line for line in lines), err
    assert "Traceback" not in err


def _read_only_dir(tmp_path: Path) -> Path:
    """A folder this process cannot create files in (root ignores permission bits: use /proc then)."""
    if os.geteuid() != 0:
        d = tmp_path / "ro"
        d.mkdir()
        d.chmod(0o555)
        return d
    return Path("/proc")


@pytest.mark.parametrize("where", ["read-only dir", "below a file"])
def test_json_to_unwritable_place_is_an_input_error(trained, tmp_path, where, capsys):
    if where == "read-only dir":
        target = _read_only_dir(tmp_path) / "metrics.json"
    else:
        (tmp_path / "file").write_text("x")
        target = tmp_path / "file" / "metrics.json"
    before = (trained["run"] / "metrics.json").read_bytes() if (trained["run"] / "metrics.json").exists() else None
    with pytest.raises(InputError) as e:
        evaluate_run(trained["run"], json_path=target, progress=False)
    assert str(target) in str(e.value)
    assert main(["eval", "--run", str(trained["run"]), "--json", str(target), "--quiet"]) == 2
    assert str(target) in capsys.readouterr().err
    # Checked before any work: the run's metrics.json is untouched.
    after = (trained["run"] / "metrics.json").read_bytes() if (trained["run"] / "metrics.json").exists() else None
    assert before == after


def test_write_metrics_is_strict_json(tmp_path):
    path = write_metrics({"a": float("nan"), "b": {"c": np.float32(2.5), "d": [np.inf, -np.inf, 1]},
                          "e": np.arange(3)}, tmp_path / "m.json")
    assert _strict_json(path) == {"a": None, "b": {"c": 2.5, "d": [None, None, 1]}, "e": [0, 1, 2]}


def test_render_rejects_bad_options(trained, tmp_path, capsys):
    assert main(["render", "--run", str(tmp_path / "nope"), "--output-dir", str(tmp_path / "o"), "--quiet"]) == 2
    assert "run folder not found" in capsys.readouterr().err
    assert main(["render", "--run", str(trained["run"]), "--output-dir", str(tmp_path / "o"), "--downscale", "0",
                 "--quiet"]) == 2
    assert "--downscale" in capsys.readouterr().err
    assert main(["render", "--run", str(trained["run"]), "--output-dir", str(tmp_path / "o"),
                 "--min-segment-fraction", "1.5", "--quiet"]) == 2
    assert "--min-segment-fraction: must be in [0, 1), got 1.5" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["render", "--run", str(trained["run"]), "--output-dir", str(tmp_path / "o"), "--outputs", "normals"])


def test_points_from_rendered_depth_lie_on_the_rendered_surface(trained):
    """The fallback 3D points project back onto their pixel centres at the rendered z-depth."""
    from lift3d.eval.evaluate import points_from_rendered_depth

    loaded = load_run(trained["run"], "cpu")
    scene = loaded.scene()
    i = int(scene.split("test")[0])
    ref = render_frame(loaded.model, loaded.rays(scene), i, loaded.norm.scale)
    pts = points_from_rendered_depth(loaded, scene, num_points=10**6, frames=[i], min_opacity=0.0)
    hit = ref.depth > 0
    assert len(pts.xyz) == int(hit.sum()) > 0
    uv, z = scene.cameras.project(i, pts.xyz)
    vv, uu = np.nonzero(hit)
    np.testing.assert_allclose(uv, np.stack([uu + 0.5, vv + 0.5], -1), atol=1e-3)
    np.testing.assert_allclose(z, ref.depth[hit], rtol=1e-5)
    np.testing.assert_array_equal(pts.semantic, ref.semantic[hit])
    np.testing.assert_array_equal(pts.instance, ref.instance[hit])
    sub = points_from_rendered_depth(loaded, scene, num_points=50, frames=[i], min_opacity=0.0)
    assert len(sub.xyz) == 50


def test_eval_scores_frames_at_their_true_poses(trained, evaluated, tmp_path, capsys):
    """Test views whose written pose is off but whose true pose is given score as if the written pose were
    right; with --no-true-poses they are rendered where the written pose says."""
    from scipy.spatial.transform import Rotation

    scene_copy = tmp_path / "scene"
    shutil.copytree(trained["scene"], scene_copy)
    path = scene_copy / "transforms.json"
    meta = json.loads(path.read_text())
    test = set(meta["test_filenames"])
    for fr in meta["frames"]:
        if fr["file_path"] in test:
            true = np.asarray(fr["gt_transform_matrix"], float)
            noisy = true.copy()
            noisy[:3, :3] = true[:3, :3] @ Rotation.from_rotvec(np.radians([3.0, -2.0, 1.0])).as_matrix()
            noisy[:3, 3] += [0.05, -0.04, 0.03]
            fr["transform_matrix"] = noisy.tolist()
    path.write_text(json.dumps(meta))
    common = ["eval", "--run", str(trained["run"]), "--data", str(scene_copy), "--no-points3d", "--timing-repeats",
              "0", "--quiet"]
    out = tmp_path / "true.json"
    assert main(common + ["--json", str(out)]) == 0
    at_true = json.loads(out.read_text())
    assert "scored frames rendered from their true poses" in capsys.readouterr().out
    reference = evaluated["metrics"]  # the same run on the scene with exact poses
    assert at_true["poses"]["scored_at"] == "gt_transform_matrix"
    assert at_true["poses"]["written_vs_true"]["rms_deg"] > 3.0
    assert at_true["psnr_per_frame"] == pytest.approx(reference["psnr_per_frame"], abs=1e-4)
    assert at_true["miou"] == pytest.approx(reference["miou"], abs=1e-6)
    out = tmp_path / "written.json"
    assert main(common + ["--json", str(out), "--no-true-poses"]) == 0
    at_written = json.loads(out.read_text())
    assert at_written["poses"]["scored_at"] == "transform_matrix"
    # (The 30-step field is too blurry for a reliable sign; the views must differ.)
    assert max(abs(a - b) for a, b in zip(at_written["psnr_per_frame"], at_true["psnr_per_frame"])) > 0.02


def test_small_thing_segments_take_their_surroundings_labels():
    """A few-pixel (category, instance) pair takes the labels around it; stuff, larger segments and a segment
    of one object split over the frame (large in total) stay; 0 keeps everything."""
    sem = np.full((20, 20), 1)
    inst = np.zeros((20, 20), int)
    sem[2:12, 2:12], inst[2:12, 2:12] = 5, 3  # an object: 100 pixels
    sem[5, 5], inst[5, 5] = 5, 7  # a one-pixel fragment of another instance inside it
    sem[15, 15], inst[15, 15] = 6, 1  # a one-pixel thing of another class on stuff
    sem[15:17, 2:4], inst[15:17, 2:4] = 5, 3  # a 4-pixel piece of the 100-pixel object elsewhere: kept
    s, i = merge_small_segments(sem, inst, min_pixels=3)
    assert (s[5, 5], i[5, 5]) == (5, 3)
    assert (s[15, 15], i[15, 15]) == (1, 0)
    assert (s[15:17, 2:4] == 5).all() and (i[15:17, 2:4] == 3).all()
    changed = (s != sem) | (i != inst)
    assert changed.sum() == 2 and sem[5, 5] == 5 and inst[5, 5] == 7  # the inputs are not modified
    s0, i0 = merge_small_segments(sem, inst, 0)
    assert np.array_equal(s0, sem) and np.array_equal(i0, inst)
    only_small = merge_small_segments(np.full((2, 2), 5), np.ones((2, 2), int), 10)  # nothing to take labels from
    assert (only_small[0] == 5).all() and (only_small[1] == 1).all()


def test_render_frame_merges_small_segments_unless_told_not_to(trained):
    loaded = load_run(trained["run"], "cpu")
    scene = loaded.scene()
    rays = loaded.rays(scene)
    i = int(scene.split("test")[0])
    raw = render_frame(loaded.model, rays, i, loaded.norm.scale, min_segment_fraction=0.0)
    h, w = raw.semantic.shape
    expect = merge_small_segments(raw.semantic, raw.instance, MIN_SEGMENT_FRACTION * h * w)
    ref = render_frame(loaded.model, rays, i, loaded.norm.scale)
    assert np.array_equal(ref.semantic, expect[0]) and np.array_equal(ref.instance, expect[1])
    big = render_frame(loaded.model, rays, i, loaded.norm.scale, min_segment_fraction=0.5)
    pairs = {(int(a), int(b)) for a, b in zip(big.semantic.ravel(), big.instance.ravel()) if b > 0}
    assert all(((big.semantic == a) & (big.instance == b)).sum() >= 0.5 * h * w for a, b in pairs)


def test_eval_rejects_a_bad_segment_fraction(trained, capsys):
    assert main(["eval", "--run", str(trained["run"]), "--min-segment-fraction", "-0.1", "--no-points3d",
                 "--timing-repeats", "0", "--quiet"]) == 2
    assert "--min-segment-fraction: must be in [0, 1), got -0.1" in capsys.readouterr().err


# --------------------------------------------------------------------------------------- instance ids from the export
def test_rendered_instance_ids_come_from_the_exported_objects():
    from types import SimpleNamespace

    from lift3d.data.cameras import Cameras, look_at
    from lift3d.eval.evaluate import FIELD_CHANNEL_OFFSET, RenderedSplit, with_export_instances

    # One camera at the origin looking along +y at a wall 2 m away; image 4 x 4. The field gave the two
    # chairs (class 7) of the left and right halves the same channel 3; the export holds them as objects 1
    # and 2 at x = -1 and x = +1. Class 8 has channel 5 but no exported object; class 1 is stuff.
    cams = Cameras(c2w=look_at(np.zeros(3), np.array([0.0, 2.0, 0.0]))[None], fx=np.array([2.0]),
                   fy=np.array([2.0]), cx=np.array([2.0]), cy=np.array([2.0]), width=np.array([4]),
                   height=np.array([4]))
    sem = np.array([[7, 7, 7, 7], [7, 7, 7, 7], [8, 8, 1, 1], [1, 1, 1, 1]])
    inst = np.where(sem == 7, 3, np.where(sem == 8, 5, 0))
    depth = np.full((4, 4), 2.0, np.float32)
    depth[1, 0] = 0.0  # nothing hit: keeps its channel
    rendered = RenderedSplit([0], [np.zeros((4, 4, 3), np.float32)], [depth], [sem], [inst], [np.ones((4, 4))])
    cloud = SimpleNamespace(xyz=np.array([[-1.0, 2.0, 0.0], [1.0, 2.0, 0.0], [0.0, 2.0, -1.0]]),
                            semantic=np.array([7, 7, 1]), instance=np.array([1, 2, 0]))
    out = with_export_instances(rendered, SimpleNamespace(cameras=cams), cloud, things=[7, 8])
    ids = out.instance[0]
    assert ids[0].tolist() == [1, 1, 2, 2]  # the left half is object 1, the right half object 2
    assert ids[1, 0] == 3 + FIELD_CHANNEL_OFFSET and ids[1, 1:].tolist() == [1, 2, 2]
    assert ids[2].tolist() == [5 + FIELD_CHANNEL_OFFSET] * 2 + [0, 0]  # no exported class-8 object; stuff
    assert ids[3].tolist() == [0, 0, 0, 0]
    assert out.semantic[0] is sem and rendered.instance[0] is inst  # labels unchanged, the input untouched


def test_export_instances_lift_pixels_by_the_median_depth():
    from types import SimpleNamespace

    from lift3d.data.cameras import Cameras, look_at
    from lift3d.eval.evaluate import RenderedSplit, with_export_instances

    # Two chairs at 2 m, left and right; a car-sized object of the same class 6 m behind the right one. Fog
    # behind the chairs drags the expected depth to 6 m: lifted by it, the right half would take the far
    # object's id. The median depth (2 m; 0 = never reached, then the expected depth counts) lands on the chairs.
    cams = Cameras(c2w=look_at(np.zeros(3), np.array([0.0, 2.0, 0.0]))[None], fx=np.array([2.0]),
                   fy=np.array([2.0]), cx=np.array([2.0]), cy=np.array([2.0]), width=np.array([4]),
                   height=np.array([4]))
    sem = np.full((4, 4), 7)
    expected = np.full((4, 4), 6.0, np.float32)
    median = np.full((4, 4), 2.0, np.float32)
    median[3] = 0.0
    cloud = SimpleNamespace(xyz=np.array([[-1.0, 2.0, 0.0], [1.0, 2.0, 0.0], [3.0, 6.0, 0.0]]),
                            semantic=np.array([7, 7, 7]), instance=np.array([1, 2, 3]))
    rendered = RenderedSplit([0], [np.zeros((4, 4, 3), np.float32)], [expected], [sem], [np.ones((4, 4), int)],
                             [np.ones((4, 4))], median_depth=[median])
    ids = with_export_instances(rendered, SimpleNamespace(cameras=cams), cloud, things=[7]).instance[0]
    assert ids[0].tolist() == [1, 1, 2, 2] and ids[2].tolist() == [1, 1, 2, 2]
    assert ids[3, 2:].tolist() == [3, 3]  # no median depth: the expected depth (6 m) reaches the far object
    no_median = RenderedSplit([0], rendered.rgb, [expected], [sem], rendered.instance, rendered.confidence)
    without = with_export_instances(no_median, SimpleNamespace(cameras=cams), cloud, things=[7]).instance[0]
    assert (without[:, 2:] == 3).all()  # frames rendered without a median depth: the expected depth


def test_eval_scores_both_instance_sources(trained, evaluated):
    m = evaluated["metrics"]
    assert m["instances_from"] == "export"
    other = m["other_instances"]
    assert other["instances_from"] == "field" and set(other) >= {"pq_scene", "pq_scene_strict", "things", "stuff"}
    assert "instance ids from export; from field" in evaluated["stdout"]
    field = evaluate_run(trained["run"], EvalOptions(timing_repeats=0, num_points=20000, instances="field"),
                         progress=False, write=False)
    assert field["instances_from"] == "field" and field["other_instances"]["instances_from"] == "export"
    # The same renders and the same export, scored the other way round.
    assert field["pq_scene"] == pytest.approx(other["pq_scene"], abs=1e-12)
    assert field["other_instances"]["pq_scene"] == pytest.approx(m["pq_scene"], abs=1e-12)
    assert field["miou"] == m["miou"]  # semantics do not depend on where instance ids come from


def test_eval_rejects_an_unknown_instance_source(trained, capsys):
    with pytest.raises(InputError, match="--instances"):
        evaluate_run(trained["run"], EvalOptions(instances="labels"), progress=False, write=False)


def test_eval_without_a_usable_export_scores_the_heads_ids(trained, monkeypatch):
    import lift3d.eval.evaluate as ev

    def no_surface(*args, **kwargs):
        raise InputError("run", "the field has no surface at density 1 (train longer)")

    monkeypatch.setattr(ev, "extract_labelled_points", no_surface)
    m = evaluate_run(trained["run"], EvalOptions(with_points3d=False, timing_repeats=0), progress=False, write=False)
    assert m["instances_from"].startswith("field (no export:") and "no surface" in m["instances_from"]
    assert m["other_instances"] is None and m["pq_scene"] is not None
    # With the 3D block asked for, the export's error is the eval's error (as before).
    with pytest.raises(InputError, match="no surface"):
        evaluate_run(trained["run"], EvalOptions(timing_repeats=0), progress=False, write=False)


def test_eval_without_3d_gt_scores_the_export_against_the_depth_maps(trained, tmp_path):
    from lift3d.eval.frame_metrics import depth_gt_points

    scene_copy = tmp_path / "no3d"
    shutil.copytree(trained["scene"], scene_copy)
    (scene_copy / "gt" / "points.ply").unlink()
    m = evaluate_run(trained["run"], EvalOptions(timing_repeats=0, num_points=20000), data=scene_copy, progress=False,
                     write=False)
    assert m["points3d"] is None
    g = m["geometry_from_depth"]
    assert g["reference"] == "gt_depth" and g["frames"] == m["frames"] and 0.0 <= g["fscore"] <= 1.0
    scene = load_scene(scene_copy)
    frames = [int(i) for i in scene.split("test")]
    gt = depth_gt_points(scene, frames)
    assert g["n_gt"] == len(gt) and g["tau"] == pytest.approx(0.01 * np.linalg.norm(np.ptp(gt, axis=0)))
    # the depth maps scored against themselves: every point within tau both ways
    from lift3d.eval.points3d import geometry3d
    assert geometry3d(gt, gt, g["tau"])["fscore"] == 1.0
    d = m["depth"]
    assert 0.0 <= d["share_over_0.1"] <= 1.0 and d["mae_of_diagonal"] == pytest.approx(d["mae"] / d["diagonal"])
    # the points off the surface are placed in front of it, behind it or out of view: 1 - precision in all
    off = g["imprecise"]
    assert sum(off.values()) == pytest.approx(1.0 - g["precision"], abs=1e-3)
    # the points no scored frame sees are left out of the observed precision, so it is never below the precision
    assert g["precision_observed"] == pytest.approx(min(1.0, g["precision"] / (1 - off["unobserved"])), abs=1e-4)
    assert g["precision_observed"] >= g["precision"] - 1e-4 and 0.0 <= g["fscore_observed"] <= 1.0
    table = format_eval_table(json_safe(m))
    assert "3D geometry" in table and "% of the diagonal" in table and "in front of it" in table
    assert "a scored frame can judge" in table


def test_eval_reports_3d_iou_per_class_and_the_smallest_objects(trained, evaluated):
    p = evaluated["metrics"]["points3d"]
    scene = load_scene(trained["scene"])
    names = {c.name for c in scene.categories}
    assert p["per_class"] and set(p["per_class"]) <= names and all(0 <= v <= 1 for v in p["per_class"].values())
    gt = scene.gt_points()
    things = np.isin(gt["semantic"], scene.thing_ids) & (gt["instance"] != 0)
    assert len(p["objects"]) == len(np.unique(np.stack([gt["semantic"][things], gt["instance"][things]], 1), axis=0))
    sizes = [o["size"] for o in p["objects"]]
    assert sizes == sorted(sizes) and all(0 <= o["iou"] <= 1 and o["class"] in names for o in p["objects"])
    assert "3D point IoU per class" in evaluated["stdout"] and "smallest" in evaluated["stdout"]


def test_the_smallest_objects_line_skips_objects_with_too_few_gt_points_to_measure():
    objects = [{"class": "streetlight", "points": 1, "size": 0.0, "iou": 0.0},
               {"class": "cup", "points": 29, "size": 0.11, "iou": 0.2},
               {"class": "car", "points": 900, "size": 4.2, "iou": 0.8}]
    text = format_eval_table({"points3d": {"objects": objects, "per_class": {"car": 0.5}}})
    line = next(x for x in text.splitlines() if x.startswith("smallest"))
    assert "streetlight" not in line and line.index("cup 0.11 m 0.200 (lost)") < line.index("car 4.20 m 0.800")
