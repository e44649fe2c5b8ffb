"""Label-model sizes from what the training labels show: instance channels V and the understanding grid's
finest resolution ("model only what the scene requires", docs/presets.md).

Both are read off the *thing segments* of the training pseudo-labels (:class:`ThingSegments`, gathered while
:class:`lift3d.train.data.TrainingData` loads the frames):

- **V**: how many distinct objects the labels show. Per thing class, the most segments of that class one
  frame holds is a lower bound on its objects; summed over the classes the labels use consistently (in at
  least ``max(3, 5 %)`` of the frames, so a class a spurious detection shows once adds nothing), it estimates
  the scene's objects. ``V = headroom × that``, at least one more than the most thing segments in one frame
  (so every frame's segments can take distinct channels), rounded up to a multiple of 8.
- **Label resolution**: how large the small things are. Each segment's size in world units is
  ``√(pixels) × depth / focal`` (depth: the median of the frame's depth map over the segment when there is
  one, else the typical camera distance of the scene); the understanding grid's finest level gets
  ``cells_per_thing`` cells across the 10th percentile of those sizes, capped by a memory budget.

Examples
--------
>>> segs = ThingSegments(frame=np.array([0, 0, 1, 1, 2, 2, 3]), channel=np.array([3, 3, 3, 4, 3, 4, 4]),
...                      pixels=np.array([400, 300, 500, 100, 400, 90, 80]), depth=np.full(7, 2.0),
...                      focal=np.full(7, 100.0))
>>> segs.estimate_objects(n_frames=4)  # channel 3: two in frame 0; channel 4: one per frame
(3, {3: 2, 4: 1})
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Segments smaller than this share of their image do not count for sizes (a few-pixel speck says more
#: about the segmenter's noise than about the objects).
MIN_SEGMENT_SHARE = 1e-3


@dataclass
class ThingSegments:
    """One row per thing segment of the training pseudo-labels.

    Attributes
    ----------
    frame : np.ndarray
        ``[S]`` training-frame slot (0-based).
    channel : np.ndarray
        ``[S]`` semantic channel of the segment.
    pixels : np.ndarray
        ``[S]`` pixel count.
    depth : np.ndarray
        ``[S]`` median depth over the segment (world units), 0 = unknown.
    focal : np.ndarray
        ``[S]`` focal length of the frame (pixels).
    image_pixels : np.ndarray, optional
        ``[S]`` pixels of the segment's image (for :data:`MIN_SEGMENT_SHARE`); default: no filter.
    """

    frame: np.ndarray
    channel: np.ndarray
    pixels: np.ndarray
    depth: np.ndarray
    focal: np.ndarray
    image_pixels: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.frame)

    @classmethod
    def concatenate(cls, parts: list["ThingSegments"]) -> "ThingSegments":
        if not parts:
            z = np.zeros(0)
            return cls(z.astype(np.int64), z.astype(np.int64), z.astype(np.int64), z, z, z.astype(np.int64))
        cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
        return cls(cat("frame"), cat("channel"), cat("pixels"), cat("depth"), cat("focal"), cat("image_pixels"))

    def _kept(self) -> np.ndarray:
        if self.image_pixels is None:
            return np.ones(len(self), bool)
        return self.pixels >= MIN_SEGMENT_SHARE * self.image_pixels

    def max_per_frame(self) -> int:
        """The most thing segments one frame holds."""
        return int(np.bincount(self.frame).max(initial=0)) if len(self) else 0

    def estimate_objects(self, n_frames: int) -> tuple[int, dict[int, int]]:
        """Distinct objects the labels show: Σ over consistently used classes of the most segments of that
        class in one frame. Returns the estimate and the per-channel counts."""
        keep = self._kept()
        frame, channel = self.frame[keep], self.channel[keep]
        min_frames = max(3, math.ceil(0.05 * n_frames))
        per_class: dict[int, int] = {}
        for c in np.unique(channel):
            f = frame[channel == c]
            if len(np.unique(f)) < min_frames:
                continue
            per_class[int(c)] = int(np.bincount(f).max())
        return int(sum(per_class.values())), per_class

    def sizes(self, fallback_depth: float) -> np.ndarray:
        """``[S']`` size of each kept segment in world units (``√pixels · depth / focal``)."""
        keep = self._kept()
        depth = np.where(self.depth[keep] > 0, self.depth[keep], fallback_depth)
        return np.sqrt(self.pixels[keep]) * depth / self.focal[keep]


def round_up(x: float, multiple: int) -> int:
    return int(math.ceil(x / multiple) * multiple)


def instance_capacity(segments: ThingSegments, n_frames: int, headroom: float, cap: int) -> tuple[int, str, dict]:
    """V from the objects the labels show (see the module docstring); returns V, the reason and the numbers."""
    objects, per_class = segments.estimate_objects(n_frames)
    busiest = segments.max_per_frame()
    want = max(headroom * objects, busiest + 1, 1)
    v = int(min(cap, round_up(want, 8)))
    why = (f"{headroom:g} x {objects} objects the labels show (per thing class, the most segments one frame holds; "
           f"classes in >= {max(3, math.ceil(0.05 * n_frames))} frames), at least {busiest} + 1 (the busiest "
           f"frame's thing segments), rounded up to a multiple of 8" + (f", capped at {cap}" if v == cap else ""))
    return v, why, {"objects": objects, "objects_per_channel": per_class, "busiest_frame": busiest}


def label_resolution(segments: ThingSegments, *, scale: float, fallback_depth: float, extent: float,
                     cells_per_thing: float, channels: int, budget_mb: float, minimum: int) -> tuple[int, str, dict]:
    """Finest understanding-grid resolution from the small things' sizes, capped by a memory budget.

    Parameters
    ----------
    scale : float
        Normalised units per world unit.
    fallback_depth : float
        World-unit depth for segments without a depth map.
    extent : float
        Side of the grid in normalised units (2 for the bounded box ``[-1, 1]^3``, 4 contracted).
    cells_per_thing : float
        Grid cells across the small-thing size.
    channels : int
        Features per node of the level (its memory is ``R³ · channels`` float32 parameters).
    budget_mb : float
        Largest parameter memory of the level (MiB); Adam keeps three more copies.
    minimum : int
        Never below this (the coarser levels the preset lists).

    Returns
    -------
    resolution, why, numbers
    """
    budget_res = int((budget_mb * 2**20 / 4 / max(1, channels)) ** (1 / 3))
    sizes = segments.sizes(fallback_depth)
    if len(sizes) == 0:
        return minimum, "no thing segments: the preset's levels", {}
    small = float(np.percentile(sizes, 10))
    want = cells_per_thing * extent / max(small * scale, 1e-9)
    res = int(min(max(round_up(want, 8), minimum), max(budget_res // 8 * 8, minimum)))
    why = (f"{cells_per_thing:g} cells across the small things (10th percentile of thing-segment sizes: "
           f"{small:.3f} world units, sqrt(pixels) x depth / focal) -> {want:.0f}/axis"
           + (f", capped at {res} by the {budget_mb:g} MiB budget" if res < want else ""))
    return res, why, {"small_thing_size": small, "wanted": float(want), "budget_resolution": budget_res}
