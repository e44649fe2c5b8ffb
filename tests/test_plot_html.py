"""``lift3d plot FILE.ply --html``: a self-contained page, opened in headless Chromium (``tests/interop.py``:
skipped without it, failed under CI)."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

from lift3d.data.ply import write_labelled_ply
from lift3d.viz.palette import instance_color
from interop import require_tool

CLASSES = [{"id": 1, "name": "floor", "isthing": False, "color": [120, 90, 60]},
           {"id": 3, "name": "table", "isthing": True, "color": [30, 30, 200]}]
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run"]


def _write_scene(folder: Path, mesh: bool = False) -> Path:
    """A floor grid with a table block on it (points), or a box mesh."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "classes.json").write_text(json.dumps({"classes": CLASSES}))
    if mesh:
        v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float32)
        f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
        path = folder / "mesh.ply"
        write_labelled_ply(path, v, semantic=np.full(8, 3), instance=np.full(8, 1), faces=f)
        return path
    g = np.stack(np.meshgrid(np.linspace(0, 2, 60), np.linspace(0, 2, 60), [0.0]), -1).reshape(-1, 3)
    t = np.random.default_rng(0).uniform([0.6, 0.6, 0], [1.4, 1.4, 0.7], (3000, 3))
    xyz = np.concatenate([g, t])
    sem = np.r_[np.full(len(g), 1), np.full(len(t), 3)]
    inst = np.r_[np.zeros(len(g), int), np.ones(len(t), int)]
    path = folder / "points.ply"
    write_labelled_ply(path, xyz, semantic=sem, instance=inst, confidence=np.ones(len(xyz)))
    return path


def test_html_page_is_self_contained(tmp_path):
    from lift3d.cli.main import main

    src = _write_scene(tmp_path / "export")
    out = tmp_path / "view.html"
    assert main(["plot", str(src), "--html", str(out)]) == 0
    page = out.read_text()
    # Nothing is fetched when the page opens: no external scripts, styles, images or fetch calls.
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", page)
    assert "fetch(" not in page and "XMLHttpRequest" not in page and "import " not in page
    assert '"name":"table"' in page and '"count":3000' in page  # the legend, from classes.json beside


def _screenshot(chromium: str, html: Path, png: Path, fragment: str = "") -> np.ndarray:
    import cv2

    subprocess.run([chromium, *CHROMIUM_FLAGS, f"--user-data-dir={png.parent / ('profile' + png.stem)}",
                    "--window-size=800,600", f"--screenshot={png}", html.as_uri() + fragment],
                   check=True, capture_output=True, timeout=120)
    return cv2.cvtColor(cv2.imread(str(png)), cv2.COLOR_BGR2RGB)


def _has_colour(img: np.ndarray, rgb, tol: int = 40, min_pixels: int = 200) -> bool:
    return int((np.abs(img.astype(int) - np.asarray(rgb)).max(-1) <= tol).sum()) >= min_pixels


def test_html_page_renders_in_headless_chromium(tmp_path):
    from lift3d.viz.html import write_html

    chromium = require_tool("chromium")

    page = write_html(_write_scene(tmp_path / "export"), tmp_path / "view.html")
    shot = _screenshot(chromium, page, tmp_path / "instances.png")
    view = shot[:, :560]  # the 3D view, left of the legend panel
    drawn = (view < 245).any(-1)
    assert drawn.mean() > 0.05, "the canvas is blank"
    table_instance = instance_color(1)[0]
    assert _has_colour(view, table_instance), "instance colours are drawn"
    assert not _has_colour(view, CLASSES[1]["color"], tol=20)
    classes = _screenshot(chromium, page, tmp_path / "classes.png", "#classes")[:, :560]
    assert _has_colour(classes, CLASSES[1]["color"], tol=20), "the class view shows the class colour"
    mesh_page = write_html(_write_scene(tmp_path / "mesh", mesh=True), tmp_path / "mesh.html")
    mesh = _screenshot(chromium, mesh_page, tmp_path / "mesh.png")[:, :560]
    assert (mesh < 245).any(-1).mean() > 0.05, "the mesh is drawn"
