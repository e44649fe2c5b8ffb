"""Where the scene's surfaces are, before the field is sized (docs/presets.md, "What the scene decides").

The scene space (bounded box or contracted space, :func:`lift3d.model.normalization.infer_normalization`)
comes from the content, never from where the cameras stand: the depth maps when every frame has one, else
the scene's own sparse points (``lift3d triangulate``'s, COLMAP's), else points triangulated now from the
training images — the same points the images-only depth targets start from, so they are computed once and
handed on (:func:`lift3d.train.image_depth.image_depth_targets`'s ``sparse``). A ``scene_box`` in
``transforms.json`` still decides, but when the content lies outside it the run says so, with the numbers.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from lift3d.data.scene import Scene
from lift3d.data.stereo import DenseDepth, SparsePoints
from lift3d.model.config import Config
from lift3d.model.normalization import OUTSIDE_WARNING, ContentPoints, content_box, depth_content, share_outside
from lift3d.errors import InputError
from lift3d.train.image_depth import frames_without_depth, scene_dense_maps, scene_sparse_points
from lift3d.train.profile import OUTDOOR_SHARE, outdoor_label_share


@dataclass
class SceneGeometry:
    """What the images say of the scene's surfaces before training: where they are (``content``) and the sparse
    points and plane-sweep maps behind that, handed on to the depth targets so they are computed once."""

    content: ContentPoints | None = None
    sparse: SparsePoints | None = None
    dense: DenseDepth | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    """Wall time of each stage that ran: ``triangulation`` (or reading the scene's sparse points), ``plane_sweep``."""


#: Every this-many-th pixel of a plane-sweep map becomes a content point (a map of 128² holds ~10 000 depths).
DENSE_STRIDE = 2


def scene_content(scene: Scene, cfg: Config, progress: bool = False) -> SceneGeometry:
    """The points that say where the scene is, and the sparse points and plane-sweep maps behind them.

    Depth maps when every frame has one; else the scene's sparse points or points triangulated now from the
    training frames, with the plane sweep's depths when the run will use them (source ``dense`` or ``planes``,
    or ``auto`` in a scene that does not look outdoor: :func:`looks_outdoor`). The sweep's depths reach the
    plain walls that sparse points miss, so the space and the profile see them.

    Parameters
    ----------
    scene : Scene
    cfg : Config
        The run's settings: points are triangulated here only when the run would triangulate anyway (depth
        targets from the images on, training frames without a depth map, a source other than ``none``).
    progress : bool
    """
    depth = depth_content(scene)
    if depth is not None:
        return SceneGeometry(depth)
    train = scene.split("train")
    wants_points = (cfg.losses.image_depth > 0 and len(frames_without_depth(scene, train)) > 0
                    and cfg.image_depth.source != "none")
    if scene.sparse_points_paths is None and not wants_points:
        return SceneGeometry()
    started = time.perf_counter()
    sparse, origin = scene_sparse_points(scene, train, cache=None, progress=progress)
    seconds = {"triangulation": round(time.perf_counter() - started, 2)}
    if not len(sparse):
        return SceneGeometry(None, sparse, seconds=seconds)
    source = "points triangulated from the training images" if origin == "triangulated" else f"sparse points, {origin}"
    content = ContentPoints(np.asarray(sparse.xyz, np.float64), source)
    requested = cfg.image_depth.source
    if not wants_points or requested == "sparse" or (requested == "auto" and looks_outdoor(scene, content)):
        return SceneGeometry(content, sparse, seconds=seconds)
    started = time.perf_counter()
    dense, _ = scene_dense_maps(scene, train, sparse, cache=None, progress=progress)
    seconds["plane_sweep"] = round(time.perf_counter() - started, 2)
    index = {f.name: k for k, f in enumerate(scene.frames)}
    xyz = [content.xyz] + [_map_points(scene, index[name], d) for name, d in zip(dense.frame_names, dense.depth)]
    return SceneGeometry(ContentPoints(np.concatenate(xyz), source + " and their plane-sweep depths"), sparse, dense,
                         seconds)


def looks_outdoor(scene: Scene, content: ContentPoints) -> bool:
    """Whether the labels or the sparse points already say outdoors (:mod:`lift3d.train.profile`'s first two
    rules), where ``auto`` uses sparse points alone and no plane sweep is wanted."""
    cams = scene.cameras.centers[scene.split("train")]
    return (not content_box(content, cams)[1]
            or outdoor_label_share(scene, scene.split("train")) > OUTDOOR_SHARE)


def _map_points(scene: Scene, i: int, depth: np.ndarray) -> np.ndarray:
    d = np.asarray(depth)[::DENSE_STRIDE, ::DENSE_STRIDE]
    rows, cols = np.nonzero(d > 0)
    return scene.cameras.unproject(i, cols * DENSE_STRIDE, rows * DENSE_STRIDE, d[rows, cols])


#: Content within this fraction of the diagonal outside a given ``scene_box`` is on its faces, not cut off.
BOX_TOLERANCE = 0.02


def box_warnings(scene: Scene, content: ContentPoints | None) -> list[str]:
    """A warning when a ``scene_box`` in transforms.json leaves more than :data:`OUTSIDE_WARNING` of the
    content farther than :data:`BOX_TOLERANCE` outside it (surfaces beyond would be painted onto its faces)."""
    if scene.scene_box is None or content is None or not len(content.xyz) or scene.scene_box.type != "bounded":
        return []
    box = np.asarray(scene.scene_box.aabb, float)
    # surfaces on the box's faces (a room's walls) scatter a little past them with depth noise: only content
    # beyond a margin of the diagonal counts as cut off
    tolerance = BOX_TOLERANCE * float(np.linalg.norm(box[1] - box[0]))
    share = share_outside(box + [[-tolerance] * 3, [tolerance] * 3], content.xyz)
    if share <= OUTSIDE_WARNING:
        return []
    lo, hi = np.percentile(content.xyz, [1, 99], axis=0)
    return [f"scene_box in transforms.json leaves {share:.1%} of the {content.source} outside it (by more than "
            f"{tolerance:.3g}; box "
            f"{np.round(box[0], 2).tolist()} .. {np.round(box[1], 2).tolist()}; the points' 1-99 % range "
            f"{np.round(lo, 2).tolist()} .. {np.round(hi, 2).tolist()}): surfaces beyond it are painted onto its "
            "faces; grow the box or remove it to let lift3d size the space from the content"]


def check_poses(scene: Scene) -> dict:
    """The pose-convention check of the training frames (:mod:`lift3d.sfm.pose_check`), for ``config.yml``.

    Raises
    ------
    InputError
        Naming ``transforms.json`` when the poses fit the images badly as written and a convention fix makes
        them fit (world-to-camera written as camera-to-world, OpenCV camera axes written as OpenGL).
    """
    # here, not at module level: keeps `import lift3d.train` cheap (OpenCV's feature code loads only here)
    from lift3d.sfm.pose_check import FIX_MEANS, check_pose_convention

    # the input depth only: depth kept for evaluation (gt_depth_file_path) stays out of training, checks included
    depth = scene.depth if scene.has_depth else None
    check = check_pose_convention(scene.cameras, scene.split("train"), scene.image, depth, stored="opengl")
    if check.likely_fix is not None:
        raise InputError(scene.root / "transforms.json", f"{FIX_MEANS[check.likely_fix]} ({check.describe()}): "
                         "transform_matrix must be camera-to-world in OpenGL camera axes (x right, y up, looking "
                         f"down -z); fix: {check.likely_fix} each transform_matrix (or convert again with lift3d "
                         f"convert --fix-poses {check.likely_fix.replace(' ', '-')})")
    out = check.to_json()
    if not check.fits:
        out["warning"] = f"the poses fit the images poorly under every convention tried ({check.describe()})"
    return out
