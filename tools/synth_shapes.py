#!/usr/bin/env python3
"""Draw docs/images/synth_shapes.png: the room shapes and the clutter of ``lift3d synth`` (``--room-shape``,
``--clutter``), each as a cut-away seen from above (the walls and ceiling between the eye and the room left
out, the camera path as dots) and one of its views with the GT panoptic map.

    python tools/synth_shapes.py                         # writes docs/images/synth_shapes.png
    python tools/synth_shapes.py --out shapes.png --size 160
    python tools/synth_shapes.py --only sloped:2 --out /tmp/sloped.png   # one room (shape:seed[:clutter])
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

OUT = Path(__file__).resolve().parent.parent / "docs" / "images" / "synth_shapes.png"
#: (title, shape, seed, clutter): seeds chosen to show each variant (round and open have two).
ROOMS = [
    ("polygon", "polygon", 8, "none"), ("hexagon", "hexagon", 1, "none"), ("sloped", "sloped", 0, "none"),
    ("vaulted", "vaulted", 0, "none"), ("round: cylinder", "round", 2, "none"),
    ("round: curved wall", "round", 4, "none"), ("open: doorway", "open", 2, "none"),
    ("open: dark space", "open", 0, "none"), ("auto, --clutter dense", "auto", 0, "dense"),
]


def cutaway(content, eye: np.ndarray):
    """The content without the wall and ceiling triangles whose room side faces away from ``eye``."""
    from lift3d.synth.geometry import Mesh
    from lift3d.synth.polygons import inside_polygon

    poly = content.room_polygon
    objects = []
    for o in content.objects:
        if o.category_id not in (1, 3, 5):  # walls, ceiling, windows
            objects.append(o)
            continue
        m = o.mesh
        tri = m.vertices[m.triangles]
        centre = tri.mean(1)
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        if o.category_id == 3:
            inward = -np.sign(n[:, 2:3]) * n  # a ceiling's room side is below it
        else:
            probe = centre[:, :2] + 0.05 * n[:, :2]
            inward = np.where(inside_polygon(probe, poly)[:, None], n, -n)
        keep = np.einsum("ij,ij->i", inward, eye - centre) > 0
        keep |= np.abs(n[:, 2]) > 0.99 if o.category_id == 1 else False  # tops and bottoms of inner walls
        if keep.any():
            objects.append(replace(o, mesh=Mesh(m.vertices, m.triangles[keep], m.corner_normals[keep],
                                                m.material[keep])))
    return replace(content, objects=objects)


def _labels_rgb(sem: np.ndarray, seg: np.ndarray, colors: dict) -> np.ndarray:
    img = np.zeros(sem.shape + (3,), np.uint8)
    for cid, col in colors.items():
        img[sem == cid] = col
    edge = np.zeros(sem.shape, bool)
    edge[:, 1:] |= seg[:, 1:] != seg[:, :-1]
    edge[1:, :] |= seg[1:, :] != seg[:-1, :]
    img[edge] = (img[edge] * 0.3).astype(np.uint8)
    return img


def draw_room(shape: str, seed: int, clutter: str, size: int) -> np.ndarray:
    """One cell: the cut-away (2 x size wide, 1.5 x size high) above a view and its GT panoptic map."""
    from lift3d.data.cameras import Cameras, look_at
    from lift3d.synth.cameras import camera_path
    from lift3d.synth.geometry import RayCaster
    from lift3d.synth.make import build_content, render_view

    content, _ = build_content("indoor", seed, shape, clutter)
    caster = RayCaster(content)
    lo, hi = content.aabb
    centre = (lo + hi) / 2
    # The cut-away: from a corner, 50° above the floor; sloped and vaulted rooms from the side at eye height,
    # across the slope or along the vault, so the ceiling's profile shows.
    room = content.description["room"]
    ceiling = room.get("ceiling", {})
    az, el = np.radians(-60.0), np.radians(50.0)
    if ceiling.get("type") == "plane":
        d = np.array(ceiling["rising_towards"])
        az, el = np.arctan2(d[1], d[0]) - np.pi / 2 + np.radians(15.0), 0.0
    elif "bulges_towards" in room:  # a curved wall: seen from the other side
        b = np.array(room["bulges_towards"])
        az = np.arctan2(-b[1], -b[0]) + np.radians(20.0)
    elif ceiling.get("type") == "barrel_vault":
        a = np.array(ceiling["across"])
        az, el = np.arctan2(a[1], a[0]) + np.pi / 2 + np.radians(15.0), 0.0
    direction = np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
    target = np.array([centre[0], centre[1], 0.45 * hi[2]])
    w, h = 2 * size, 3 * size // 2
    fx = 0.5 * w / np.tan(np.radians(45) / 2)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    for dist in np.linspace(2.0, 60.0, 300):  # the nearest eye that frames the whole room
        eye = target + dist * direction
        cams = Cameras(c2w=look_at(eye, target)[None], fx=fx, fy=fx, cx=w / 2, cy=h / 2, width=w, height=h)
        uv, z = cams.project(0, corners)
        if np.all(z > 0) and np.all((uv > [0.04 * w, 0.04 * h]) & (uv < [0.96 * w, 0.96 * h])):
            break
    top = render_view(RayCaster(cutaway(content, eye)), cams, 0)["rgb"].copy()
    rng = np.random.default_rng(np.random.SeedSequence([seed, 1, 0]))
    rng.integers(3), rng.uniform(60.0, 80.0)  # as make_scene draws: the path choice, the field of view
    path = camera_path(content, caster, "walk", 24, rng, fov=(70.0, 1.0))
    uv, z = cams.project(0, path[:, :3, 3])
    for (u, v), d in zip(uv, z):
        if d > 0:
            cv2.circle(top, (int(u), int(v)), 2, (255, 40, 40), -1, cv2.LINE_AA)
    # The view that sees the most things (after the first few, which start at a wall).
    fxv = 0.5 * size / np.tan(np.radians(70) / 2)
    views = Cameras(c2w=path, fx=fxv, fy=fxv, cx=size / 2, cy=size / 2, width=size, height=size)
    best, best_n = 0, -1
    for i in range(len(path)):
        seg = render_view(caster, Cameras(c2w=path[i:i + 1], fx=fxv / 4, fy=fxv / 4, cx=size / 8, cy=size / 8,
                                          width=size // 4, height=size // 4), 0, supersample=False)["segment"]
        n = len(np.unique(seg[seg > 1000]))
        if n > best_n:
            best, best_n = i, n
    view = render_view(caster, views, best)
    colors = {c.id: c.color for c in content.categories}
    labels = _labels_rgb(view["category"], view["segment"], colors)
    return np.vstack([top, np.hstack([view["rgb"], labels])])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--size", type=int, default=128, help="side of a view in pixels (the cut-away is 2x wide)")
    ap.add_argument("--only", nargs="+", default=None, metavar="SHAPE:SEED[:CLUTTER]")
    ap.add_argument("--columns", type=int, default=3)
    args = ap.parse_args()
    rooms = ROOMS if args.only is None else [
        (x, *(x.split(":") + ["none"])[:3]) for x in args.only]
    size, gap, header = args.size, 6, 16
    cells = []
    for title, shape, seed, clutter in rooms:
        cell = draw_room(shape, int(seed), clutter, size)
        canvas = np.full((header + cell.shape[0], cell.shape[1], 3), 255, np.uint8)
        canvas[header:] = cell
        cv2.putText(canvas, f"{title} (seed {seed})", (2, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1,
                    cv2.LINE_AA)
        cells.append(canvas)
    cols = min(args.columns, len(cells))
    rows = (len(cells) + cols - 1) // cols
    ch, cw = cells[0].shape[:2]
    grid = np.full((rows * (ch + gap) - gap, cols * (cw + gap) - gap, 3), 255, np.uint8)
    for k, cell in enumerate(cells):
        r, c = divmod(k, cols)
        grid[r * (ch + gap):r * (ch + gap) + ch, c * (cw + gap):c * (cw + gap) + cw] = cell
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), grid[:, :, ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
