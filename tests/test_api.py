"""The public API of a trained run (docs/api.md): lift3d.load_run, classes, query_points, render, render_rays.

Runs on the session's tiny trained run (``tiny_run`` in conftest.py). docs/api.md's examples are doctests
run here too.
"""

from __future__ import annotations

import doctest
from pathlib import Path

import numpy as np
import pytest

import lift3d
from lift3d.data.images import read_label_map, read_rgb
from lift3d.errors import InputError
from lift3d.export import export_run
from lift3d.model import run as run_module
from lift3d.export.renders import render_to_folder
from lift3d.render.output import DEPTH_PNG_UNIT

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def run(tiny_run):
    return lift3d.load_run(tiny_run, device="cpu")


def test_the_docs_examples_run(tiny_run):
    result = doctest.testfile(str(ROOT / "docs" / "api.md"), module_relative=False, globs={"run_dir": str(tiny_run)},
                              optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False)
    assert result.attempted > 10 and result.failed == 0


def test_one_loader(run, tiny_run):
    assert lift3d.load_run is run_module.load_run
    assert run.step == 15 and str(run.run.path) == str(tiny_run)
    assert set(run.classes) == set(run.labels.semantic_ids)
    scene_names = {c.id: c.name for c in run.scene().categories}
    assert all(c.name == scene_names[c.id] for c in run.classes.values())


def test_classes_without_the_scene_folder(run, monkeypatch):
    """Names come from the categories recorded at training; older runs without them fall back to the scene
    folder and, when that is gone too, to class_<id>."""
    monkeypatch.setitem(run.cfg.scene, "data", "/nonexistent/scene")
    assert run.classes[1].name == "wall"
    monkeypatch.delitem(run.cfg.scene, "categories")
    assert run.classes[1].name == "class_1" and len(run.classes[1].color) == 3


def test_render_equals_lift3d_render(run, tiny_run, tmp_path):
    res = render_to_folder(tiny_run, tmp_path, ["rgb", "depth", "semantic", "instance"], split="test",
                           previews=False, progress=False, device="cpu", instances="field")
    scene = run.scene()
    cams = scene.cameras
    i = int(scene.split("test")[0])
    stem = res.stems[0]
    assert stem == scene.frames[i].name
    out = run.render(cams.c2w[i], cams.K(i), int(cams.width[i]), int(cams.height[i]))
    assert np.array_equal(read_rgb(tmp_path / "rgb" / f"{stem}.png"),
                          np.round(np.clip(out["rgb"], 0, 1) * 255).astype(np.uint8))
    depth_mm = np.where(out["depth"] > 0, np.round(out["depth"] / DEPTH_PNG_UNIT), 0)
    assert np.array_equal(read_label_map(tmp_path / "depth" / f"{stem}.png"), depth_mm)
    assert np.array_equal(read_label_map(tmp_path / "semantic" / f"{stem}.png"), out["semantic"])
    instance = np.where(out["semantic"] > 0, out["instance"], 0)
    assert np.array_equal(read_label_map(tmp_path / "instance" / f"{stem}.png"), instance)


def test_render_rays_agree_with_render_and_chunks_change_nothing(run):
    scene = run.scene()
    cams = scene.cameras
    i = int(scene.split("test")[0])
    out = run.render(cams.c2w[i], cams.K(i), int(cams.width[i]), int(cams.height[i]))
    vv, uu = np.mgrid[0:out["depth"].shape[0], 0:out["depth"].shape[1]]
    u, v = uu.ravel(), vv.ravel()
    o, d = cams.rays(i, u, v)
    r = run.render_rays(o, d * 3.0)  # directions need not be unit length
    assert np.array_equal(r["semantic"], out["semantic"][v, u]) and np.array_equal(r["instance"], out["instance"][v, u])
    # The two build their rays apart (float rounding of origin/direction); the proposal resampling is only
    # piecewise continuous in the ray, so a rare ray may place a sample differently: bounded, not exact.
    rgb_diff = np.abs(r["rgb"] - out["rgb"][v, u]).max(1)
    assert (rgb_diff > 1e-5).mean() <= 0.005 and rgb_diff.max() < 1e-2, (np.sort(rgb_diff)[-5:], len(rgb_diff))
    x, y = cams.normalized_coords(i, u.astype(float), v.astype(float))
    cos = 1.0 / np.sqrt(x * x + y * y + 1.0)
    hit = out["depth"][v, u] > 0
    depth_off = ~np.isclose(r["depth"][hit] * cos[hit], out["depth"][v, u][hit], rtol=1e-4)
    assert hit.any() and depth_off.mean() <= 0.005
    small = run.render_rays(o, d, chunk_size=7)
    assert all(np.allclose(small[k], r[k], atol=1e-5) for k in r) and np.array_equal(small["semantic"], r["semantic"])
    pts = o[:50] + d[:50] * 0.5
    a, b = run.query_points(pts), run.query_points(pts, chunk=7)  # (batched matmuls round differently)
    assert np.array_equal(a["semantic"], b["semantic"]) and np.array_equal(a["instance"], b["instance"])
    assert all(np.allclose(a[k], b[k], rtol=1e-4, atol=1e-5) for k in ("density", "confidence", "semantic_probs"))


def test_query_points_at_exported_points_give_the_exported_labels(run, tiny_run, tmp_path):
    # without the instance clean-up, which folds crumbs, unsure and unconfirmed instances into their
    # neighbour's class on purpose (docs/api.md), and without the label steps that take a point's class from
    # the training views' labels or its neighbours' orientation
    export_run(tiny_run, tmp_path, pointcloud=True, num_points=3000, device="cpu", merge_fragments=False,
               crumb_points=0, min_instance_confidence=0.0, min_support_views=0, view_vote=False, orient_stuff=False)
    pts = lift3d.load_labelled_points(tmp_path)
    q = run.query_points(pts.xyz)
    assert np.array_equal(q["semantic"], pts.semantic)
    things = [c.id for c in run.classes.values() if c.isthing]
    assert (q["instance"][~np.isin(q["semantic"], things)] == 0).all()
    # Every exported instance is one (class, channel) of the field; a channel may hold several instances.
    ids = np.unique(pts.instance[pts.instance > 0])
    assert len(ids) > 0
    for k in ids:
        members = pts.instance == k
        assert len(np.unique(q["instance"][members])) == 1 and len(np.unique(q["semantic"][members])) == 1
    assert (q["instance"][pts.instance > 0] > 0).all() and (pts.instance[q["instance"] == 0] == 0).all()


def test_the_export_keeps_the_fields_own_labels_that_query_points_gives(run, tiny_run, tmp_path):
    # with every step on: the export's final labels differ from the field's where its steps relabel, and
    # field_semantic / field_instance say what the field itself says there
    export_run(tiny_run, tmp_path, pointcloud=True, num_points=3000, device="cpu")
    pts = lift3d.load_labelled_points(tmp_path)
    q = run.query_points(pts.xyz)
    assert pts.field_semantic is not None and pts.field_instance is not None
    assert np.mean(q["semantic"] == pts.field_semantic) >= 0.99
    assert np.mean(q["instance"] == pts.field_instance) >= 0.99


def test_bad_input_is_a_value_error_naming_the_argument(run):
    with pytest.raises(InputError, match="xyz: expected an \\(N, 3\\) array"):
        run.query_points(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="directions must be non-zero"):
        run.render_rays(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="c2w must be 4x4"):
        run.render(np.eye(3), np.eye(3), 8, 8)
    with pytest.raises(InputError, match="run folder not found"):
        lift3d.load_run("/nonexistent/run")


def test_the_render_timing_recipe_of_the_benchmarks_runs(tiny_run, capsys):
    """docs/benchmarks.md tells users how to time the render figure through the public API: that code runs."""
    from lift3d.bench.runner import RENDER_THROUGH_THE_API

    code = "\n".join(RENDER_THROUGH_THE_API).split("```python\n")[1].split("```")[0]
    exec(code.replace("outputs/<scene>/fast/<YYYY-MM-DD_HHMMSS>", str(tiny_run)), {})
    assert capsys.readouterr().out.strip().endswith("ms per 2048 rays")
