"""Scene normalisation and the sizes a scene determines (docs/presets.md, "what the scene decides").

The field lives in *normalised* coordinates: the foreground box maps to ``[-1, 1]^3``. For bounded scenes
that box is the whole scene; for unbounded scenes everything outside it is contracted. The similarity
transform (uniform scale + translation, no rotation, so exports keep the user's axes) is saved as the run's
``transform.json`` so exports can be written back in the input world frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lift3d.data.scene import Scene
from lift3d.errors import InputError
from lift3d.utils.atomic import write_json_atomic
from lift3d.utils.files import read_json


@dataclass
class SceneNormalization:
    """``x_norm = (x_world − center) · scale``."""

    center: np.ndarray  # [3]
    scale: float
    bounded: bool
    aabb_world: np.ndarray  # [2, 3] foreground box in world units

    @property
    def matrix(self) -> np.ndarray:
        """4×4 world → normalised."""
        m = np.eye(4) * self.scale
        m[3, 3] = 1.0
        m[:3, 3] = -self.center * self.scale
        return m

    def to_normalized(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points, np.float64) - self.center) * self.scale

    def to_world(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points, np.float64) / self.scale + self.center

    def c2w_normalized(self, c2w: np.ndarray) -> np.ndarray:
        """Camera-to-world matrices ``[F, 4, 4]`` re-expressed in normalised coordinates (rotation kept)."""
        out = np.array(c2w, dtype=np.float64, copy=True)
        out[..., :3, 3] = self.to_normalized(out[..., :3, 3])
        return out

    def to_json(self) -> dict:
        return {
            "transform": self.matrix.tolist(),
            "center": self.center.tolist(),
            "scale": float(self.scale),
            "bounded": bool(self.bounded),
            "aabb_world": np.asarray(self.aabb_world).tolist(),
            "note": "x_normalized = transform @ [x_world, 1]; the inverse gives world coordinates",
        }

    @classmethod
    def from_json(cls, d: dict) -> "SceneNormalization":
        return cls(np.asarray(d["center"], float), float(d["scale"]), bool(d["bounded"]), np.asarray(d["aabb_world"], float))

    def save(self, path: Path) -> None:
        write_json_atomic(path, self.to_json())

    @classmethod
    def load(cls, path: Path) -> "SceneNormalization":
        raw = read_json(path)
        try:
            return cls.from_json(raw)
        except (TypeError, ValueError, KeyError) as exc:
            raise InputError(path, f"not a scene normalisation ({exc})") from exc


def _optical_axes_focus(scene: Scene) -> tuple[np.ndarray, float]:
    """Least-squares point closest to all optical axes, and how much in front of the cameras it is
    (fraction of cameras for which the point lies ahead)."""
    c = scene.cameras.centers
    d = scene.cameras.forward
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for ci, di in zip(c, d):
        p = np.eye(3) - np.outer(di, di)
        a += p
        b += p @ ci
    focus = np.linalg.lstsq(a, b, rcond=None)[0]
    ahead = float(np.mean(((focus - c) * d).sum(-1) > 0))
    return focus, ahead


def infer_normalization(scene: Scene, margin: float = 1.05) -> tuple[SceneNormalization, str]:
    """Decide bounded vs unbounded and the foreground box, and say why.

    Rules, in order:
    1. ``scene_box`` in transforms.json decides (type and box).
    2. Depth maps: the box of the back-projected depth (1st–99th percentile) and the cameras; unbounded
       when the far content (99th percentile distance) reaches beyond 10× the camera spread.
    3. Otherwise: when the optical axes meet in front of most cameras (an inward-looking capture), bounded
       around the cameras and that focus point; else unbounded around the cameras.
    """
    cams = scene.cameras.centers
    if scene.scene_box is not None:
        aabb = np.asarray(scene.scene_box.aabb, float)
        bounded = scene.scene_box.type == "bounded"
        why = f"scene_box in transforms.json ({scene.scene_box.type})"
    elif scene.has_depth:
        pts = []
        idx = np.linspace(0, len(scene) - 1, min(len(scene), 16)).astype(int)
        for i in idx:
            d = scene.depth(i)
            h, w = d.shape
            vv, uu = np.mgrid[0:h:4, 0:w:4]
            z = d[vv, uu]
            ok = z > 0
            pts.append(scene.cameras.unproject(i, uu[ok], vv[ok], z[ok]))
        pts = np.concatenate(pts) if pts else cams
        lo, hi = np.percentile(pts, 1, axis=0), np.percentile(pts, 99, axis=0)
        spread = max(float(np.ptp(cams, axis=0).max()), 1e-6)
        reach = float(np.percentile(np.linalg.norm(pts - cams.mean(0), axis=1), 99))
        bounded = reach < 10.0 * max(spread, 0.1 * reach)
        aabb = np.stack([np.minimum(lo, cams.min(0)), np.maximum(hi, cams.max(0))])
        if not bounded:
            # The foreground box: the cameras and the nearer content.
            near = np.percentile(pts, [10, 90], axis=0)
            aabb = np.stack([np.minimum(near[0], cams.min(0)), np.maximum(near[1], cams.max(0))])
        why = f"depth maps (content reach {reach:.3g} vs camera spread {spread:.3g})"
    else:
        focus, ahead = _optical_axes_focus(scene)
        bounded = ahead > 0.8 and len(scene) > 2
        pts = np.vstack([cams, focus[None]]) if bounded else cams
        aabb = np.stack([pts.min(0), pts.max(0)])
        why = f"camera layout (optical axes meet ahead of {ahead:.0%} of the cameras)"
    center = aabb.mean(0)
    half = max(float((aabb[1] - aabb[0]).max()) / 2.0, 1e-6)
    scale = 1.0 / (half * margin)
    return SceneNormalization(center, scale, bounded, aabb), why


def typical_camera_distance(scene: Scene, norm: SceneNormalization) -> float:
    """Typical distance from a camera to the foreground box centre (normalised units, at least 0.5): the
    viewing distance scene sizes assume where no depth map says better."""
    cams_n = norm.to_normalized(scene.cameras.centers)
    return max(float(np.median(np.linalg.norm(cams_n, axis=1))), 0.5)


def derive_grid_resolution(scene: Scene, norm: SceneNormalization, cap: int, minimum: int = 32) -> tuple[int, str]:
    """Finest grid resolution from scene extent and image size: about one voxel per pixel footprint at the
    typical viewing distance, rounded up to a multiple of 16 and capped."""
    dist = typical_camera_distance(scene, norm)
    focal = float(np.median(scene.cameras.fx))
    footprint = dist / focal  # normalised units per pixel
    extent = 2.0 if norm.bounded else 4.0  # grid side in normalised (contracted) units
    want = extent / footprint
    res = int(np.clip(np.ceil(want / 16.0) * 16, minimum, cap))
    return res, f"{want:.0f} voxels/axis for a pixel footprint of {footprint:.4f} at distance {dist:.2f} (cap {cap})"
