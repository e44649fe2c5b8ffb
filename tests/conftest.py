"""Shared fixtures. Keep this small and generic: every test module may use it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lift3d.data.cameras import look_at
from lift3d.data.scene import Category, FrameGroundTruth, FramePseudoLabels, SceneWriter, Segment

#: Categories of :func:`tiny_scene`: two stuff classes and two thing classes.
TINY_CATEGORIES = [
    Category(1, "wall", False, (120, 120, 120)),
    Category(2, "floor", False, (80, 60, 40)),
    Category(3, "chair", True, (200, 30, 30)),
    Category(4, "table", True, (30, 30, 200)),
]


@pytest.fixture
def tiny_scene(tmp_path: Path) -> Path:
    """A small valid scene folder (6 frames of 16×12 px) written with :class:`SceneWriter`.

    Upper rows are wall, lower rows floor, with one chair (GT instance 1) and one table (GT instance 2).
    Pseudo-labels are COCO panoptic PNGs with per-frame segment ids and scores; GT panoptic, uint16 depth,
    ``gt/points.ply`` and explicit splits (train 0-3, val 4, test 5) are included. Returns the folder.
    """
    root = tmp_path / "tiny_scene"
    h, w, n_frames = 12, 16, 6
    rng = np.random.default_rng(0)
    with SceneWriter(root, TINY_CATEGORIES) as writer:
        names = []
        for k in range(n_frames):
            angle = 2 * np.pi * k / n_frames
            eye = np.array([2.0 * np.cos(angle), 2.0 * np.sin(angle), 1.0])
            # GT ids are scene-consistent: 1 = wall, 2 = floor, 11 = chair, 12 = table.
            gt = np.full((h, w), 1, np.int64)
            gt[h // 2 :] = 2
            gt[4:9, 2 + k % 3 : 6 + k % 3] = 11
            gt[3:8, 10:14] = 12
            gt[0, 0] = 0  # one void pixel
            # Pseudo-labels: the same layout under per-frame arbitrary ids (offset by 100 k).
            offset = 100 * k + 7
            pan = np.where(gt > 0, gt + offset, 0)
            segments = [Segment(int(g + offset), cat, score=round(0.5 + 0.1 * j, 2))
                        for j, (g, cat) in enumerate([(1, 1), (2, 2), (11, 3), (12, 4)])]
            gt_segments = [Segment(1, 1), Segment(2, 2), Segment(11, 3), Segment(12, 4)]
            depth = 1.5 + rng.random((h, w)).astype(np.float32)
            names.append(writer.add_frame(
                f"frame_{k:03d}", rng.integers(0, 256, (h, w, 3), dtype=np.uint8), look_at(eye, np.zeros(3)),
                (14.0, 14.0, w / 2, h / 2), labels=FramePseudoLabels(pan, segments),
                gt=FrameGroundTruth(gt, gt_segments), depth=depth,
            ))
        writer.set_splits(train=names[:4], val=names[4:5], test=names[5:])
        writer.set_scene_box("bounded", np.array([[-1.0, -1.0, -0.5], [1.0, 1.0, 1.5]]))
        # 3D GT: instance ids match the GT panoptic ids of the things, 0 on stuff.
        semantic = rng.integers(1, 5, 50)
        instance = np.select([semantic == 3, semantic == 4], [11, 12], 0)
        writer.write_gt_points(rng.uniform(-1, 1, (50, 3)), semantic=semantic, instance=instance)
    return root


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory) -> Path:
    """A tiny synthetic scene trained for a few steps (geometry is rough, which is all the CLI needs).

    Shared by the export tests (test_export.py, test_export_formats.py): trained once per session.
    """
    from lift3d.synth import SynthOptions, make_scene
    from lift3d.train.trainer import train

    root = tmp_path_factory.mktemp("tiny_run")
    make_scene(root / "scene", SynthOptions(kind="indoor", seed=0, noise="moderate", n_views=6, width=32, height=32),
               progress=False)
    result = train(root / "scene", preset="fast", output_dir=root / "runs", progress=False, print_summary=False,
                   overrides={"optim": {"steps": 15}, "losses": {"feature": 0.0},
                              "data": {"patch_size": 0, "rays_per_image": 128},
                              "field": {"grid": {"resolution_cap": 48}},
                              "trainer": {"eval_every": 0, "eval_images": 0, "checkpoint_every": 0}})
    return Path(result.run.path)


# tests/helpers holds scripts that tests launch in subprocesses (e.g. with torchrun); they are not test
# modules and must not be imported (or doctest-collected) by pytest itself.
collect_ignore = ["helpers"]
