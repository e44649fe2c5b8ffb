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


@dataclass
class ContentPoints:
    """Where the scene's surfaces are, in world units: what the scene space is sized from.

    Attributes
    ----------
    xyz : np.ndarray
        ``[N, 3]`` world points (back-projected depth maps, or triangulated / the scene's sparse points).
    source : str
        Where they came from, for the reason in ``config.yml``.
    """

    xyz: np.ndarray
    source: str


#: Share of the content points the derived box may leave out on each side of each axis (robust to stray
#: points: a triangulation keeps a few far outliers).
CONTENT_TAIL = 0.01
#: The derived box grows by this fraction of its diagonal on every side, so that the surfaces at the content's
#: edge (the far walls) lie inside it rather than on its faces.
CONTENT_MARGIN = 0.05
#: Content farther from the cameras than this many times their spread (99th percentile distance) is a scene
#: that reaches far (a street, a landscape): unbounded, contracted space.
FAR_REACH = 10.0
#: More than this share of the content outside a given ``scene_box`` is reported.
OUTSIDE_WARNING = 0.01


def depth_content(scene: Scene, max_frames: int = 16, stride: int = 4) -> ContentPoints | None:
    """Back-projected depth of up to ``max_frames`` frames spread over the capture (every ``stride``-th pixel),
    or None when not every frame has a depth map."""
    if not scene.has_depth:
        return None
    pts = []
    for i in np.linspace(0, len(scene) - 1, min(len(scene), max_frames)).astype(int):
        d = scene.depth(int(i))
        h, w = d.shape
        vv, uu = np.mgrid[0:h:stride, 0:w:stride]
        z = d[vv, uu]
        ok = z > 0
        pts.append(scene.cameras.unproject(int(i), uu[ok], vv[ok], z[ok]))
    xyz = np.concatenate(pts) if pts else np.zeros((0, 3))
    return ContentPoints(xyz, "depth maps") if len(xyz) else None


def share_outside(aabb: np.ndarray, xyz: np.ndarray) -> float:
    """Share of the points ``[N, 3]`` outside the box ``[2, 3]`` (0 without points).

    Examples
    --------
    >>> share_outside(np.array([[0, 0, 0], [1, 1, 1.0]]), np.array([[0.5, 0.5, 0.5], [2, 0.5, 0.5]]))
    0.5
    """
    if not len(xyz):
        return 0.0
    aabb = np.asarray(aabb, float)
    return float(np.mean(np.any((xyz < aabb[0]) | (xyz > aabb[1]), axis=1)))


def optical_axes_focus(scene: Scene) -> tuple[np.ndarray, float]:
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


def content_box(content: ContentPoints, cams: np.ndarray) -> tuple[np.ndarray, bool, str]:
    """The foreground box ``[2, 3]`` from where the content is, whether the scene is bounded, and why.

    The box holds the cameras and the content between its ``CONTENT_TAIL`` and ``1 − CONTENT_TAIL``
    quantiles on each axis, grown by ``CONTENT_MARGIN`` of its diagonal on every side. The scene is unbounded
    when the content reaches (99th percentile distance from the cameras' centroid) more than ``FAR_REACH``
    times as far as the cameras spread; then the box holds the cameras and the nearer content (10th–90th
    percentile) and the rest of space is contracted.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> room = ContentPoints(rng.uniform([-3, -2, 0], [3, 2, 2.5], (5000, 3)), "points")
    >>> cams = rng.uniform([-1, -1, 1.4], [1, 1, 1.6], (20, 3))
    >>> box, bounded, why = content_box(room, cams)
    >>> bounded, np.round(box, 1).tolist()
    (True, [[-3.3, -2.3, -0.3], [3.3, 2.3, 2.9]])
    """
    xyz = np.asarray(content.xyz, np.float64)
    lo = np.percentile(xyz, 100 * CONTENT_TAIL, axis=0)
    hi = np.percentile(xyz, 100 * (1 - CONTENT_TAIL), axis=0)
    spread = max(float(np.ptp(cams, axis=0).max()) if len(cams) > 1 else 0.0, 1e-6)
    reach = float(np.percentile(np.linalg.norm(xyz - cams.mean(0), axis=1), 99))
    bounded = reach < FAR_REACH * max(spread, reach / FAR_REACH)
    if not bounded:
        lo, hi = np.percentile(xyz, [10, 90], axis=0)
    box = np.stack([np.minimum(lo, cams.min(0)), np.maximum(hi, cams.max(0))])
    grow = CONTENT_MARGIN * float(np.linalg.norm(box[1] - box[0]))
    box = box + [[-grow] * 3, [grow] * 3]
    why = (f"{content.source} ({len(xyz)} points; the box of their {CONTENT_TAIL:.0%}-{1 - CONTENT_TAIL:.0%} "
           f"quantiles and the cameras grown by {CONTENT_MARGIN:.0%} of its diagonal; content reach {reach:.3g} vs "
           f"camera spread {spread:.3g}" + (")" if bounded else f", more than {FAR_REACH:g}x: unbounded)"))
    return box, bounded, why


def infer_normalization(scene: Scene, margin: float = 1.05,
                        content: ContentPoints | None = None) -> tuple[SceneNormalization, str]:
    """Decide bounded vs unbounded and the foreground box, and say why.

    Rules, in order:
    1. ``scene_box`` in transforms.json decides (type and box).
    2. Where the content is (:func:`content_box`): ``content`` when given (the caller's triangulated points),
       else the scene's depth maps (:func:`depth_content`).
    3. Otherwise the camera layout: when the optical axes meet in front of most cameras (an inward-looking
       capture), bounded around the cameras and that focus point; else unbounded around the cameras. A scene
       whose surfaces reach past its cameras is cut by that box: the reason says so.
    """
    cams = scene.cameras.centers
    if content is None:
        content = depth_content(scene)
    if scene.scene_box is not None:
        aabb = np.asarray(scene.scene_box.aabb, float)
        bounded = scene.scene_box.type == "bounded"
        why = f"scene_box in transforms.json ({scene.scene_box.type})"
    elif content is not None and len(content.xyz):
        aabb, bounded, why = content_box(content, cams)
    else:
        focus, ahead = optical_axes_focus(scene)
        bounded = ahead > 0.8 and len(scene) > 2
        pts = np.vstack([cams, focus[None]]) if bounded else cams
        aabb = np.stack([pts.min(0), pts.max(0)])
        why = (f"camera layout (optical axes meet ahead of {ahead:.0%} of the cameras); no depth maps or "
               "triangulated points to say where the surfaces are")
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
