"""Keypoints and descriptors with OpenCV (SIFT by default, ORB as an option).

Keypoint positions are returned in lift3d's continuous pixel coordinates: pixel ``(c, r)`` covers
``[c, c+1) x [r, r+1)``, its centre is ``(c + 0.5, r + 0.5)`` (as COLMAP). OpenCV puts pixel centres on
integers, so ``uv = keypoint.pt + 0.5``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from lift3d.sfm.config import FeatureConfig


@dataclass
class Features:
    """Keypoints of one image.

    Attributes
    ----------
    uv : np.ndarray
        ``float64 [N, 2]`` positions in continuous pixel coordinates of the stored image.
    descriptors : np.ndarray
        ``float32 [N, 128]`` unit-norm RootSIFT, or ``uint8 [N, 32]`` ORB.
    rgb : np.ndarray
        ``uint8 [N, 3]`` image colour at each keypoint (nearest pixel; grey repeated for grey images).
    """

    uv: np.ndarray
    descriptors: np.ndarray
    rgb: np.ndarray

    def __len__(self) -> int:
        return len(self.uv)


def _grey(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2:
        return image
    return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)


def detect(image: np.ndarray, config: FeatureConfig, mask: np.ndarray | None = None) -> Features:
    """Detect keypoints and compute descriptors.

    Parameters
    ----------
    image : np.ndarray
        ``uint8 [H, W, 3]`` RGB (or ``[H, W]`` grey).
    config : FeatureConfig
        Detector and its thresholds; images smaller than ``upscale_to`` are enlarged first.
    mask : np.ndarray, optional
        ``bool [H, W]``: detect only where true.

    Returns
    -------
    Features

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> img = (rng.random((64, 64)) * 255).astype(np.uint8)
    >>> f = detect(img, FeatureConfig(upscale_to=128))
    >>> len(f) > 20, f.descriptors.shape[1], bool(f.uv.min() >= 0 and f.uv.max() <= 64)
    (True, 128, True)
    """
    grey = _grey(image)
    colour = image if image.ndim == 3 else np.repeat(image[..., None], 3, axis=2)
    h, w = grey.shape
    scale = 1.0
    if config.upscale_to and min(h, w) < config.upscale_to:
        scale = config.upscale_to / min(h, w)
        grey = cv2.resize(grey, (round(w * scale), round(h * scale)), interpolation=cv2.INTER_CUBIC)
        if mask is not None:
            mask = cv2.resize(mask.astype(np.uint8), grey.shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
    sx, sy = grey.shape[1] / w, grey.shape[0] / h
    cv_mask = None if mask is None else (mask.astype(np.uint8) * 255)
    if config.detector == "orb":
        det = cv2.ORB_create(nfeatures=config.max_features, fastThreshold=config.orb_fast_threshold,
                             edgeThreshold=15, patchSize=15)
    else:
        det = cv2.SIFT_create(nfeatures=config.max_features, contrastThreshold=config.contrast_threshold,
                              edgeThreshold=config.edge_threshold, sigma=config.sigma)
    kps, desc = det.detectAndCompute(grey, cv_mask)
    if desc is None or not kps:
        dim, dt = (32, np.uint8) if config.detector == "orb" else (128, np.float32)
        return Features(np.zeros((0, 2)), np.zeros((0, dim), dt), np.zeros((0, 3), np.uint8))
    pts = np.array([k.pt for k in kps], np.float64)
    # OpenCV's resize maps pixel centres: x_src + 0.5 = (x_dst + 0.5) / s, i.e. continuous coordinates scale.
    uv = (pts + 0.5) / np.array([sx, sy])
    cols = np.clip(uv[:, 0].astype(np.int64), 0, w - 1)
    rows = np.clip(uv[:, 1].astype(np.int64), 0, h - 1)
    rgb = np.asarray(colour[rows, cols], np.uint8).reshape(-1, 3)
    if config.detector == "orb":
        return Features(uv, desc, rgb)
    desc = desc.astype(np.float32)
    # RootSIFT (Arandjelovic & Zisserman 2012): L1-normalise, square root -> Hellinger kernel as a dot product.
    desc /= np.maximum(desc.sum(1, keepdims=True), 1e-12)
    desc = np.sqrt(desc)
    desc /= np.maximum(np.linalg.norm(desc, axis=1, keepdims=True), 1e-12)
    return Features(uv, desc, rgb)
