"""A simulated 2D panoptic segmenter: ground-truth panoptic maps in, noisy per-frame pseudo-labels out.

Real 2D segmenters (Mask2Former and the like) segment each frame on its own, with their own segment ids, and
make two sorts of mistakes: *independent* ones that change from frame to frame, and *view-correlated* ones
that repeat whenever an object is seen from a similar direction (a cabinet read as a table from one side).
Lifting to 3D averages out the first sort; the second sort is what makes it hard. The simulation does both:

0. **view-correlated confusion** (:class:`ViewConfusers`, optional) — each GT thing, and each of a few patches
   of every stuff surface, has a persistent *confuser* (a plausible wrong class) that wins when the object is
   seen from a range of directions: a cone around an axis. The axis points at one of the cameras that have the
   object in view, and the cone's half-angle is chosen so that it holds a share ``view_share`` of those
   cameras. With probability ``view_confusion`` the confuser is active; an active confuser then wins in a frame
   (with probability ``view_win``) whenever the direction from the object (or patch centre) to the camera lies
   inside the cone — in the same frames every time, whatever the rest of the noise;

then, with every frame's own random stream (independent across frames; rates per preset in
:data:`PRESETS`; ``docs/synth.md`` documents them):

1. **missed instances** — a visible thing is not detected; its pixels become void or are absorbed by the
   surrounding stuff (nearest stuff pixel);
2. **merged instances** — two same-class things that touch in the image become one segment;
3. **split instances** — a thing is cut into two segments by a random straight line;
4. **class confusion** — a segment gets a plausible wrong class (thing→thing and stuff→stuff mostly, taken
   from the scene's confusion table; a small share crosses between things and stuff);
5. **boundary errors** — each segment is dilated or eroded by up to a few pixels (eroded pixels go to the
   neighbouring segments);
6. **abstention** — a void ring along some segment boundaries and a few void blobs;
7. **spurious segments** — small ellipses labelled as a random thing class.

Every output segment gets a ``score``. Segments hit by an error of kind 0, 2-4 or 7, or whose overlap with
their ground truth fell under IoU 0.5, are *corrupted*. With probability ``score_informativeness`` a segment's
score is *informed*: drawn from ``score_corrupt`` if it is corrupted and from ``score_correct`` otherwise;
else it is drawn from the range spanning both, whatever the segment's correctness (0: the scores say nothing
about correctness; 1: they separate correct from corrupted segments as a calibrated segmenter's would).
Ids are random in [1, 65535] per frame.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Callable

import cv2
import numpy as np

from lift3d.data.scene import Category, Segment

#: Largest pseudo-label segment id: 16-bit, so the labels also fit the two-PNG (semantic + instance) layout.
MAX_SEGMENT_ID = 65535


@dataclass(frozen=True)
class NoiseConfig:
    """Rates of the simulated segmenter's errors (see the module docstring and ``docs/synth.md``).

    Pixel sizes are for a 128-pixel image side and scale with ``min(height, width) / 128``.

    Attributes
    ----------
    name : str
        Preset name (``clean``, ``moderate``, ``hard``) or ``custom``.
    p_miss : float
        Probability that a visible thing instance is missed.
    p_miss_void : float
        Share of missed instances whose pixels become void; the rest go to the surrounding stuff.
    p_confuse : float
        Probability that a segment gets a wrong class.
    p_cross_kind : float
        Share of confusions that cross between thing and stuff classes.
    p_merge : float
        Probability that a pair of touching same-class thing segments is merged.
    p_split : float
        Probability that a thing of at least ``min_split_area`` pixels is split in two.
    boundary_px : float
        Largest boundary shift: each segment is dilated or eroded by a radius drawn uniformly from
        ``-boundary_px .. boundary_px``.
    p_boundary_void : float
        Probability that a segment's one-pixel inner boundary ring becomes void (abstention at edges).
    abstain_blobs_per_frame : float
        Mean (Poisson) number of void blobs per frame.
    spurious_per_frame : float
        Mean (Poisson) number of spurious small thing segments per frame.
    min_split_area : int
        Smallest thing (pixels) that may be split.
    score_correct, score_corrupt : tuple of float
        Uniform score ranges of correct and corrupted segments.
    view_confusion : float
        Share of GT things and stuff patches whose view-correlated confuser is active (0 = none).
    view_share : float
        Share of the views of an object (the cameras that have it in view) that lie in its confuser's cone.
    view_win : float
        Probability that an active confuser wins in a frame viewed from inside its cone.
    view_stuff_patches : int
        Patches per stuff class, each with its own confuser.
    score_informativeness : float
        Share of segments whose score depends on their correctness (see the module docstring).
    """

    name: str = "custom"
    p_miss: float = 0.0
    p_miss_void: float = 0.5
    p_confuse: float = 0.0
    p_cross_kind: float = 0.1
    p_merge: float = 0.0
    p_split: float = 0.0
    boundary_px: float = 0.0
    p_boundary_void: float = 0.0
    abstain_blobs_per_frame: float = 0.0
    spurious_per_frame: float = 0.0
    min_split_area: int = 60
    score_correct: tuple[float, float] = (0.7, 1.0)
    score_corrupt: tuple[float, float] = (0.3, 0.8)
    view_confusion: float = 0.0
    view_share: float = 0.4
    view_win: float = 0.9
    view_stuff_patches: int = 4
    score_informativeness: float = 1.0

    def to_json(self) -> dict:
        return asdict(self)

    def problems(self) -> list[tuple[str, str]]:
        """``(field, problem)`` for every value out of its range (empty when the configuration is valid).

        Examples
        --------
        >>> NoiseConfig(p_miss=-0.1, view_share=0).problems()
        [('p_miss', 'must be in [0, 1], got -0.1'), ('view_share', 'must be in (0, 1], got 0')]
        """
        out = []
        for name in ("p_miss", "p_miss_void", "p_confuse", "p_cross_kind", "p_merge", "p_split", "p_boundary_void",
                     "view_confusion", "view_win", "score_informativeness"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 <= v <= 1.0):
                out.append((name, f"must be in [0, 1], got {v!r}"))
        for name in ("boundary_px", "abstain_blobs_per_frame", "spurious_per_frame", "min_split_area",
                     "view_stuff_patches"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 <= v < 1e6):
                out.append((name, f"must be a non-negative number, got {v!r}"))
        if not (isinstance(self.view_share, (int, float)) and 0.0 < self.view_share <= 1.0):
            out.append(("view_share", f"must be in (0, 1], got {self.view_share!r}"))
        for name in ("score_correct", "score_corrupt"):
            lo, hi = getattr(self, name)
            if not 0.0 <= lo <= hi <= 1.0:
                out.append((name, f"must be a range (lo, hi) with 0 <= lo <= hi <= 1, got {(lo, hi)!r}"))
        return out


_MODERATE = NoiseConfig(
    "moderate", p_miss=0.08, p_confuse=0.10, p_merge=0.25, p_split=0.05, boundary_px=1.0,
    p_boundary_void=0.15, abstain_blobs_per_frame=0.4, spurious_per_frame=0.5,
)

#: ``--noise`` presets, from easy to hard. ``moderate`` is meant to resemble a decent off-the-shelf segmenter
#: on unseen data if its errors were independent across views; ``hard`` doubles every rate (and the boundary
#: shift); ``view-correlated`` is ``moderate`` plus persistent view-dependent confusions and scores that say
#: little about correctness (the realistic setting); ``clean`` is the ground truth under per-frame ids.
PRESETS: dict[str, NoiseConfig] = {
    "clean": NoiseConfig("clean", score_correct=(1.0, 1.0)),
    "moderate": _MODERATE,
    "hard": NoiseConfig(
        "hard", p_miss=0.16, p_confuse=0.20, p_merge=0.50, p_split=0.10, boundary_px=2.0,
        p_boundary_void=0.30, abstain_blobs_per_frame=0.8, spurious_per_frame=1.0,
    ),
    "view-correlated": replace(_MODERATE, name="view-correlated", view_confusion=0.4, view_share=0.4,
                               score_informativeness=0.3),
}


def noise_config(noise: str | NoiseConfig) -> NoiseConfig:
    """A preset by name, or ``noise`` itself when it already is a :class:`NoiseConfig`."""
    if isinstance(noise, NoiseConfig):
        return noise
    if noise not in PRESETS:
        raise KeyError(noise)
    return PRESETS[noise]


@dataclass
class SegmenterOutput:
    """One frame's pseudo-labels: COCO panoptic segment ids, the segments' info and what was done."""

    panoptic: np.ndarray  # [H, W] int64 segment ids (0 = void), random per frame
    segments: list[Segment]
    counts: dict[str, float]


@dataclass
class ViewErrors:
    """The view-correlated errors of one frame: GT thing segment id → the class it is read as, and a map of
    stuff pixels read as another class (``[H, W]`` category ids, 0 = unchanged)."""

    things: dict[int, int]
    stuff: np.ndarray | None = None


@dataclass
class Confuser:
    """A persistent, view-dependent class error of one GT thing or one patch of a stuff surface.

    Attributes
    ----------
    segment_id : int
        The GT thing's segment id, or the stuff category id for a patch.
    category : int
        The wrong class that wins.
    centre : np.ndarray
        ``[3]`` the object's centre (its bounding box's) or the patch's centre on the surface.
    axis : np.ndarray
        ``[3]`` unit vector: the confuser wins when the direction from ``centre`` to the camera is within
        ``cone_deg`` of it.
    cone_deg : float
        The cone's half-angle in degrees.
    radius : float
        A patch's radius in metres (``inf`` for a thing: all of it).
    draw : float
        Uniform draw deciding whether the confuser is active (``draw < view_confusion``), so that raising
        ``view_confusion`` only adds confusers.
    """

    segment_id: int
    category: int
    centre: np.ndarray
    axis: np.ndarray
    cone_deg: float
    radius: float
    draw: float

    @property
    def is_thing(self) -> bool:
        return not np.isfinite(self.radius)

    def sees(self, eye: np.ndarray) -> bool:
        """Whether a camera at ``eye`` looks at the object from inside the cone."""
        to_eye = np.asarray(eye, np.float64) - self.centre
        return float(to_eye @ self.axis) >= np.cos(np.radians(self.cone_deg)) * float(np.linalg.norm(to_eye))


class ViewConfusers:
    """The scene's persistent view-correlated errors (error 0 of the module docstring).

    Parameters
    ----------
    confusers : list of Confuser
        Every candidate (active or not: ``config.view_confusion`` decides).
    config : NoiseConfig
        ``view_confusion`` and ``view_win``.
    """

    def __init__(self, confusers: list[Confuser], config: NoiseConfig):
        self.confusers = confusers
        self.config = config
        self.active = [c.draw < config.view_confusion for c in confusers]

    @classmethod
    def build(cls, things: list[tuple[int, int, np.ndarray]], stuff_points: dict[int, np.ndarray],
              in_view: Callable[[np.ndarray], np.ndarray], camera_centres: np.ndarray,
              confusable: dict[int, list[int]], config: NoiseConfig, rng: np.random.Generator,
              patch_radius: tuple[float, float] = (0.3, 0.8)) -> "ViewConfusers":
        """Draw a confuser for every thing and ``config.view_stuff_patches`` per stuff class.

        Parameters
        ----------
        things : list of (segment id, category id, centre [3])
            The GT things.
        stuff_points : dict
            Stuff category id → ``[P, 3]`` points of its surfaces that the cameras see (patch centres are drawn
            among them; the sky has none).
        in_view : callable
            ``[M, 3]`` points → ``[M, N]`` bool: which of the ``N`` cameras have each point in their field of
            view.
        camera_centres : np.ndarray
            ``[N, 3]``.
        confusable : dict
            Category id → plausible wrong category ids (same kind).
        config : NoiseConfig
            ``view_share`` sets the cones; ``view_stuff_patches`` the patches per stuff class.
        rng : np.random.Generator
            The scene's own stream for view errors (the same draws whatever ``view_confusion``).
        patch_radius : (float, float)
            Range of patch radii in metres.
        """
        cand: list[tuple[int, int, np.ndarray, float]] = []  # segment id, wrong class, centre, radius
        for seg, cat, centre in things:
            pool = [c for c in confusable.get(cat, []) if c != cat]
            if pool:
                cand.append((int(seg), int(pool[rng.integers(len(pool))]), np.asarray(centre, np.float64), np.inf))
        for cat in sorted(stuff_points):
            pts = stuff_points[cat]
            pool = [c for c in confusable.get(cat, []) if c != cat]
            if not pool or not len(pts):
                continue
            for _ in range(int(config.view_stuff_patches)):
                cand.append((int(cat), int(pool[rng.integers(len(pool))]), pts[int(rng.integers(len(pts)))],
                             float(rng.uniform(*patch_radius))))
        if not cand:
            return cls([], config)
        seen = in_view(np.stack([c[2] for c in cand]))
        out = []
        for (seg, wrong, centre, radius), cams in zip(cand, seen):
            eyes = camera_centres[cams] if cams.any() else camera_centres
            dirs = eyes - centre
            dirs /= np.maximum(np.linalg.norm(dirs, axis=1, keepdims=True), 1e-9)
            axis = dirs[int(rng.integers(len(dirs)))]
            # The cone holds the share `view_share` of the views, counting from the axis outwards.
            angles = np.degrees(np.arccos(np.clip(dirs @ axis, -1.0, 1.0)))
            cone = float(np.quantile(angles, config.view_share)) + 1e-6 if len(angles) > 1 else 30.0
            out.append(Confuser(seg, wrong, centre, axis, min(cone, 180.0), radius, float(rng.random())))
        return cls(out, config)

    def for_view(self, segment: np.ndarray, category: np.ndarray, xyz: np.ndarray, eye: np.ndarray,
                 rng: np.random.Generator) -> ViewErrors:
        """This frame's view errors.

        Parameters
        ----------
        segment, category : np.ndarray
            ``[H, W]`` GT segment ids and category ids.
        xyz : np.ndarray
            ``[H, W, 3]`` world point each pixel sees (NaN where nothing is hit).
        eye : np.ndarray
            ``[3]`` the camera centre (the true one).
        rng : np.random.Generator
            This frame's stream for view errors (one draw per candidate confuser, active or not).
        """
        wins = rng.random(len(self.confusers)) < self.config.view_win
        things: dict[int, int] = {}
        stuff = None
        present = None
        for c, active, win in zip(self.confusers, self.active, wins):
            if not (active and win and c.sees(eye)):
                continue
            if c.is_thing:
                if present is None:
                    present = set(np.unique(segment).tolist())
                if c.segment_id in present:
                    things[c.segment_id] = c.category
                continue
            on = category == c.segment_id
            if not on.any():
                continue
            hit = np.zeros(on.shape, bool)
            hit[on] = np.sum((xyz[on] - c.centre) ** 2, axis=1) <= c.radius**2
            if hit.any():
                if stuff is None:
                    stuff = np.zeros(segment.shape, np.int64)
                stuff[hit & (stuff == 0)] = c.category
        return ViewErrors(things, stuff)

    def to_json(self) -> dict:
        """Counts and the active confusers (JSON-ready)."""
        return {
            "candidates": len(self.confusers), "active": int(sum(self.active)),
            "confusers": [{"segment_id": c.segment_id, "wrong_category": c.category,
                           "centre": np.round(c.centre, 3).tolist(), "axis": np.round(c.axis, 3).tolist(),
                           "cone_deg": round(c.cone_deg, 2), "radius_m": None if c.is_thing else round(c.radius, 3)}
                          for c, a in zip(self.confusers, self.active) if a],
        }


def _unit_or_up(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-9 else np.array([0.0, 0.0, 1.0])


def _disk(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def _fill_from_nearest(lab: np.ndarray, pending: np.ndarray, seeds: np.ndarray) -> None:
    """Give every ``pending`` pixel the label of the nearest ``seeds`` pixel (void when there are no seeds)."""
    if not pending.any():
        return
    if not seeds.any():
        lab[pending] = 0
        return
    src = np.where(seeds, 0, 255).astype(np.uint8)
    # DIST_LABEL_PIXEL numbers every zero (seed) pixel; each other pixel gets the number of its nearest seed.
    _, nearest = cv2.distanceTransformWithLabels(src, cv2.DIST_L2, 3, labelType=cv2.DIST_LABEL_PIXEL)
    lut = np.zeros(int(nearest.max()) + 1, lab.dtype)
    lut[nearest[seeds]] = lab[seeds]
    lab[pending] = lut[nearest[pending]]


def simulate_segmenter(
    gt_segments: np.ndarray,
    gt_category: dict[int, int],
    categories: list[Category],
    confusable: dict[int, list[int]],
    config: NoiseConfig,
    rng: np.random.Generator,
    view_errors: ViewErrors | None = None,
) -> SegmenterOutput:
    """Corrupt one frame's ground truth the way a 2D panoptic segmenter would.

    Parameters
    ----------
    gt_segments : np.ndarray
        ``[H, W]`` int GT panoptic segment ids (0 = void).
    gt_category : dict
        GT segment id → category id.
    categories : list of Category
        The vocabulary (which classes are things).
    confusable : dict
        Category id → plausible wrong category ids of the same kind.
    config : NoiseConfig
        Error rates.
    rng : np.random.Generator
        This frame's own random stream (independent across frames).
    view_errors : ViewErrors, optional
        This frame's view-correlated errors (:meth:`ViewConfusers.for_view`), applied first.

    Returns
    -------
    SegmenterOutput
    """
    h, w = gt_segments.shape
    scale = min(h, w) / 128.0
    is_thing = {c.id: c.isthing for c in categories}
    thing_cats = [c.id for c in categories if c.isthing]
    stuff_cats = [c.id for c in categories if not c.isthing]

    # Working map of output-segment indices (0 = void); index j starts as GT segment gt_ids[j].
    gt_ids, inverse = np.unique(gt_segments, return_inverse=True)
    lab = inverse.reshape(h, w).astype(np.int32)
    if gt_ids[0] != 0:
        lab += 1
        gt_ids = np.concatenate([[0], gt_ids])
    gt_index = lab.copy()  # GT segment index per pixel, kept for the correctness check at the end
    cat: list[int] = [0] + [int(gt_category[int(g)]) for g in gt_ids[1:]]
    events: list[set[str]] = [set() for _ in cat]
    counts: dict[str, float] = {k: 0 for k in COUNT_KEYS}
    counts["frames"] = 1
    alive = np.bincount(lab.ravel(), minlength=len(cat)) > 0
    alive[0] = False
    counts["gt_segments"] = int(alive.sum())
    counts["gt_things"] = int(sum(alive[j] and is_thing[cat[j]] for j in range(len(cat))))

    def new_segment(category: int, tags: set[str]) -> int:
        cat.append(category)
        events.append(set(tags))
        return len(cat) - 1

    def live(j: int) -> bool:
        return bool(np.any(lab == j))

    # 0. view-correlated confusion: things relabelled whole, stuff in the patch's pixels
    counts["pixels"] = h * w
    if view_errors is not None:
        for j in range(1, len(gt_ids)):
            wrong = view_errors.things.get(int(gt_ids[j]))
            if wrong is not None and alive[j]:
                cat[j] = int(wrong)
                events[j].add("view_confused")
                counts["view_confused_things"] += 1
                counts["view_confused_pixels"] += int(np.sum(lab == j))
        if view_errors.stuff is not None:
            for wrong in np.unique(view_errors.stuff[view_errors.stuff > 0]):
                mask = (view_errors.stuff == wrong) & (lab > 0)
                if mask.any():
                    k = new_segment(int(wrong), {"view_confused"})
                    lab[mask] = k
                    counts["view_confused_patches"] += 1
                    counts["view_confused_pixels"] += int(mask.sum())

    # 1. missed instances
    missed_to_bg = np.zeros((h, w), bool)
    for j in range(1, len(alive)):  # GT segments (view-confused stuff patches are stuff, never missed)
        if alive[j] and is_thing[cat[j]] and rng.random() < config.p_miss:
            mask = lab == j
            counts["missed"] += 1
            if rng.random() < config.p_miss_void:
                lab[mask] = 0
                counts["missed_to_void"] += 1
            else:
                missed_to_bg |= mask
                counts["missed_to_background"] += 1
            events[j].add("missed")
    if missed_to_bg.any():
        stuff_px = np.isin(lab, [j for j in range(1, len(cat)) if not is_thing[cat[j]]]) & ~missed_to_bg
        seeds = stuff_px if stuff_px.any() else (lab > 0) & ~missed_to_bg
        _fill_from_nearest(lab, missed_to_bg, seeds)

    # 2. merged instances: same-class things that touch (within a couple of pixels) in this frame
    touch = _disk(max(1, round(2 * scale)))
    things_now = [j for j in range(1, len(cat)) if is_thing[cat[j]] and live(j)]
    dilated = {j: cv2.dilate((lab == j).astype(np.uint8), touch).astype(bool) for j in things_now}
    pairs = [(a, b) for i, a in enumerate(things_now) for b in things_now[i + 1:]
             if cat[a] == cat[b] and np.any(dilated[a] & (lab == b))]
    counts["merge_candidates"] = len(pairs)
    merged_away: set[int] = set()
    for k in rng.permutation(len(pairs)):
        a, b = pairs[k]
        if a in merged_away or b in merged_away or "merged" in events[a] or "merged" in events[b]:
            continue  # one merge per segment: chains would glue whole rows of cars together
        counts["merge_considered"] += 1
        if rng.random() < config.p_merge:
            lab[lab == b] = a
            events[a].add("merged")
            merged_away.add(b)
            counts["merged"] += 1

    # 3. split instances: a random straight cut through the segment, 30-70 % on either side
    min_area = config.min_split_area * scale * scale
    for j in [j for j in range(1, len(cat)) if is_thing[cat[j]] and j not in merged_away]:
        ys, xs = np.nonzero(lab == j)
        if len(ys) < min_area or "merged" in events[j]:
            continue
        counts["split_eligible"] += 1
        if rng.random() < config.p_split:
            angle = rng.uniform(0, np.pi)
            proj = xs * np.cos(angle) + ys * np.sin(angle)
            cut = np.quantile(proj, rng.uniform(0.3, 0.7))
            side = proj > cut
            k = new_segment(cat[j], {"split"})
            lab[ys[side], xs[side]] = k
            events[j].add("split")
            counts["split"] += 1

    # 4. class confusion, per output segment. A thing is relabelled whole; a stuff segment only in a blob
    #    (an ellipse around one of its pixels, ~20-70 % of it), as segmenters mislabel part of a floor or wall
    #    rather than all of it.
    for j in range(1, len(cat)):
        mask = lab == j
        if not mask.any():
            continue
        counts["confusion_eligible"] += 1
        if rng.random() >= config.p_confuse:
            continue
        cross = rng.random() < config.p_cross_kind
        if cross:
            pool = stuff_cats if is_thing[cat[j]] else thing_cats
        else:
            pool = [c for c in confusable.get(cat[j], []) if c != cat[j]] or \
                   [c for c in (thing_cats if is_thing[cat[j]] else stuff_cats) if c != cat[j]]
        if not pool:
            continue
        wrong = int(pool[rng.integers(len(pool))])
        counts["confused"] += 1
        counts["confused_cross_kind"] += int(cross)
        if is_thing[cat[j]]:
            cat[j] = wrong
            events[j].add("confused")
            continue
        ys, xs = np.nonzero(mask)
        pick = rng.integers(len(ys))
        # Semi-axes scale with the segment but stay under ~a quarter of the image side: a huge road segment
        # should not turn into a rare class's (sidewalk's) largest false positive.
        size = min(np.sqrt(len(ys)), 0.35 * min(h, w))
        blob = _ellipse_at(h, w, (int(xs[pick]), int(ys[pick])), rng.uniform(0.35, 0.8) * size,
                           rng.uniform(0.35, 0.8) * size, rng.uniform(0, 180)) & mask
        k = new_segment(wrong, {"confused"})
        lab[blob] = k

    # 5. boundary errors: dilate or erode every segment by a random radius
    r_max = int(round(config.boundary_px * scale))
    present = [j for j in range(1, len(cat)) if live(j)]
    counts["boundary_eligible"] = len(present)
    if r_max > 0:
        radii = {j: int(rng.integers(-r_max, r_max + 1)) for j in present}
        counts["boundary_shifted"] = sum(r != 0 for r in radii.values())
        order = [present[k] for k in rng.permutation(len(present))]
        for j in order:  # dilations overwrite their neighbours, in random order
            if radii[j] > 0:
                mask = (lab == j).astype(np.uint8)
                grown = cv2.dilate(mask, _disk(radii[j])).astype(bool)
                lab[grown] = j
        for j in order:  # erosions hand the removed ring to the nearest other segment
            if radii[j] < 0:
                mask = lab == j
                if not mask.any():
                    continue
                kept = cv2.erode(mask.astype(np.uint8), _disk(-radii[j])).astype(bool)
                ring = mask & ~kept
                _fill_from_nearest(lab, ring, (lab > 0) & ~mask)

    # 6. abstention: void rings at some boundaries, and void blobs
    ring_w = max(1, int(round(scale)))
    for j in range(1, len(cat)):
        if config.p_boundary_void > 0 and rng.random() < config.p_boundary_void:
            mask = lab == j
            if not mask.any():
                continue
            kept = cv2.erode(mask.astype(np.uint8), _disk(ring_w)).astype(bool)
            lab[mask & ~kept] = 0
            counts["boundary_void"] += 1
    for _ in range(rng.poisson(config.abstain_blobs_per_frame)):
        blob = _ellipse(rng, h, w, 4 * scale, 14 * scale)
        lab[blob] = 0
        counts["abstain_blobs"] += 1

    # 7. spurious small thing segments
    for _ in range(rng.poisson(config.spurious_per_frame)):
        blob = _ellipse(rng, h, w, 3 * scale, 9 * scale)
        if not blob.any() or not thing_cats:
            continue
        k = new_segment(int(thing_cats[rng.integers(len(thing_cats))]), {"spurious"})
        lab[blob] = k
        counts["spurious"] += 1

    # ---- finalise: one segment per stuff class (as a panoptic segmenter outputs), scores, random ids
    first_of_stuff: dict[int, int] = {}
    remap = np.arange(len(cat), dtype=np.int32)
    for j in range(1, len(cat)):
        if not is_thing[cat[j]]:
            keep = first_of_stuff.setdefault(cat[j], j)
            remap[j] = keep
            if keep != j:
                events[keep] |= events[j] - {"missed"}
    lab = remap[lab]
    final = np.nonzero(np.bincount(lab.ravel(), minlength=len(cat)))[0]
    final = final[final > 0]

    # Correctness: the best IoU with a GT segment of the same class must exceed 0.5, and no structural error.
    n_gt = len(gt_ids)
    inter = np.bincount((lab.astype(np.int64) * n_gt + gt_index).ravel(), minlength=len(cat) * n_gt)
    inter = inter.reshape(len(cat), n_gt)
    area_out, area_gt = inter.sum(1), inter.sum(0)
    gt_cat = np.array([0] + [gt_category[int(g)] for g in gt_ids[1:]])
    ids = rng.choice(MAX_SEGMENT_ID, size=len(final), replace=False) + 1
    out = np.zeros(len(cat), np.int64)
    segments: list[Segment] = []
    for j, sid in zip(final, ids):
        same = gt_cat == cat[j]
        same[0] = False
        iou = inter[j] / np.maximum(area_out[j] + area_gt - inter[j], 1)
        best = float(iou[same].max()) if same.any() else 0.0
        corrupted = bool(events[j] & {"confused", "view_confused", "merged", "split", "spurious"}) or best <= 0.5
        s_inf = config.score_informativeness
        informed = s_inf >= 1.0 or (s_inf > 0.0 and rng.random() < s_inf)
        if informed:
            lo, hi = config.score_corrupt if corrupted else config.score_correct
        else:  # a score that says nothing about this segment's correctness
            lo = min(config.score_corrupt[0], config.score_correct[0])
            hi = max(config.score_corrupt[1], config.score_correct[1])
        score = float(rng.uniform(lo, hi)) if hi > lo else float(lo)
        counts["corrupted_segments" if corrupted else "correct_segments"] += 1
        counts["score_sum_corrupt" if corrupted else "score_sum_correct"] += score
        out[j] = int(sid)
        segments.append(Segment(int(sid), int(cat[j]), score))
    counts["output_segments"] = len(segments)
    return SegmenterOutput(out[lab], segments, counts)


def _ellipse(rng: np.random.Generator, h: int, w: int, r_min: float, r_max: float) -> np.ndarray:
    """A filled ellipse at a random place with random semi-axes in [r_min, r_max], as a boolean mask."""
    centre = (int(rng.integers(0, w)), int(rng.integers(0, h)))
    a, b = rng.uniform(r_min, r_max), rng.uniform(r_min, r_max)
    return _ellipse_at(h, w, centre, a, b, rng.uniform(0, 180))


def _ellipse_at(h: int, w: int, centre: tuple[int, int], a: float, b: float, angle: float) -> np.ndarray:
    mask = np.zeros((h, w), np.uint8)
    cv2.ellipse(mask, centre, (max(1, int(round(a))), max(1, int(round(b)))), float(angle), 0, 360, 1, thickness=-1)
    return mask.astype(bool)


#: Counters of :func:`simulate_segmenter`, summed over frames by :class:`NoiseStats`.
COUNT_KEYS = (
    "frames", "gt_segments", "gt_things", "missed", "missed_to_void", "missed_to_background",
    "merge_candidates", "merge_considered", "merged", "split_eligible", "split", "confusion_eligible", "confused",
    "confused_cross_kind", "boundary_eligible", "boundary_shifted", "boundary_void", "abstain_blobs",
    "spurious", "output_segments", "correct_segments", "corrupted_segments", "score_sum_correct",
    "score_sum_corrupt", "view_confused_things", "view_confused_patches", "view_confused_pixels", "pixels",
)


@dataclass
class NoiseStats:
    """Noise statistics summed over frames, plus the pseudo-labels' semantic quality against the GT."""

    categories: list[Category]
    counts: dict[str, float] = field(default_factory=lambda: {k: 0 for k in COUNT_KEYS})
    confusion: np.ndarray | None = None  # [K+1, K+1] GT class (row) × pseudo class (column), 0 = void

    def add(self, counts: dict[str, float], gt_semantic: np.ndarray, pseudo_semantic: np.ndarray) -> None:
        """Add one frame's counters and semantic maps (category ids, 0 = void)."""
        for k, v in counts.items():
            self.counts[k] = self.counts.get(k, 0) + v
        n = max(c.id for c in self.categories) + 1
        if self.confusion is None:
            self.confusion = np.zeros((n, n), np.int64)
        idx = gt_semantic.astype(np.int64).ravel() * n + pseudo_semantic.astype(np.int64).ravel()
        self.confusion += np.bincount(idx, minlength=n * n).reshape(n, n)

    def summary(self) -> dict:
        """Counts, rates per error kind, mean scores and pseudo-label mIoU (JSON-ready, rounded)."""
        c = self.counts

        def rate(num: str, den: str) -> float | None:
            return round(c[num] / c[den], 4) if c.get(den) else None

        frames = max(c["frames"], 1)
        conf = self.confusion if self.confusion is not None else np.zeros((1, 1), np.int64)
        valid = conf[1:]  # GT void pixels are not scored
        n_valid = int(valid.sum())
        iou = class_iou(conf)
        out = {
            "counts": {k: (round(v, 4) if isinstance(v, float) else int(v)) for k, v in c.items()
                       if not k.startswith("score_sum")},
            "rates": {
                "missed": rate("missed", "gt_things"),
                "merged": rate("merged", "merge_considered"),
                "split": rate("split", "split_eligible"),
                "confused": rate("confused", "confusion_eligible"),
                "boundary_shifted": rate("boundary_shifted", "boundary_eligible"),
                "boundary_void": rate("boundary_void", "output_segments"),
                "abstain_blobs_per_frame": round(c["abstain_blobs"] / frames, 4),
                "spurious_per_frame": round(c["spurious"] / frames, 4),
                "corrupted_segments": rate("corrupted_segments", "output_segments"),
                "view_confused_things": rate("view_confused_things", "gt_things"),
                "view_confused_pixels": rate("view_confused_pixels", "pixels"),
            },
            "mean_score": {
                "correct": round(c["score_sum_correct"] / c["correct_segments"], 4) if c["correct_segments"] else None,
                "corrupted": round(c["score_sum_corrupt"] / c["corrupted_segments"], 4)
                if c["corrupted_segments"] else None,
            },
            "pixels": {
                "void_fraction": round(float(valid[:, 0].sum()) / max(n_valid, 1), 4),
                "semantic_accuracy": round(float(np.trace(conf[1:, 1:])) / max(n_valid, 1), 4),
            },
            "semantic_class_iou": {
                c.name: (None if not np.isfinite(iou[c.id - 1]) else round(float(iou[c.id - 1]), 4))
                for c in self.categories if c.id < conf.shape[0]
            },
            "semantic_miou": round(semantic_miou(conf, min_area=0.005), 4),
            "semantic_miou_strict": round(semantic_miou(conf, min_area=0.0), 4),
        }
        return out


def class_iou(confusion: np.ndarray) -> np.ndarray:
    """IoU of classes ``1..K-1`` (``[K-1]``, NaN where a class is in neither GT nor prediction) from a
    ``[K, K]`` GT-row × prediction-column confusion matrix whose index 0 is void (GT-void rows ignored)."""
    valid = confusion[1:].astype(np.float64)
    tp = np.diag(valid[:, 1:])
    union = valid.sum(1) + valid[:, 1:].sum(0) - tp
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, tp / np.maximum(union, 1), np.nan)


def semantic_miou(confusion: np.ndarray, min_area: float = 0.005) -> float:
    """Mean IoU of predicted vs GT classes from a confusion matrix (the mIoU rules of docs/metrics.md).

    Parameters
    ----------
    confusion : np.ndarray
        ``[K, K]`` counts, rows = GT class, columns = predicted class, index 0 = void. GT-void pixels (row 0)
        are ignored; predicting void on a valid pixel counts against the GT class.
    min_area : float
        Classes covering less than this fraction of the valid pixels in both prediction and GT are ignored.

    Examples
    --------
    >>> import numpy as np
    >>> conf = np.array([[0, 0, 0], [0, 3, 1], [0, 1, 3]])
    >>> round(semantic_miou(conf), 4)
    0.6
    """
    valid = confusion[1:].astype(np.float64)  # rows: GT classes 1..K-1
    total = valid.sum()
    if total == 0:
        return float("nan")
    tp = np.diag(valid[:, 1:])
    gt_area = valid.sum(1)
    pred_area = valid[:, 1:].sum(0)
    union = gt_area + pred_area - tp
    keep = (gt_area / total >= min_area) | (pred_area / total >= min_area)
    keep &= union > 0
    if min_area <= 0:
        keep = union > 0
    return float(np.mean(tp[keep] / union[keep])) if keep.any() else float("nan")


def with_rates(config: NoiseConfig, **rates: float) -> NoiseConfig:
    """A copy of ``config`` with some rates replaced (``name`` becomes ``custom``)."""
    return replace(config, name="custom", **rates)
