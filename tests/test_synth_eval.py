"""``lift3d eval`` on a synthetic scene: a warning when scored frames were trained on, and rendered depth
scored against the exact GT depth (``gt_depth_file_path``) rather than the noisy sensor depth."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lift3d.data.scene import load_scene
from lift3d.eval.evaluate import EvalOptions, RenderedSplit, evaluate_run, metrics_from_arrays, trained_frames_warning
from lift3d.eval.report import format_eval_table


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> dict:
    """A tiny synthetic scene with sensor depth and a 5-step run on it."""
    from lift3d.synth import SynthOptions, make_scene
    from lift3d.train.trainer import train

    root = tmp_path_factory.mktemp("synth_eval")
    make_scene(root / "scene", SynthOptions(kind="indoor", seed=103, n_views=6, width=24, height=24), progress=False)
    overrides = {"optim": {"steps": 5}, "losses": {"feature": 0.0}, "field": {"grid": {"resolution_cap": 16}},
                 "data": {"rays_per_image": 32, "patch_size": 8}, "trainer": {"eval_images": 1}}
    result = train(root / "scene", preset="fast", output_dir=root / "outputs", overrides=overrides, progress=False,
                   print_summary=False)
    return {"scene": root / "scene", "run": Path(result.run.path)}


def test_scoring_training_frames_warns_in_table_and_json(run, tmp_path):
    m = evaluate_run(run["run"], EvalOptions(split="train", with_points3d=False, timing_repeats=0),
                     json_path=tmp_path / "train.json", progress=False)
    scene = load_scene(run["scene"])
    names = [scene.frames[i].name for i in scene.split("train")]
    assert m["frames_also_trained"] == names and len(m["warnings"]) == 1
    assert "also training frames" in m["warnings"][0]
    written = json.loads((tmp_path / "train.json").read_text())
    assert written["warnings"] == m["warnings"] and written["frames_also_trained"] == names
    table = format_eval_table(m)
    assert "WARNING" in table and names[0] in table
    assert m["depth"]["reference"] == "gt_depth"
    clean = {**m, "warnings": [], "frames_also_trained": []}
    assert "WARNING" not in format_eval_table(clean)
    assert trained_frames_warning(scene, scene.split("test")) == ([], [])


def test_partly_trained_frames_are_listed(run):
    scene = load_scene(run["scene"])
    train, test = scene.split("train"), scene.split("test")
    both, warnings = trained_frames_warning(scene, [int(test[0]), int(train[0])])
    assert both == [scene.frames[int(train[0])].name] and "1 of the 2" in warnings[0]


def test_depth_is_scored_against_exact_gt_depth(run):
    scene = load_scene(run["scene"])
    frames = [int(i) for i in scene.split("test")]
    # A "rendering" that reproduces the exact depth scores zero error against the GT depth, not against the
    # noisy sensor depth with holes.
    exact = [scene.gt_depth(i) for i in frames]
    rend = RenderedSplit(frames, [scene.image(i).astype(np.float32) / 255 for i in frames], exact,
                         [scene.gt_labels(i).semantic for i in frames], [scene.gt_labels(i).instance for i in frames],
                         [np.ones(e.shape, np.float32) for e in exact])
    m = metrics_from_arrays(scene, frames, rend, with_baseline=False)
    assert m["depth"]["reference"] == "gt_depth" and m["depth"]["mae"] == pytest.approx(0.0, abs=1e-6)
    assert m["depth"]["n_valid"] == sum(int((e > 0).sum()) for e in exact)
