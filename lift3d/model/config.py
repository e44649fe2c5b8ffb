"""Typed training configuration: dataclasses whose fields document themselves and become CLI flags.

A run's settings are resolved in this order (later wins)::

    dataclass defaults  <  configs/<preset>.yaml  <  configs/indoor|outdoor.yaml  <  --section.field flags

and then sizes the scene determines (U, V, grid resolution, bounded/unbounded) are filled in where a
field is 0/"auto". The fully resolved configuration is written to the run's ``config.yml``.

Every leaf field is a flag, e.g. ``--optim.steps 2000``, ``--losses.feature 0``; settings of a nested
section have its name too, e.g. ``--field.grid.understanding-resolutions 16 32``. The text under a field is
its ``--help``. Settings written before the field kinds had sections of their own (``field.grid_levels``,
``field.head_hidden_dim``, ...) are read into their new place (:func:`upgrade_config_dict`), so older run
folders and checkpoints keep loading.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import inspect
import textwrap
import typing
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path
from typing import Any, Iterator, Sequence

import yaml

from lift3d.errors import InputError
from lift3d.field.registry import FIELD_KINDS, FieldConfig, upgrade_field_settings
from lift3d.model.loss_terms import LossConfig
from lift3d.render.renderer import SamplingConfig
from lift3d.utils.atomic import write_text_atomic

CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"
PRESETS = ("fast", "balanced", "quality")


@dataclass
class DataConfig:
    """How training rays are drawn from the images."""

    images_per_batch: int = 4
    """Images each step draws its rays from (instance assignment is solved per image)."""
    rays_per_image: int = 256
    """Random rays per image and step (besides the patch)."""
    patch_size: int = 16
    """Side of the square patch per image and step (L_feat and L_seg use patches); 0 = no patches."""
    segments_per_image: int = 0
    """Segment sampler for L_seg (Panoptic Lifting's): 2D segments drawn per image and step, each with
    ``rays_per_segment`` rays inside it, besides the patch and the random rays. Every segment is equally
    likely whatever its size (so small ones get rays), things ``thing_segment_weight`` times as likely.
    0 = off: L_seg then only groups the random rays that happen to share a segment."""
    rays_per_segment: int = 8
    """Rays drawn inside each sampled segment (the L_seg group size)."""
    thing_segment_weight: float = 2.0
    """How much likelier the segment sampler draws a thing segment than a stuff segment."""
    instance_headroom: float = 1.5
    """V = headroom × the objects the labels show (per thing class, the most segments of that class one
    frame holds, summed over the classes), at least the busiest frame's thing segments + 1, rounded up to a
    multiple of 8 (lift3d.train.scene_sizes)."""
    max_instance_channels: int = 128
    """Upper bound on the derived number of instance channels V."""
    profile: str = "auto"
    """Which kind of scene this is, and so which priors may run (docs/presets.md, "Scene profiles"): ``auto``
    decides from what the scene shows (lift3d.train.profile), or one of ``manhattan-room``, ``room``, ``open``,
    ``outdoor``, ``object``. Recorded in config.yml with the evidence (``scene.profile``)."""

    @property
    def rays_per_step(self) -> int:
        """Rays one training step renders: per image the random rays, the segment sampler's and the patch.

        Examples
        --------
        >>> DataConfig(images_per_batch=16, rays_per_image=32, patch_size=8, segments_per_image=4).rays_per_step
        2048
        """
        per_image = self.rays_per_image + self.segments_per_image * self.rays_per_segment + self.patch_size ** 2
        return self.images_per_batch * per_image


@dataclass
class ImageDepthConfig:
    """Depth from the images for training frames without a depth map (docs/sfm.md, "Training with it")."""

    source: str = "auto"
    """``sparse``: triangulated points (the scene's ``sparse_points`` — ``lift3d triangulate``'s or COLMAP's
    kept by ``lift3d convert`` — else triangulated from the training frames at the start, cached in the run
    folder); ``dense``: those and plane-sweep depth maps (the scene's ``mvs_depth_file_path``, else computed
    at the start); ``planes``: the sparse points and, at the pixels the 2D labels give a stuff class, where
    the ray meets the planes fitted to the sparse and plane-sweep points of that class
    (:mod:`lift3d.sfm.planes`); ``none``: colours only; ``auto``: the measured default (``planes`` in a
    bounded scene, ``sparse`` in an unbounded one)."""
    rays_per_image: int = 32
    """Rays per image and step drawn among the pixels that have a depth target (besides the random rays;
    sparse points cover ~1 % of the pixels, so random rays would rarely meet one)."""
    point_share: float = 0.5
    """Share of those rays drawn among a frame's point targets (triangulated points: objects as well as
    stuff), the rest among its dense ones (planes, plane sweep); 0 = uniformly among all its targets, where
    plane targets outnumber points ~10 to 1 and objects got ~2 of 32 rays. On tuning scenes 100 and 102
    (fast): objects found 0.25 -> 0.75 on both, point mIoU +0.03 / +0.01, 3D F-score unchanged
    (0.882 -> 0.888, 0.804 -> 0.801), exported instances 11 -> 14 and 13 -> 17."""
    sigma_scale: float = 1.0
    """Each target's standard deviation is multiplied by this."""
    min_sigma: float = 0.005
    """Smallest standard deviation of a target (normalised units; about 2 cm in an 8 m room)."""
    plane_threshold: float = 0.01
    """``planes``: RANSAC inlier distance, as a fraction of the scene's diagonal."""
    plane_boundary_rows: int = 2
    """``planes``: rows of each class on either side of a label boundary (a wall on the floor, a thing on the
    floor, a ceiling on a wall) for it to count; a one-pixel speck is no boundary."""
    plane_height_percentile: float = 99.0
    """``planes``: how high the stuff points reach above the floor (this percentile of their heights): the top of
    the vertical lines up from a wall's or a thing's foot."""
    plane_directions_agree_deg: float = 1.5
    """``planes``: the room's two wall directions are the vertical planes' mean normal modulo a right angle, taken
    again over the planes within this many degrees of it (a bay wall at 4° pulled a room's mean 0.35° off, 5 cm
    across its 8 m wall)."""
    plane_min_points: int = 8
    """``planes``: fewest points (after thinning) that make a plane."""
    plane_min_share: float = 0.005
    """``planes``: a plane also needs this share of the stuff points (after thinning)."""
    plane_fit_point_share: float = 0.6
    """``planes``, fit-planes: a triangulated point takes the class most of its observations have when at least
    this share of them agree (else it has none: a keypoint on an object's edge that the labels split)."""
    plane_fit_max_planes: int = 24
    """``planes``, fit-planes: most planes the sequential RANSAC finds."""
    plane_fit_iterations: int = 500
    """``planes``, fit-planes: RANSAC draws per plane."""
    plane_fit_candidates: int = 64
    """``planes``, fit-planes: the best RANSAC planes (distinct from each other) scored against the sight lines
    per plane found."""
    plane_fit_max_crossing_share: float = 0.2
    """``planes``, fit-planes: a candidate is dropped when more sight lines cross it inside its points' hull than
    this share of those that end on it (on indoor tuning scenes real walls had up to 0.12, false planes from
    0.23)."""
    plane_fit_max_sightlines: int = 2_000_000
    """``planes``, fit-planes: the free-space test uses at most this many sight lines, an even random draw of
    them (seeded by ``plane_fit_seed``) when there are more. The test compares two counts of sight lines, so a
    draw of two million keeps its share to well under a percent while the fit's time stops growing with the
    frames and pixels (a 160 × 120 capture of 92 views has 1.8 M; 184 views of 640 × 480, 6.3 M). 0 = all."""
    plane_fit_class_share: float = 0.25
    """``planes``, fit-planes: a plane holds every class with at least this share of its inliers."""
    plane_fit_class_cover: float = 0.5
    """``planes``, fit-planes: a plane also holds every class of which it has at least this share of the points
    (and 3): a rug on the floor or a window in a wall has too few points for a quarter of the plane's."""
    plane_fit_seed: int = 0
    """``planes``, fit-planes: seed of RANSAC's draws (the planes are the same for the same seed)."""
    plane_floor_boundary: bool = True
    """``planes``: also fit walls to the points where the 2D labels put a wall on the floor (the ray through
    that boundary meets the floor plane at the wall's foot; the wall rises vertically from there), which needs no
    texture (:func:`lift3d.sfm.planes.floor_boundary_points`)."""
    plane_floor_boundary_step: float = 2.0
    """``planes``, with ``plane_floor_boundary``: spacing of the wall points up each vertical line, in plane
    thresholds."""
    plane_floor_boundary_tolerance: float = 1.0
    """``planes``, with ``plane_floor_boundary``: a wall's foot that one pixel of boundary moves by more than this
    many plane thresholds (a ray grazing the floor far away) is left out."""
    plane_corner_cutters: bool = True
    """``planes``: drop a wall that cuts across the corner of two other walls and is made of their ends' points
    (a stray cluster between them can make it the largest plane; :func:`lift3d.sfm.planes.corner_cutters`)."""
    plane_corner_cutters_near: float = 2.0
    """``planes``, with ``plane_corner_cutters``: a wall's points within this many plane thresholds of another wall
    are at that wall's end; two walls that meet more than this far behind a wall make it a corner cutter."""
    plane_corner_cutters_end_share: float = 0.15
    """``planes``, with ``plane_corner_cutters``: share of a wall's points each of the two other walls must have at
    its ends."""
    plane_corner_cutters_ends_share: float = 0.4
    """``planes``, with ``plane_corner_cutters``: share of a wall's points the two ends must have together."""
    plane_floor_line_walls: bool = True
    """``planes``: walls that no plane has yet, found where the wall-on-floor boundaries of many views agree
    to within ``plane_line_pixels`` rows, in the directions of the walls found and at right angles to them (a
    far plain wall: its feet, each known to half a metre across a room, are too scattered to fit in metres;
    :func:`lift3d.sfm.planes.floor_line_walls`)."""
    plane_floor_line_correct: bool = True
    """``planes``: move a wall found by stereo to where the views' wall-on-floor boundaries put it when they
    clearly disagree (a plain wall fitted to a few points can sit 10–20 cm inside a long room, or turn a few
    degrees; :func:`lift3d.sfm.planes.correct_walls`). Needs ``plane_floor_line_walls``."""
    plane_floor_line_min_views: int = 3
    """``planes``, with ``plane_floor_line_walls``: fewest views whose boundaries support a wall found or moved."""
    plane_floor_line_view_share: float = 0.05
    """``planes``, with ``plane_floor_line_walls``: a view supports a wall when its foot lies within
    ``plane_line_pixels`` rows of the view's boundary in at least this share of the image's columns."""
    plane_floor_line_max_walls: int = 8
    """``planes``, with ``plane_floor_line_walls``: most walls found per direction."""
    plane_floor_line_crossing_share: float = 0.2
    """``planes``, with ``plane_floor_line_walls``: a wall found is added unless sight lines cross it inside its
    points' hull more than this share as often as they end on it (the plane fit's test)."""
    plane_floor_line_class_share: float = 0.25
    """``planes``, with ``plane_floor_line_walls``: a wall found holds the classes of at least this share of its
    points."""
    plane_floor_line_gap: float = 5.0
    """``planes``, with ``plane_floor_line_walls``: a wall found is the most populated stretch of its feet without a
    gap over this many plane thresholds (feet of another wall that line up with it across the room are left
    out)."""
    plane_floor_line_settle: bool = True
    """``planes``, with ``plane_floor_line_walls``: a wall found first moves onto the stereo points in front of its
    stretch (the boundaries put a far wall's foot a row off, which across a room is several centimetres)."""
    plane_floor_line_past_edge: bool = True
    """``planes``, with ``plane_floor_line_walls``: a wall found rises past the top of a view's image while the
    view still labels it wall there (a view looking down at a far wall's foot does not say where the wall
    ends)."""
    plane_floor_line_correct_reach: float = 4.0
    """``planes``, with ``plane_floor_line_correct``: a wall moves at most this many plane thresholds."""
    plane_floor_line_correct_gain: float = 1.5
    """``planes``, with ``plane_floor_line_correct``: a wall moves when the boundaries support it there at least
    this many times as much as where it is."""
    plane_floor_line_correct_crossing_share: float = 1.0
    """``planes``, with ``plane_floor_line_correct``: a wall does not move to where more sight lines cross it than
    this share of those that end on it, and more than cross it where it is (a sofa's base or a window's sill
    can hold the boundary off a wall's foot along a stretch)."""
    plane_square_walls: bool = True
    """``planes``: walls within a few degrees of the room's wall directions (the walls' mean direction modulo a
    right angle) turn onto them about the middle of their points, when their points still fit
    (:func:`lift3d.sfm.planes.square_walls`): stereo turns a plain wall by 1–4° (tuning rooms 5–24), which at
    the end of a 5 m wall is 5–17 cm."""
    plane_square_walls_max_turn_deg: float = 5.0
    """``planes``, with ``plane_square_walls``: walls within this many degrees of one of the room's directions turn
    onto it."""
    plane_square_walls_min_kept: float = 0.9
    """``planes``, with ``plane_square_walls``: a wall turns only while this share of its points near it stay
    within the plane threshold (a wall really at an angle keeps its points only as it is)."""
    plane_line_pixels: float = 1.0
    """``planes``: how many rows a view's wall-on-floor boundary may be off the wall's foot and still count
    for it (``plane_floor_line_walls``)."""
    plane_ceiling_boundary: bool = True
    """``planes``: a stuff class no plane holds (a plain ceiling has next to no points) whose pixels the 2D
    labels put directly above walls gets a level plane where those boundary rays meet the walls' planes, when
    they agree on one height above the cameras (:func:`lift3d.sfm.planes.ceiling_height`)."""
    plane_ceiling_extend: bool = True
    """``planes``: a level plane above the cameras that stereo found for a ceiling class reaches over every pixel
    the 2D labels give that class (stereo matches a textured ceiling in a few spots only)."""
    plane_ceiling_slope: bool = True
    """``planes``, with ``plane_ceiling_boundary``: one tilted plane through the ceiling-on-wall boundary points
    (an attic's or a lean-to's ceiling) when it holds most of them, spans them in two directions, tilts 3–45°, lies
    above every camera (:func:`lift3d.sfm.planes.sloped_ceiling`) and holds 1.1 × as many of them as a level
    height does (or there is none)."""
    plane_ceiling_crossing_share: float = 1.0
    """``planes``, with ``plane_ceiling_boundary``: a level plane over a ceiling class's pixels is not added where
    more sight lines cross it than this share of those that end on it (a window's sill above the eyes: 30 × as
    many crossed as ended; real ceilings 0–0.21)."""
    plane_ceiling_wall_share: float = 0.5
    """``planes``, with ``plane_ceiling_boundary``: a class that at least this share of the walls hold is a wall's
    class, not a ceiling's (a few walls can hold the ceiling class from the points along their top edges)."""
    plane_enclosed: bool = True
    """``planes``: the segments of a stuff class no plane holds (a window whose pattern stereo matched wrongly)
    that one plane surrounds in a view (most of their one-pixel ring meets it) take that plane's depth
    (:func:`lift3d.sfm.planes.enclosed_segments`)."""
    plane_enclosed_margin: bool = True
    """``planes``, with ``plane_enclosed``, where the scene box is the room (premise ``box``: a bounded scene by
    default): an enclosed segment's pixels take the plane's depth within its margin too, not only over the hull of
    its points (a window high on a wall whose points stop below it; outdoors, sky above a building's face must
    not)."""
    plane_enclosed_ring_share: float = 0.6
    """``planes``, with ``plane_enclosed``: share of a segment's one-pixel ring (void left out) that must meet the
    one plane."""
    plane_enclosed_min_ring: int = 8
    """``planes``, with ``plane_enclosed``: fewest pixels of a segment's ring (a smaller segment is noise)."""
    plane_enclosed_max_targeted: float = 0.5
    """``planes``, with ``plane_enclosed_held``: a segment of which more than this share of the pixels already
    have a target is left alone (a floor segment that a wall's plane happens to surround is the floor's)."""
    plane_wall_reach: bool = True
    """``planes``, where the scene box is the room (premises ``room`` and ``box``: a bounded scene by default): a
    wall's plane reaches past its points and margin, inside the scene box, to the pixels of its class, until
    another plane's extent, a sight line through it, or floor a view sees behind its line stops it (a long wall
    that two views see end-on; :func:`lift3d.sfm.planes.wall_reach`)."""
    plane_wall_reach_box_pad: float = 1.0
    """``planes``, with ``plane_wall_reach``: a wall reaches no farther than the scene box grown by this many plane
    thresholds."""
    plane_enclosed_held: bool = True
    """``planes``, with ``plane_enclosed``: classes a plane holds are enclosed too, in the segments whose pixels
    mostly met no plane holding their class (a window in a second wall, when the plane holding the window class
    is the first wall's)."""
    plane_standing: bool = True
    """``planes``: the pixels of a thing the 2D labels put directly on the floor get the depth of an upright face
    rising from where that boundary's ray meets the floor plane, up to the height the other views' labels
    leave it, where three views' feet line up and the plane sweep's depths on the thing do not refute it (a plain
    cabinet has no texture for stereo; :mod:`lift3d.sfm.standing`). On tuning rooms 5–16, 0.89 of its 4 913
    targets were within 1 % of the diagonal; trained on rooms 6 and 7, point mIoU +0.009 / +0.003 (docs/sfm.md)."""
    plane_standing_step: float = 0.5
    """``planes``, with ``plane_standing``: spacing of the points up the vertical line above a thing's foot (how
    finely its top is found), in plane thresholds."""
    plane_standing_tolerance: float = 2.0
    """``planes``, with ``plane_standing``: a foot that one pixel of boundary moves by more than this many plane
    thresholds is left out."""
    plane_standing_min_views: int = 3
    """``planes``, with ``plane_standing``: fewest views whose feet line up to make a face."""
    plane_standing_carve_share: float = 0.25
    """``planes``, with ``plane_standing``: a point of the line above a foot is carved when this share of the views
    that have it in their image (and ``plane_standing_carve_views``) label it a stuff class."""
    plane_standing_carve_views: int = 2
    """``planes``, with ``plane_standing``: fewest views that carve a point of the line above a foot."""
    plane_standing_iterations: int = 300
    """``planes``, with ``plane_standing``: RANSAC draws per face."""
    plane_standing_seed: int = 0
    """``planes``, with ``plane_standing``: seed of those draws."""
    plane_standing_depth_tolerance: float = 1.0
    """``planes``, with ``plane_standing``: a plane-sweep depth agrees with a face within this many plane
    thresholds."""
    plane_standing_agreement: float = 0.65
    """``planes``, with ``plane_standing``: share of the plane-sweep depths a face meets that must agree with it (on
    six tuning rooms, faces whose targets were mostly right agreed with 58–100 % of them, plants, shelves and
    chairs with 0–53 %)."""
    plane_standing_min_refuting: int = 5
    """``planes``, with ``plane_standing``: disagreeing plane-sweep depths a face may always have (a few edge
    depths of a plain box are off)."""
    plane_voxel: float = 0.01
    """``planes``: points are thinned to one per cell of this size (fraction of the diagonal) and class
    before fitting, so densely matched spots do not outvote sparsely matched walls; 0 keeps every point."""
    plane_margin: float = 0.1
    """``planes``: how far a plane reaches beyond the hull of its points, as a fraction of the diagonal."""
    plane_margin_seen_through: bool = True
    """``planes``: a plane's margin does not reach where sight lines to points beyond the plane pass through it
    (:meth:`lift3d.sfm.planes.StuffPlanes.with_seen_through`): the inner wall of an L-shaped room whose other
    inner wall has no plane no longer reaches into the other wing."""
    plane_margin_seen_through_cell: float = 2.0
    """``planes``, with ``plane_margin_seen_through``: size of the cells of a margin that a sight line takes away,
    in plane thresholds."""
    plane_label_support: float = 0.0
    """``planes``: keep a plane target only when at least this share of the other training views that see its
    point (in their image, not behind another plane, label not void) label it a class of its plane: a thing
    that one view's segmenter calls wall otherwise gets the wall's depth (:func:`lift3d.sfm.planes.label_support`;
    0 keeps every target). Off by default: at 0.5, on six images-only tuning rooms the plane targets on things
    fell by 30–55 % and the targets off by > 1 % of the diagonal by 6–43 %, for 1–10 % of the good ones; trained
    on four (`fast`), point mIoU rose by +0.003 to +0.036 but the 3D F-score fell by 0.001–0.013, PQ^scene
    moved −0.057 to +0.022 and no further object was found (docs/sfm.md)."""
    plane_label_support_votes: int = 2
    """``planes``, with ``plane_label_support``: fewest other views whose labels look at a target before they can
    refute it."""
    plane_label_support_tolerance: float = 2.0
    """``planes``, with ``plane_label_support``: another plane a view meets up to this many plane thresholds nearer
    than the target does not hide it from that view."""
    plane_dense_things: bool = True
    """``planes``: also use the plane sweep's depths at the pixels the 2D labels call a thing (the planes
    give stuff only; objects otherwise have the triangulated points alone: a wardrobe was rendered painted on
    the wall behind it). On six tuning rooms the sweep covers 17–31 % of the thing-labelled pixels, 53–89 % of
    them within 1 % of the diagonal (docs/sfm.md)."""
    plane_min_support: int = 2
    """``planes``: plane-sweep depths that fewer source views confirmed (``DenseDepth.support``: at the ends of a
    capture only one other view sees a point) give objects their targets but are not fitted to planes (the plane
    fit is sensitive to its points: on the tuning rooms fitting those too moved the walls' good targets 0.9456 ->
    0.9389 and lost room 12's window plane). 0 fits every depth."""
    plane_fit_max_size: int = 256
    """``planes``: the plane-sweep depths that the planes are fitted to (each one also a sight line of the fit's
    free-space test) are taken on a grid of at most this many pixels along a view's longer side. The sweep
    matches images at ``sfm.dense.max_size`` (256) and upsamples its maps to the image: at 640 × 480 it matched
    256 × 192, so every third pixel of each row and column keeps what it found and the rest add time and memory
    only (184 such views: fitting every pixel took > 10 min and 11 GB). 0 takes every pixel."""
    plane_stride: int = 4
    """``planes``: a target at every ``plane_stride``-th pixel of each row and column (planes cover most of a
    view; denser targets would crowd out the sparse points on objects when target rays are drawn)."""
    plane_sigma_floor: float = 0.5
    """``planes``: a plane or face target's standard deviation is its plane's residual, at least this many plane
    thresholds."""


@dataclass
class OptimConfig:
    """Optimiser and schedule (Adam, exponential decay)."""

    steps: int = 3000
    """Training steps."""
    lr_grid: float = 0.02
    """Learning rate of the voxel grids."""
    lr_mlp: float = 0.002
    """Learning rate of the decoders."""
    lr_final_factor: float = 0.1
    """Learning rates decay exponentially to this fraction at the last step."""
    warmup_steps: int = 50
    """Linear learning-rate warm-up."""
    max_bad_steps: int = 20
    """Consecutive bad steps (non-finite loss, or one above ``divergence_factor`` × the first loss) before
    training stops; a bad step is skipped."""
    divergence_factor: float = 1e3
    """A finite loss above this multiple of the process's first loss counts as a bad step: a learning rate
    that explodes without overflowing otherwise "trains" a collapsed field to the end. 0 disables."""


@dataclass
class TrainerConfig:
    """Run control: devices, logging, evaluation and checkpoints."""

    seed: int = 0
    """Seed of every random number generator."""
    device: str = "auto"
    """``auto`` (CUDA when available), ``cpu`` or ``cuda[:N]``."""
    threads: int = 0
    """CPU threads (0 = every core this process may use)."""
    eval_every: int = 500
    """Steps between evaluations on held-out views (0 = only at the end)."""
    eval_images: int = 4
    """Held-out views rendered per periodic evaluation."""
    checkpoint_every: int = 1000
    """Steps between checkpoints (one is always written at the end)."""
    keep_checkpoints: int = 2
    """Most recent checkpoints kept on disk."""
    log_every: int = 25
    """Steps between log lines in log.jsonl."""
    time_budget: float = 0.0
    """Stop after this many seconds of training (0 = no limit); the benchmark's equal-budget ablation."""
    feature_weights: str = ""
    """Perceptual prior weights (state dict for EfficientNet-Lite0 or a TorchScript module); empty = built-in."""


@dataclass
class Config:
    """Everything a run needs. ``scene`` holds what was derived from the scene (written to config.yml)."""

    preset: str = "fast"
    data: DataConfig = dc_field(default_factory=DataConfig)
    field: FieldConfig = dc_field(default_factory=FieldConfig)
    sampling: SamplingConfig = dc_field(default_factory=SamplingConfig)
    losses: LossConfig = dc_field(default_factory=LossConfig)
    image_depth: ImageDepthConfig = dc_field(default_factory=ImageDepthConfig)
    optim: OptimConfig = dc_field(default_factory=OptimConfig)
    trainer: TrainerConfig = dc_field(default_factory=TrainerConfig)
    scene: dict = dc_field(default_factory=dict)

    def to_dict(self) -> dict:
        return to_dict(self)


SECTIONS = ("data", "field", "sampling", "losses", "image_depth", "optim", "trainer")


# ------------------------------------------------------------------------------------------ dict <-> dataclass
def to_dict(obj: Any) -> Any:
    """A dataclass tree as plain dicts/lists (tuples become lists) for YAML."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_dict(x) for x in obj]
    if isinstance(obj, dict):
        return {k: to_dict(v) for k, v in obj.items()}
    return obj


def _coerce(tp: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            value = [value]
        args = typing.get_args(tp)
        inner = args[0] if args else Any
        return tuple(_coerce(inner, v, where) for v in value)
    if tp is bool:
        if isinstance(value, str):
            if value.lower() in ("1", "true", "yes", "on"):
                return True
            if value.lower() in ("0", "false", "no", "off"):
                return False
            raise InputError(where, f"expected true/false, got {value!r}")
        return bool(value)
    if tp in (int, float, str):
        try:
            if tp is int and isinstance(value, float) and not value.is_integer():
                raise ValueError
            return tp(value)
        except (TypeError, ValueError):
            raise InputError(where, f"expected {tp.__name__}, got {value!r}") from None
    return value


@functools.lru_cache(maxsize=None)
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def update_dataclass(obj: Any, values: dict, where: str) -> Any:
    """Return a copy of dataclass ``obj`` with ``values`` (nested dicts for nested dataclasses) applied.
    Unknown keys are an error naming ``where``."""
    if not isinstance(values, dict):
        raise InputError(where, "expected a mapping")
    names = {f.name for f in dataclasses.fields(obj)}
    hints = _hints(type(obj))
    changes = {}
    for key, val in values.items():
        if key not in names:
            raise InputError(where, f"unknown setting {key!r} (known: {', '.join(sorted(names))})")
        cur = getattr(obj, key)
        if dataclasses.is_dataclass(cur):
            changes[key] = update_dataclass(cur, val, f"{where}:{key}")
        elif hints[key] is dict:
            changes[key] = dict(val or {})
        else:
            changes[key] = _coerce(hints[key], val, f"{where}:{key}")
    return dataclasses.replace(obj, **changes)


def upgrade_config_dict(d: dict) -> dict:
    """A settings mapping (config.yml, a checkpoint's config, a preset) in the current layout: the ``field``
    keys of the old flat layout move into their kind's section (:func:`upgrade_field_settings`)."""
    if isinstance(d, dict) and isinstance(d.get("field"), dict):
        return {**d, "field": upgrade_field_settings(d["field"])}
    return d


def check_config(cfg: Config, where: str) -> Config:
    """Settings their types do not check: ``field.kind`` names a registered kind; fractions lie in [0, 1]."""
    if cfg.field.kind not in FIELD_KINDS:
        raise InputError(where, f"field.kind: unknown field kind {cfg.field.kind!r} (known: {', '.join(FIELD_KINDS)})")
    for name in ("render_label_coverage", "render_color_coverage", "train_label_coverage"):
        coverage = getattr(cfg.sampling, name)
        if not 0.0 <= coverage <= 1.0:
            raise InputError(where, f"sampling.{name}: must be in [0, 1], got {coverage}")
    if not 0.0 <= cfg.field.scene_box_pad < 1.0:
        raise InputError(where, f"field.scene_box_pad: must be in [0, 1), got {cfg.field.scene_box_pad}")
    return cfg


def config_from_dict(d: dict, where: str = "config") -> Config:
    """A :class:`Config` from a (possibly old-layout) mapping such as a run's config.yml."""
    return check_config(update_dataclass(Config(), upgrade_config_dict(d), where), where)


def load_yaml(path: Path) -> dict:
    if not path.is_file():
        raise InputError(path, "file not found")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise InputError(path, f"not valid YAML ({exc})") from exc
    if not isinstance(data, dict):
        raise InputError(path, "must hold a mapping of settings")
    return data


def preset_path(name: str) -> Path:
    """``fast``/``balanced``/``quality``/``indoor``/``outdoor`` → ``configs/<name>.yaml``; a path stays."""
    p = Path(name)
    if p.suffix in (".yaml", ".yml"):
        return p
    path = CONFIG_DIR / f"{name}.yaml"
    if not path.is_file():
        known = sorted(x.stem for x in CONFIG_DIR.glob("*.yaml"))
        raise InputError("--preset", f"unknown preset {name!r} (known: {', '.join(known)})")
    return path


def load_config(preset: str = "fast", kind: str | None = None, overrides: dict | None = None) -> Config:
    """Defaults < preset < indoor/outdoor defaults < overrides.

    Examples
    --------
    >>> cfg = load_config("fast", overrides={"optim": {"steps": 10}})
    >>> cfg.optim.steps, cfg.preset
    (10, 'fast')
    """
    cfg = Config(preset=Path(preset).stem)
    path = preset_path(preset)
    cfg = update_dataclass(cfg, upgrade_config_dict(load_yaml(path)), str(path))
    if kind:
        kpath = preset_path(kind)
        cfg = update_dataclass(cfg, upgrade_config_dict(load_yaml(kpath)), str(kpath))
    if overrides:
        # old flat flags (--field.grid-resolution-cap) still work, as old config.yml files do
        cfg = update_dataclass(cfg, upgrade_config_dict(overrides), "command line")
    kind_from_flags = bool(overrides) and "kind" in (overrides.get("field") or {})
    return check_config(cfg, "command line" if kind_from_flags else str(path))


def save_config(cfg: Config, path: Path) -> None:
    write_text_atomic(path, yaml.safe_dump(cfg.to_dict(), sort_keys=False))


# ------------------------------------------------------------------------------------------ CLI flags
@functools.lru_cache(maxsize=None)
def field_docs(cls: type) -> dict[str, str]:
    """The string literal under each dataclass field (its documentation), read from the source."""
    try:
        src = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    body = ast.parse(src).body[0].body  # type: ignore[attr-defined]
    docs: dict[str, str] = {}
    for prev, node in zip(body, body[1:]):
        if (isinstance(prev, ast.AnnAssign) and isinstance(prev.target, ast.Name)
                and isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)
                and isinstance(node.value.value, str)):
            docs[prev.target.id] = " ".join(node.value.value.split())
    return docs


#: The scene kinds whose defaults (configs/<kind>.yaml) training applies after the preset, and when.
SCENE_KINDS = {"indoor": "bounded", "outdoor": "unbounded"}


def _leaves(obj: Any, path: str) -> Iterator[tuple[str, Any]]:
    """``(dotted path, value)`` of every leaf setting of a configuration section."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            yield from _leaves(value, f"{path}.{f.name}")
        else:
            yield f"{path}.{f.name}", value


def _by_preset(values: dict[str, Any], fallback: Any) -> str:
    """``values`` (preset name → value) and the value of a preset file that leaves the setting out, in words.

    >>> _by_preset({"fast": 1, "balanced": 2, "quality": 2}, 3)
    '1 in fast, 2 in balanced and quality, else 3'
    >>> _by_preset({"fast": 0.1, "balanced": 0.1}, 0.0), _by_preset({"fast": 5}, 5)
    ('0.1 in every preset, else 0.0', '5')
    """
    distinct = list(dict.fromkeys(values.values()))
    if distinct == [fallback]:
        return repr(fallback)
    if len(distinct) == 1:
        text = f"{distinct[0]!r} in every preset"
    else:
        text = ", ".join(f"{v!r} in " + " and ".join(n for n, x in values.items() if x == v) for v in distinct)
    return f"{text}, else {fallback!r}"


def preset_defaults(sections: Sequence[str] = SECTIONS) -> dict[str, str]:
    """What each run setting really defaults to, in words, for the ``--help`` of ``lift3d train``.

    A run's value comes from the dataclass default, then the preset (:data:`PRESETS` or a YAML file), then
    the scene kind's defaults (:data:`SCENE_KINDS`), so the dataclass default alone misstates every setting
    a preset or a kind file sets. The text is built from the files themselves.

    Returns
    -------
    dict
        Dotted setting path (``losses.image_depth``) → e.g. ``0.1 in every preset, else 0.0``, or
        ``0.02 for bounded, 0.05 for unbounded scenes``. Settings nothing overrides map to ``repr`` of their
        default.

    Examples
    --------
    >>> text = preset_defaults()
    >>> text["losses.image_depth"], text["optim.steps"]
    ('0.1 in every preset, else 0.0', '1500 in fast, 5000 in balanced, 10000 in quality, else 3000')
    >>> text["sampling.near_plane"], text["trainer.seed"]
    ('0.02 for bounded, 0.05 for unbounded scenes', '0')
    """
    def values(cfg: Config) -> dict[str, Any]:
        return {key: value for section in sections for key, value in _leaves(getattr(cfg, section), section)}

    # A --preset YAML of the user's that does not set a field leaves the dataclass default to the kind file.
    fallback = {kind: values(update_dataclass(Config(), upgrade_config_dict(load_yaml(preset_path(kind))), kind))
                for kind in SCENE_KINDS}
    by_kind = {kind: {p: values(load_config(p, kind)) for p in PRESETS} for kind in SCENE_KINDS}
    text = {}
    for key in values(Config()):
        per_kind = {kind: _by_preset({p: by_kind[kind][p][key] for p in PRESETS}, fallback[kind][key])
                    for kind in SCENE_KINDS}
        if len(set(per_kind.values())) == 1:
            text[key] = next(iter(per_kind.values()))
        else:
            text[key] = ", ".join(f"{t} for {SCENE_KINDS[kind]}" for kind, t in per_kind.items()) + " scenes"
    return text


def add_config_flags(parser: argparse.ArgumentParser, root: Any = None, sections: Sequence[str] = SECTIONS) -> None:
    """One flag per leaf setting: ``--<section>.<field-name>``, and ``--<section>.<sub>.<field-name>`` in a
    nested section such as ``field.grid`` (dest ``cfg:<dotted path>``); one argument group per section.

    ``root`` is the configuration tree whose ``sections`` become flags (default: the run configuration, whose
    help gives the presets' and scene kinds' values, :func:`preset_defaults`; ``lift3d triangulate`` passes
    its :class:`~lift3d.sfm.config.SfmConfig`, whose help gives the dataclass defaults)."""
    defaults = Config() if root is None else root
    default_text = preset_defaults(sections) if root is None else {}
    for section in sections:
        _add_section_flags(parser, section, getattr(defaults, section), default_text)


def _add_section_flags(parser: argparse.ArgumentParser, path: str, obj: Any, default_text: dict[str, str]) -> None:
    docs = field_docs(type(obj))
    hints = _hints(type(obj))
    group = parser.add_argument_group(f"{path} settings", (type(obj).__doc__ or "").strip().split("\n")[0])
    nested = []
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            nested.append((f"{path}.{f.name}", value))
            continue
        tp = hints[f.name]
        flag = f"--{path}.{f.name.replace('_', '-')}"
        default = default_text.get(f"{path}.{f.name}", repr(value))
        kwargs: dict[str, Any] = dict(dest=f"cfg:{path}.{f.name}", default=argparse.SUPPRESS,
                                      help=f"{docs.get(f.name, '')} (default: {default})".replace("%", "%%"))
        if typing.get_origin(tp) in (tuple, list):
            kwargs.update(nargs="*", metavar="V")
        elif tp is bool:
            kwargs.update(metavar="{true,false}")
        else:
            kwargs.update(metavar=tp.__name__.upper() if isinstance(tp, type) else "V")
        group.add_argument(flag, **kwargs)
    for sub_path, sub in nested:
        _add_section_flags(parser, sub_path, sub, default_text)


def overrides_from_args(args: argparse.Namespace) -> dict:
    """Collect the ``--section[.sub].field`` flags the user gave into a nested dict.

    Examples
    --------
    >>> overrides_from_args(argparse.Namespace(**{"cfg:optim.steps": 5, "cfg:field.grid.levels": 2, "quiet": True}))
    {'optim': {'steps': 5}, 'field': {'grid': {'levels': 2}}}
    """
    out: dict[str, dict] = {}
    for key, val in vars(args).items():
        if key.startswith("cfg:"):
            *sections, name = key[4:].split(".")
            node = out
            for section in sections:
                node = node.setdefault(section, {})
            node[name] = val
    return out
