#!/usr/bin/env python3
"""Draw docs/images/synth_examples.png: one view of several ``lift3d synth`` scenes (seeds and kinds) with
its GT panoptic map, the view-correlated pseudo-labels and the sensor depth.

    python tools/synth_examples.py                 # writes docs/images/synth_examples.png
    python tools/synth_examples.py --out grid.png --seeds 0 1 2 3 --outdoor-seeds 0 1
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np

OUT = Path(__file__).resolve().parent.parent / "docs" / "images" / "synth_examples.png"


def _labels_rgb(sem: np.ndarray, seg: np.ndarray, colors: dict[int, tuple[int, int, int]]) -> np.ndarray:
    """Class colours with dark outlines between segments (RGB)."""
    img = np.zeros(sem.shape + (3,), np.uint8)
    for cid, col in colors.items():
        img[sem == cid] = col
    edge = np.zeros(sem.shape, bool)
    edge[:, 1:] |= seg[:, 1:] != seg[:, :-1]
    edge[1:, :] |= seg[1:, :] != seg[:-1, :]
    img[edge] = (img[edge] * 0.3).astype(np.uint8)
    return img


def _depth_rgb(depth: np.ndarray, far: float) -> np.ndarray:
    """Turbo colour map of depth up to ``far`` metres; holes (0) black (RGB)."""
    d = np.clip(depth / far, 0, 1)
    img = cv2.applyColorMap((255 * (1 - d)).astype(np.uint8), cv2.COLORMAP_TURBO)[:, :, ::-1].copy()
    img[depth <= 0] = 0
    return img


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--outdoor-seeds", type=int, nargs="+", default=[0, 1])
    args = ap.parse_args()

    from lift3d.data.scene import load_scene
    from lift3d.synth import SynthOptions, make_scene

    size, margin, header = 128, 92, 30
    columns, titles = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for kind, seeds in (("indoor", args.seeds), ("outdoor", args.outdoor_seeds)):
            for seed in seeds:
                root = Path(tmp) / f"{kind}{seed}"
                rep = make_scene(root, SynthOptions(kind=kind, seed=seed, noise="view-correlated", n_views=12,
                                                    width=size, height=size), progress=False)
                scene = load_scene(root)
                colors = {c.id: c.color for c in scene.categories}
                # The view showing the most objects.
                counts = [len(np.unique(scene.gt_labels(i).instance)) for i in range(len(scene))]
                i = int(np.argmax(counts))
                gt, ps = scene.gt_labels(i), scene.pseudo_labels(i)
                far = 8.0 if kind == "indoor" else 12.0
                columns.append(np.vstack([scene.image(i), _labels_rgb(gt.semantic, gt.segment, colors),
                                          _labels_rgb(ps.semantic, ps.segment, colors),
                                          _depth_rgb(scene.depth(i), far)]))
                desc = rep["content"]["scene"]
                shape = desc["room"]["shape"] if kind == "indoor" else "street"
                titles.append((f"{kind} seed {seed}", f"{shape}, {rep['options']['camera_path']}"))
    gap = 4
    width = margin + len(columns) * (size + gap)
    canvas = np.full((header + 4 * (size + gap), width, 3), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    for k, (col, (t1, t2)) in enumerate(zip(columns, titles)):
        x = margin + k * (size + gap)
        for r in range(4):
            y = header + r * (size + gap)
            canvas[y:y + size, x:x + size] = col[r * size:(r + 1) * size]
        cv2.putText(canvas, t1, (x + 2, 12), font, 0.36, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.putText(canvas, t2, (x + 2, 25), font, 0.36, (60, 60, 60), 1, cv2.LINE_AA)
    for r, name in enumerate(["image", "GT panoptic", "pseudo-labels", "(view-corr.)", "sensor depth"]):
        row = r if r < 3 else r - 1
        y = header + row * (size + gap) + size // 2 + (14 if r == 3 else 0)
        cv2.putText(canvas, name, (4, y), font, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), canvas[:, :, ::-1])
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
