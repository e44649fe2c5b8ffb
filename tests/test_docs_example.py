"""docs/examples/minimal_scene is a valid scene folder, and docs/scene-format.md describes what is in it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lift3d.data.scene import load_scene

DOCS = Path(__file__).resolve().parents[1] / "docs"
EXAMPLE = DOCS / "examples" / "minimal_scene"
DOC = DOCS / "scene-format.md"


@pytest.fixture(scope="module")
def doc_text() -> str:
    return DOC.read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def meta() -> dict:
    return json.loads((EXAMPLE / "transforms.json").read_text(encoding="utf-8"))


def test_example_loads_and_validates():
    scene = load_scene(EXAMPLE)
    scene.validate()
    assert len(scene) == 4
    assert scene.image(0).shape == (32, 32, 3)
    assert scene.has_gt and scene.has_depth and scene.gt_points_path is not None
    assert scene.thing_ids and scene.stuff_ids
    assert scene.scene_box is not None
    for s in ("train", "val", "test"):
        assert len(scene.split(s)) > 0
    # Held-out frames really are held out.
    assert not set(scene.split("test").tolist()) & set(scene.split("train").tolist())
    gt = scene.gt_points()
    assert len(gt["xyz"]) == len(gt["semantic"]) == len(gt["instance"]) > 0
    assert np.isfinite(gt["xyz"]).all()


def test_example_is_small():
    total = sum(p.stat().st_size for p in EXAMPLE.rglob("*") if p.is_file())
    assert total < 300_000, f"docs example grew to {total} bytes"


def test_doc_mentions_every_top_level_entry(doc_text):
    for entry in sorted(EXAMPLE.iterdir()):
        assert f"`{entry.name}" in doc_text or f"{entry.name}/" in doc_text, (
            f"docs/scene-format.md does not mention {entry.name!r} of the example folder"
        )


def test_doc_mentions_every_key_of_the_example(doc_text, meta):
    keys = set(meta) | {k for fr in meta["frames"] for k in fr}
    keys |= {k for c in meta["categories"] for k in c} | set(meta["scene_box"])
    missing = sorted(k for k in keys if f"`{k}`" not in doc_text and f'"{k}"' not in doc_text)
    assert not missing, f"docs/scene-format.md does not mention these transforms.json keys: {missing}"


def test_doc_gives_the_command_that_wrote_the_example(doc_text, meta):
    a = meta["lift3d_synth"]
    cmd = (f"lift3d synth --out docs/examples/minimal_scene --kind {a['kind']} --seed {a['seed']} "
           f"--noise {a['noise']} --views {a['n_views']} --width {a['width']} --height {a['height']}")
    assert cmd in doc_text
