"""Sensor models of ``lift3d synth``: a structured-light depth camera and noisy camera poses.

Depth (``--depth sensor``, :class:`DepthSensor`): from the exact z-depth ``z`` (metres) of every pixel,

* Gaussian noise of standard deviation ``sigma(z) = 1.2 mm + 1.9 mm * (z - 0.4 m)^2`` (a structured-light
  sensor's axial noise; independent per pixel);
* holes along depth discontinuities: pixels on the *far* side of a jump of more than 5 % of the depth,
  within one pixel (at a 128-pixel image side; scaled with the image) of the nearer surface, are dropped
  with probability 0.8 (in smaller images, where that pixel is wider than the band, proportionally less) —
  the band the projector cannot light or the matcher cannot resolve;
* 2-4 % of the pixels dropped at random in blobs (dark or shiny surfaces), a fresh share per frame;
* no depth beyond ``max_range`` (10 m);
* quantisation to 1 mm (and then to the scene's depth unit, centimetres outdoors, when written).

Poses (``--pose-noise DEG CM``, :func:`perturb_poses`): each written camera is rotated in its own frame by a
random rotation vector with independent ``N(0, (DEG/sqrt 3)^2)`` components (so the RMS angle is DEG
degrees) and moved by a vector with independent ``N(0, (CM/sqrt 3)^2)`` components (RMS CM centimetres).
Rendering uses the true poses, which the scene keeps as ``gt_transform_matrix``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

#: ``--depth`` choices.
DEPTH_MODES = ("sensor", "exact", "none")


@dataclass(frozen=True)
class DepthSensor:
    """A structured-light depth sensor (see the module docstring). Lengths in metres.

    Attributes
    ----------
    sigma_0, sigma_2, z_0 : float
        Noise ``sigma(z) = sigma_0 + sigma_2 * (z - z_0)^2``.
    edge_jump : float
        Relative depth jump between 4-neighbours that counts as a discontinuity.
    edge_band_px : float
        Width of the hole band on the far side of a discontinuity, in pixels at a 128-pixel image side.
    p_edge_hole : float
        Share of the band's pixels that are holes.
    random_holes : tuple of float
        Range of the share of pixels dropped at random (in blobs), drawn per frame.
    max_range : float
        Farthest measured depth.
    quantum : float
        Quantisation step.
    """

    sigma_0: float = 0.0012
    sigma_2: float = 0.0019
    z_0: float = 0.4
    edge_jump: float = 0.05
    edge_band_px: float = 1.0
    p_edge_hole: float = 0.8
    random_holes: tuple[float, float] = (0.02, 0.04)
    max_range: float = 10.0
    quantum: float = 0.001

    def sigma(self, z: np.ndarray) -> np.ndarray:
        """Noise standard deviation (metres) at depth ``z`` (metres).

        Examples
        --------
        >>> DepthSensor().sigma(np.array([0.4, 2.4])).round(4).tolist()
        [0.0012, 0.0088]
        """
        return self.sigma_0 + self.sigma_2 * (np.asarray(z, np.float64) - self.z_0) ** 2

    def to_json(self) -> dict:
        return asdict(self)

    def edges(self, depth: np.ndarray) -> np.ndarray:
        """``bool [H, W]``: the band of pixels on the far side of a depth discontinuity (see the class)."""
        h, w = depth.shape
        valid = depth > 0
        z = np.where(valid, depth, np.inf)
        r = max(1, int(round(self.edge_band_px * min(h, w) / 128.0)))
        # Nearest depth within r pixels (a min filter); no depth never counts as nearer.
        k = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * r + 1, 2 * r + 1))
        near = cv2.erode(np.where(valid, depth, 1e9).astype(np.float32), k).astype(np.float64)
        return valid & (z > near * (1.0 + self.edge_jump))

    def apply(self, depth: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
        """Sensor depth ``[H, W]`` (0 = hole) from exact z-depth ``depth`` ``[H, W]`` (0 = nothing hit), and
        the shares of pixels dropped by each cause."""
        depth = np.asarray(depth, np.float64)
        h, w = depth.shape
        valid = depth > 0
        n_valid = max(int(valid.sum()), 1)
        # Below 128 pixels the one-pixel band is wider than the sensor's: drop a proportional share of it.
        p_edge = self.p_edge_hole * min(1.0, self.edge_band_px * min(h, w) / 128.0)
        edge = self.edges(depth) & (rng.random((h, w)) < p_edge)
        share = rng.uniform(*self.random_holes)
        # Blobs: a smooth random field (cubic upsampling of a coarse one) cut at its (1 - share) quantile.
        coarse = rng.random((h // 6 + 2, w // 6 + 2)).astype(np.float32)
        field = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC)
        blobs = field > np.quantile(field, 1.0 - share)
        far = depth > self.max_range
        noisy = depth + rng.normal(size=(h, w)) * self.sigma(depth)
        noisy = np.round(noisy / self.quantum) * self.quantum
        holes = edge | blobs | far | (noisy <= 0)
        out = np.where(valid & ~holes, noisy, 0.0)
        stats = {name: float((mask & valid).sum()) / n_valid
                 for name, mask in (("edge_holes", edge), ("random_holes", blobs), ("out_of_range", far), ("holes", holes))}
        return out, stats


def perturb_poses(c2w: np.ndarray, deg: float, cm: float, rng: np.random.Generator) -> np.ndarray:
    """Noisy copies of camera-to-world matrices ``[N, 4, 4]``: RMS rotation ``deg`` degrees (about a random
    axis, in the camera's frame) and RMS translation ``cm`` centimetres (see the module docstring).

    Examples
    --------
    >>> c2w = np.repeat(np.eye(4)[None], 2000, axis=0)
    >>> noisy = perturb_poses(c2w, 1.0, 5.0, np.random.default_rng(0))
    >>> round(float(np.sqrt(np.mean(np.sum(noisy[:, :3, 3] ** 2, axis=1)))), 2)  # RMS metres
    0.05
    """
    n = len(c2w)
    rotvec = rng.normal(0.0, np.radians(deg) / np.sqrt(3), (n, 3))
    shift = rng.normal(0.0, cm / 100.0 / np.sqrt(3), (n, 3))
    out = np.array(c2w, np.float64, copy=True)
    out[:, :3, :3] = out[:, :3, :3] @ Rotation.from_rotvec(rotvec).as_matrix()
    out[:, :3, 3] += shift
    return out


def pose_error(true_c2w: np.ndarray, noisy_c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-camera rotation error (degrees) and translation error (metres) between two ``[N, 4, 4]`` stacks."""
    rel = np.einsum("nji,njk->nik", true_c2w[:, :3, :3], noisy_c2w[:, :3, :3])
    angle = np.degrees(Rotation.from_matrix(rel).magnitude())
    return angle, np.linalg.norm(noisy_c2w[:, :3, 3] - true_c2w[:, :3, 3], axis=1)
