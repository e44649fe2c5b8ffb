"""Fixtures of the robustness suite: a small synthetic scene and a healthy tiny run, built once per session."""

from __future__ import annotations

from pathlib import Path

import pytest

from robust_helpers import tiny


@pytest.fixture(scope="session")
def synth_scene(tmp_path_factory) -> Path:
    """A small synthetic indoor scene (8 views of 32×32, scene_box, depth, GT panoptic and points).
    Treat as read-only: copy it (``robust_helpers.copy_scene``) before changing anything."""
    from lift3d.synth import SynthOptions, make_scene

    root = tmp_path_factory.mktemp("robust_scene") / "room"
    make_scene(root, SynthOptions(kind="indoor", seed=3, noise="moderate", n_views=8, width=32, height=32),
               progress=False)
    return root


@pytest.fixture(scope="session")
def healthy_run(synth_scene, tmp_path_factory) -> Path:
    """A tiny run trained in-process (40 steps, checkpoints at 20 and 40). Treat as read-only."""
    from lift3d.train.trainer import train

    out = tmp_path_factory.mktemp("robust_runs")
    result = train(synth_scene, preset="fast", output_dir=out, overrides=tiny(), progress=False,
                   print_summary=False)
    return Path(result.run.path)
