"""Do the poses fit the images? A check of the pose convention at load (docs/scene-format.md, "Poses").

A pose file read with the wrong convention — world-to-camera taken for camera-to-world, or OpenGL camera
axes taken for OpenCV ones — loads without complaint and trains into fog. Neighbouring frames tell: the
same surface seen by two of them must agree with their relative pose.

Pairs of frames that see the same things are found from the images alone (keypoint matches), so that no
reading of the poses is favoured. Then:

* With depth maps, frame ``i``'s depth is lifted to the world and projected into its partner ``j``; the
  depths must agree where ``j`` sees the same surface (median relative difference).
* Without, keypoints matched between ``i`` and ``j`` (ratio test, then a fundamental matrix found by RANSAC
  from the matches alone, so the poses play no part in choosing them) must lie on the epipolar lines the
  poses predict (median Sampson distance in pixels).

The poses are scored as written and after each fix of a likely mistake (:data:`FIXES`); when they fit
badly as written and one fix makes them fit well, :func:`check_pose_convention` names it. Both scores are
blind to a change of the world frame, so these three fixes cover every mix-up of the two conventions (e.g.
world-to-camera in OpenGL axes is undone by inverting: what remains is a rotation of the whole world).

Examples
--------
>>> c2w = np.eye(4)[None].repeat(2, 0); c2w[1, :3, 3] = [1.0, 2.0, 3.0]
>>> w2c = with_fix(c2w, "invert")                       # what a world-to-camera file holds
>>> np.allclose(w2c[1, :3, 3], [-1, -2, -3]), np.allclose(with_fix(w2c, "invert"), c2w)
(True, True)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import cv2
import numpy as np

from lift3d.data.cameras import Cameras
from lift3d.sfm.config import FeatureConfig
from lift3d.sfm.features import detect
from lift3d.sfm.geometry import ideal_pixels, sampson_distance, skew

#: The fixes tried on camera-to-world matrices in OpenCV axes: the pose file held world-to-camera matrices
#: (invert), OpenGL camera axes (flip the camera's y and z), or world-to-camera matrices of OpenGL axes.
FIXES: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "invert": lambda m: np.linalg.inv(m),
    "flip axes": lambda m: m @ np.diag([1.0, -1.0, -1.0, 1.0]),
    "invert and flip axes": lambda m: np.linalg.inv(m) @ np.diag([1.0, -1.0, -1.0, 1.0]),
}
#: What each fix says about the pose file, for messages.
FIX_MEANS = {
    "invert": "the poses look like world-to-camera matrices read as camera-to-world",
    "flip axes": "the poses look like camera axes of the other convention (OpenGL x right, y up, looking down -z "
                 "against OpenCV x right, y down, looking down +z)",
    "invert and flip axes": "the poses look like world-to-camera matrices in the other camera-axes convention",
}
#: Median Sampson distance (pixels, at the image's own size) under which matched keypoints fit the poses.
EPIPOLAR_FIT_PX = 2.0
#: Median relative depth difference under which reprojected depth fits the poses.
DEPTH_FIT = 0.05
#: A fix is named only when the poses fit at least this many times better after it than as written.
CLEARLY_BETTER = 4.0
#: Pairs of overlapping frames checked, among this many frames spread over the capture, each pair with at
#: least this many keypoint matches.
PAIRS = 6
SAMPLED_FRAMES = 12
MIN_MATCHES = 20


def with_fix(c2w_opencv: np.ndarray, fix: str, stored: str = "opencv") -> np.ndarray:
    """``[F, 4, 4]`` camera-to-world matrices (OpenCV axes) after ``fix`` (a key of :data:`FIXES`), applied to the
    matrices as the file stored them: ``stored`` is their camera axes (``opencv``, or ``opengl`` as in
    ``transforms.json``), so that the fix named for a file is the one to apply to that file."""
    apply = FIXES[fix]
    axes = np.diag([1.0, -1.0, -1.0, 1.0]) if stored == "opengl" else np.eye(4)  # OpenCV <-> stored (its own inverse)
    return np.stack([apply(np.asarray(m, np.float64) @ axes) @ axes for m in c2w_opencv])


@dataclass
class PoseCheck:
    """What the check found.

    Attributes
    ----------
    method : str
        ``depth`` (reprojected depth, median relative difference), ``epipolar`` (matched keypoints, median
        Sampson distance in pixels) or ``none`` (too few overlapping pairs or matches to tell).
    as_written : float
        The error of the poses as written (NaN with ``none``).
    fixed : dict
        The error after each of :data:`FIXES`.
    pairs : list of (int, int)
        The frames compared.
    likely_fix : str or None
        The fix that makes the poses fit well and clearly better than as written, when one does.
    """

    method: str
    as_written: float = float("nan")
    fixed: dict[str, float] = field(default_factory=dict)
    pairs: list[tuple[int, int]] = field(default_factory=list)
    likely_fix: str | None = None

    @property
    def fits(self) -> bool:
        """Whether the poses fit the images as written (True when the check could not tell)."""
        if self.method == "none":
            return True
        return self.likely_fix is None and self.as_written <= (DEPTH_FIT if self.method == "depth" else EPIPOLAR_FIT_PX)

    def describe(self) -> str:
        unit = "" if self.method == "depth" else " px"
        what = "median relative depth difference" if self.method == "depth" else "median epipolar distance"
        parts = [f"{k} {v:.3g}{unit}" for k, v in self.fixed.items()]
        return (f"{what} between {len(self.pairs)} pairs of overlapping frames: as written {self.as_written:.3g}"
                f"{unit}; after " + ", ".join(parts))

    def to_json(self) -> dict:
        return {"method": self.method, "as_written": self.as_written, "fixed": self.fixed,
                "pairs": [list(p) for p in self.pairs], "likely_fix": self.likely_fix}


def check_pose_convention(cameras: Cameras, frames: Sequence[int], image: Callable[[int], np.ndarray],
                          depth: Callable[[int], np.ndarray | None] | None = None, stored: str = "opencv"
                          ) -> PoseCheck:
    """Score the poses of ``frames`` as written and after each of :data:`FIXES`.

    Parameters
    ----------
    cameras : Cameras
        The scene's cameras (poses as read).
    frames : sequence of int
        The frames to check (pairs are chosen among up to :data:`SAMPLED_FRAMES` of them).
    image : callable
        ``image(i)`` -> ``uint8 [H, W, 3]``.
    depth : callable, optional
        ``depth(i)`` -> ``float [H, W]`` z-depth (0 = none) or None; used when every compared frame has one.
    stored : {"opencv", "opengl"}
        The camera axes of the matrices as the user wrote them (a converter's source, or ``transforms.json``'s
        OpenGL): the fixes are tried on those, so the one named is the one to apply to that file.

    Returns
    -------
    PoseCheck
    """
    frames = [int(i) for i in frames]
    matches = _overlapping_pairs(frames, image) if len(frames) > 1 else {}
    pairs = list(matches)
    if not pairs:
        return PoseCheck("none")
    variants = {"as written": cameras.c2w_opencv, **{m: with_fix(cameras.c2w_opencv, m, stored) for m in FIXES}}
    depths = {i: depth(i) for i in {f for p in pairs for f in p}} if depth is not None else {}
    if depths and all(d is not None and (d > 0).mean() > 0.2 for d in depths.values()):
        errors = {name: _depth_error(cameras, c2w, pairs, depths) for name, c2w in variants.items()}
        method, good = "depth", DEPTH_FIT
    else:
        errors = {name: _epipolar_error(cameras, c2w, matches) for name, c2w in variants.items()}
        method, good = "epipolar", EPIPOLAR_FIT_PX
    as_written = errors.pop("as written")
    check = PoseCheck(method, as_written, errors, pairs)
    best = min(errors, key=lambda k: errors[k])
    if errors[best] <= good and errors[best] * CLEARLY_BETTER <= as_written:
        check.likely_fix = best
    return check


def _overlapping_pairs(frames: list[int], image: Callable[[int], np.ndarray]
                       ) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """Up to :data:`PAIRS` pairs of frames that see the same things, chosen by the images alone (so no
    reading of the poses is favoured): of :data:`SAMPLED_FRAMES` frames spread over the capture, the pairs
    with the most keypoint matches (ratio test, then the inliers of a fundamental matrix RANSAC finds from
    the matches themselves), at least :data:`MIN_MATCHES` each; with those matches."""
    picked = [frames[k] for k in np.unique(np.linspace(0, len(frames) - 1, min(SAMPLED_FRAMES, len(frames)))
                                           .round().astype(int))]
    feats = {i: detect(image(i), FeatureConfig(max_features=2000)) for i in picked}
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    found = {}
    for a, i in enumerate(picked):
        for j in picked[a + 1:]:
            fi, fj = feats[i], feats[j]
            if len(fi) < 8 or len(fj) < 8:
                continue
            knn = matcher.knnMatch(fi.descriptors, fj.descriptors, k=2)
            good = [m[0] for m in knn if len(m) == 2 and m[0].distance < 0.8 * m[1].distance]
            if len(good) < MIN_MATCHES:
                continue
            pi, pj = fi.uv[[m.queryIdx for m in good]], fj.uv[[m.trainIdx for m in good]]
            _, inliers = cv2.findFundamentalMat(pi, pj, cv2.FM_RANSAC, 1.0, 0.999)
            if inliers is None or inliers.sum() < MIN_MATCHES:
                continue
            keep = inliers.ravel() > 0
            found[(i, j)] = (pi[keep], pj[keep])
    best = sorted(found, key=lambda p: -len(found[p][0]))
    chosen: list[tuple[int, int]] = []
    for pair in best:  # spread the pairs: each frame in at most two
        if sum(f in p for p in chosen for f in pair) < 2:
            chosen.append(pair)
        if len(chosen) == PAIRS:
            break
    return {p: found[p] for p in chosen}


def _depth_error(cameras: Cameras, c2w: np.ndarray, pairs, depths) -> float:
    errors = []
    for i, j in pairs:
        di, dj = depths[i], depths[j]
        h, w = di.shape
        step = max(1, int(np.sqrt(h * w / 20000)))
        vv, uu = np.mgrid[0:h:step, 0:w:step]
        z = di[vv, uu]
        ok = z > 0
        x_cam = np.stack([((uu[ok] + 0.5) - cameras.cx[i]) / cameras.fx[i] * z[ok],
                          ((vv[ok] + 0.5) - cameras.cy[i]) / cameras.fy[i] * z[ok], z[ok]], -1)
        world = x_cam @ c2w[i][:3, :3].T + c2w[i][:3, 3]
        in_j = (world - c2w[j][:3, 3]) @ c2w[j][:3, :3]
        zj = in_j[:, 2]
        front = zj > 1e-6
        u = cameras.fx[j] * in_j[front, 0] / zj[front] + cameras.cx[j]
        v = cameras.fy[j] * in_j[front, 1] / zj[front] + cameras.cy[j]
        hj, wj = dj.shape
        inside = (u >= 0) & (v >= 0) & (u < wj) & (v < hj)
        zz = zj[front][inside]
        seen = dj[v[inside].astype(int), u[inside].astype(int)]
        valid = seen > 0
        # A reading that puts the surface behind j or outside its image agrees nowhere: with under a tenth of
        # the lifted points landing on a depth of j, the pair counts as disagreeing (error 1), so a wrong pose
        # cannot score well on a handful of pixels.
        if valid.sum() < 0.1 * ok.sum():
            errors.append(1.0)
            continue
        rel = np.abs(zz[valid] - seen[valid]) / seen[valid]
        errors.append(float(np.median(np.minimum(rel, 1.0))))
    return float(np.median(errors))


def _epipolar_error(cameras: Cameras, c2w: np.ndarray, matches) -> float:
    distances = []
    for (i, j), (pi, pj) in matches.items():
        r_i, r_j = c2w[i][:3, :3].T, c2w[j][:3, :3].T
        t_i, t_j = -r_i @ c2w[i][:3, 3], -r_j @ c2w[j][:3, 3]
        r_ij = r_j @ r_i.T
        t_ij = t_j - r_ij @ t_i
        n = np.linalg.norm(t_ij)
        if n < 1e-9:
            continue  # no baseline under this reading: the epipolar geometry is undefined
        k_i = np.array([[cameras.fx[i], 0, cameras.cx[i]], [0, cameras.fy[i], cameras.cy[i]], [0, 0, 1]])
        k_j = np.array([[cameras.fx[j], 0, cameras.cx[j]], [0, cameras.fy[j], cameras.cy[j]], [0, 0, 1]])
        f = np.linalg.inv(k_j).T @ skew(t_ij / n) @ r_ij @ np.linalg.inv(k_i)
        # keypoints are in lift3d's pixel coordinates (centre +0.5), the same as cx, cy; undistorted here
        distances.append(sampson_distance(f, ideal_pixels(cameras, i, pi), ideal_pixels(cameras, j, pj)))
    return float(np.median(np.concatenate(distances))) if distances else float("inf")
