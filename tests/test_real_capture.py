"""Real imagery end to end: an excerpt of the ICL-NUIM living room (tests/fixtures/icl_livingroom1_excerpt,
27 frames at 160 x 120, Open3D's layout) converted, labelled from its depth, trained on its images alone,
evaluated against its depth and exported, through the command line a user types."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from lift3d.cli.main import main

EXCERPT = Path(__file__).parent / "fixtures" / "icl_livingroom1_excerpt"


def _run(*args: str) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main([*args]) == 0
    return out.getvalue()


@pytest.mark.slow
def test_a_real_capture_from_open3d_layout_to_labelled_points(tmp_path):
    scene = tmp_path / "livingroom"
    _run("convert", "--from", "open3d", str(EXCERPT), "--depth-as-gt", "--test-every", "6", "--out", str(scene),
         "--quiet")
    meta = json.loads((scene / "transforms.json").read_text())
    assert len(meta["frames"]) == 27 and all("gt_depth_file_path" in f and "depth_file_path" not in f
                                             for f in meta["frames"])
    _run("label", "--data", str(scene), "--geometric", "--quiet")
    _run("train", "--data", str(scene), "--preset", "fast", "--output-dir", str(tmp_path / "runs"), "--steps", "80",
         "--quiet", "--field.grid.resolution-cap", "64", "--trainer.eval-every", "0")
    run = next((tmp_path / "runs").glob("*/fast/*"))
    cfg = yaml.safe_load((run / "config.yml").read_text())["scene"]
    # the space from the triangulated points, not the cameras; poses fit as written; a room with its floor
    assert cfg["bounded"] and cfg["why_bounded"].startswith("points triangulated")
    assert cfg["pose_check"]["likely_fix"] is None and cfg["pose_check"]["method"] == "epipolar"
    assert cfg["profile"]["name"] in ("room", "manhattan-room"), cfg["profile"]
    assert cfg["inputs"] == "RGB + SfM points" and not cfg["depth_supervision"]
    _run("eval", "--run", str(run), "--quiet", "--num-points", "50000")
    m = json.loads((run / "metrics.json").read_text())
    assert m["depth"]["reference"] == "gt_depth" and m["psnr"] > 14  # 80 steps: ~17 dB; an untrained field ~8
    g = m["geometry_from_depth"]
    assert g["n_pred"] > 1000 and 0.0 < g["fscore"] <= 1.0 and g["tau"] == pytest.approx(0.047, abs=0.01)
    _run("export", "--run", str(run), "--pointcloud", "--output-dir", str(tmp_path / "export"), "--num-points",
         "50000", "--quiet")
    exported = json.loads((tmp_path / "export" / "metadata.json").read_text())
    # the capture's world has y down: the export says so, and plot takes it from there
    assert np.allclose(exported["up"]["axis"], [0, -1, 0])
    assert any(s["name"] == "view-surface" and s["ran"] for s in exported["steps"]["points"])


def test_a_pose_file_in_the_wrong_convention_stops_the_conversion_with_the_fix(tmp_path):
    import shutil

    import open3d as o3d

    from lift3d.convert import WriteOptions
    from lift3d.convert.open3d_rgbd import convert
    from lift3d.errors import InputError

    src = tmp_path / "capture"
    shutil.copytree(EXCERPT, src)
    # the same trajectory written world-to-camera where Open3D's .log holds camera-to-world
    traj = o3d.io.read_pinhole_camera_trajectory(str(EXCERPT / "trajectory.log"))
    for p in traj.parameters:
        p.extrinsic = np.linalg.inv(p.extrinsic)
    o3d.io.write_pinhole_camera_trajectory(str(src / "trajectory.log"), traj)
    quiet = WriteOptions(progress=False)
    with pytest.raises(InputError) as err:
        convert(src, tmp_path / "out", intrinsic=None, options=quiet)
    text = str(err.value)
    assert "trajectory.log" in text and "--fix-poses invert" in text and "\n" not in text
    fixed = convert(src, tmp_path / "out", intrinsic=None,
                    options=WriteOptions(progress=False, overwrite=True, fix_poses="invert"))
    right = convert(EXCERPT, tmp_path / "right", intrinsic=None, options=quiet)
    np.testing.assert_allclose(fixed.cameras.c2w, right.cameras.c2w, atol=1e-6)
