"""Every knob of the image-geometry pipeline, as typed dataclasses (one section per stage).

The text under each field is its documentation (and the ``--section.field`` flag's help text of
``lift3d triangulate``). Pixel thresholds are in pixels of the images as stored in the scene folder, whatever
``features.upscale_to`` does internally.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lift3d.errors import InputError


@dataclass
class FeatureConfig:
    """Keypoints and descriptors (OpenCV SIFT, or ORB)."""

    detector: str = "sift"
    """'sift' (RootSIFT descriptors, matched by L2) or 'orb' (binary descriptors, matched by Hamming distance)."""
    max_features: int = 4000
    """At most this many keypoints per image (the strongest are kept)."""
    upscale_to: int = 384
    """Images whose shorter side is below this many pixels are enlarged (bicubic) to it before detection: on
    128x128 images SIFT finds about 3x more keypoints, most of them correct (docs/sfm.md); 0 = never."""
    contrast_threshold: float = 0.01
    """SIFT contrast threshold (OpenCV's default 0.04 keeps few keypoints on smooth walls)."""
    edge_threshold: float = 10.0
    """SIFT edge threshold (higher keeps more edge-like keypoints)."""
    sigma: float = 1.6
    """SIFT Gaussian sigma of the first octave."""
    orb_fast_threshold: int = 10
    """ORB: FAST corner threshold (lower finds more corners in weak texture)."""


@dataclass
class PairConfig:
    """Which views are matched with which, from the known poses."""

    neighbors: int = 8
    """Views matched with each view (the k best by overlap); pairs are symmetric."""
    max_view_angle: float = 70.0
    """Degrees: views whose optical axes differ by more are not paired (appearance changes too much)."""
    min_overlap: float = 0.15
    """Fraction of a view's frustum samples (pixels at depths through the scene) the other view sees."""
    min_baseline_angle: float = 1.0
    """Degrees: pairs whose rays meet at a smaller median angle are not paired (depth would be noise)."""


@dataclass
class MatchConfig:
    """Descriptor matching and the epipolar check."""

    ratio: float = 0.8
    """Lowe's ratio test: best distance / second-best distance must be below this."""
    max_epipolar_error: float = 1.5
    """Sampson distance (pixels) to the epipolar geometry of the known poses and intrinsics."""
    guided: bool = True
    """Guided matching: the ratio test runs among the candidates the epipolar geometry allows (more correct
    matches on repetitive or weak texture); false = plain ratio test first, epipolar check after."""
    mutual: bool = True
    """Keep a match only when each keypoint is the other's best candidate."""
    max_distance: float = 0.7
    """Largest descriptor distance of a match, on a [0, 2] scale: L2 between unit RootSIFT descriptors, or
    2 x the fraction of differing ORB bits (a lone candidate on the epipolar line passes any ratio test)."""


@dataclass
class TrackConfig:
    """Tracks, triangulation and the filters on the triangulated points."""

    min_views: int = 3
    """A point must be seen in at least this many views (after outlier observations are removed)."""
    max_reprojection_error: float = 1.5
    """Pixels: observations reprojecting worse are removed; points left with fewer than min_views are
    dropped (reason 'large error')."""
    min_triangulation_angle: float = 2.0
    """Degrees: the widest angle between two observing rays; smaller is dropped ('small angle')."""
    box_margin: float = 0.05
    """Bounded scenes: points farther outside the scene box than this fraction of its size are dropped
    ('outside box'). Unbounded scenes keep points outside their foreground box."""
    refine_iterations: int = 5
    """Gauss-Newton iterations on each point's reprojection error over all its observations."""
    sigma_floor: float = 1.0
    """Pixels: the smallest image noise assumed for a point's uncertainty (its own residuals say less
    when it has few observations)."""


@dataclass
class DenseConfig:
    """Plane-sweep multi-view stereo (``--dense``)."""

    neighbors: int = 6
    """Source views per reference view (the best by overlap, from the same pair selection)."""
    best_k: int = 2
    """Photo-consistency aggregation: mean cost of the best K of the source views (occlusion-robust)."""
    target_angle: float = 10.0
    """Degrees: source views are ranked by overlap and by how close their ray angle is to this (wide angles
    distort the fronto-parallel windows, narrow ones give imprecise depth)."""
    plane_step: float = 1.0
    """Pixels: depth hypotheses are spaced so that the point moves about this much between neighbouring
    planes in the source view that moves most (uniform in inverse depth)."""
    max_planes: int = 128
    """At most this many planes per view and direction."""
    sweep_up: bool = True
    """Also sweep planes perpendicular to the scene's up direction (the cameras' mean image-up axis):
    floors, table tops and ceilings seen at a slant match far better than on fronto-parallel planes (Gallup
    et al., CVPR 2007)."""
    window: int = 7
    """ZNCC window side in pixels (odd)."""
    max_size: int = 256
    """Images whose longer side exceeds this are matched downscaled to it (depth maps are upsampled back)."""
    min_zncc: float = 0.6
    """Winner's aggregated ZNCC must reach this."""
    min_margin: float = 0.02
    """Winner's ZNCC minus the best ZNCC more than two planes away (uniqueness) must reach this."""
    min_texture: float = 1.0
    """Grey-level standard deviation the reference window needs (ZNCC on flat patches is noise)."""
    consistent_views: int = 2
    """Geometric filter: a depth is kept when at least this many source views' depth maps agree with it."""
    fewer_where_fewer_see: bool = True
    """Where fewer source views than ``best_k`` (``consistent_views``) have a point inside their image, as at
    the ends of a capture, the photo-consistency (geometric filter) asks only those that do, and the depth's
    support records it; false: such points get no depth (a shelf only two training views see at the end of a
    walk had none)."""
    consistency_pixels: float = 1.0
    """Geometric filter: reference -> source -> reference reprojection distance in pixels."""
    consistency_depth: float = 0.02
    """Geometric filter: relative depth difference after the round trip."""
    match_sigma: float = 0.5
    """Pixels: assumed precision of a ZNCC match, turned into a depth standard deviation per pixel."""


@dataclass
class SfmConfig:
    """The whole pipeline: sparse triangulation and dense plane sweep."""

    features: FeatureConfig = field(default_factory=FeatureConfig)
    pairs: PairConfig = field(default_factory=PairConfig)
    matching: MatchConfig = field(default_factory=MatchConfig)
    tracks: TrackConfig = field(default_factory=TrackConfig)
    dense: DenseConfig = field(default_factory=DenseConfig)

    def check(self) -> "SfmConfig":
        """Raise :class:`InputError` naming the flag of the first invalid setting; return self."""
        f, p, m, t, d = self.features, self.pairs, self.matching, self.tracks, self.dense
        checks = [
            ("features.detector", f.detector in ("sift", "orb"), "must be 'sift' or 'orb'"),
            ("features.max-features", f.max_features >= 8, "must be >= 8"),
            ("features.upscale-to", f.upscale_to >= 0, "must be >= 0"),
            ("features.contrast-threshold", f.contrast_threshold > 0, "must be positive"),
            ("pairs.neighbors", p.neighbors >= 1, "must be >= 1"),
            ("pairs.max-view-angle", 0 < p.max_view_angle <= 180, "must be in (0, 180]"),
            ("pairs.min-overlap", 0 <= p.min_overlap < 1, "must be in [0, 1)"),
            ("matching.ratio", 0 < m.ratio <= 1, "must be in (0, 1]"),
            ("matching.max-epipolar-error", m.max_epipolar_error > 0, "must be positive"),
            ("matching.max-distance", m.max_distance > 0, "must be positive"),
            ("tracks.min-views", t.min_views >= 2, "must be >= 2"),
            ("tracks.max-reprojection-error", t.max_reprojection_error > 0, "must be positive"),
            ("tracks.min-triangulation-angle", 0 <= t.min_triangulation_angle < 180, "must be in [0, 180)"),
            ("tracks.box-margin", t.box_margin >= 0, "must be >= 0"),
            ("tracks.refine-iterations", t.refine_iterations >= 0, "must be >= 0"),
            ("tracks.sigma-floor", t.sigma_floor > 0, "must be positive"),
            ("dense.neighbors", d.neighbors >= 1, "must be >= 1"),
            ("dense.best-k", 1 <= d.best_k <= d.neighbors, "must be in [1, dense.neighbors]"),
            ("dense.plane-step", d.plane_step > 0, "must be positive"),
            ("dense.max-planes", d.max_planes >= 8, "must be >= 8"),
            ("dense.window", d.window >= 3 and d.window % 2 == 1, "must be an odd number >= 3"),
            ("dense.max-size", d.max_size >= 16, "must be >= 16"),
            ("dense.consistent-views", d.consistent_views >= 0, "must be >= 0"),
            ("dense.match-sigma", d.match_sigma > 0, "must be positive"),
        ]
        for flag, ok, problem in checks:
            if not ok:
                raise InputError(f"--{flag}", problem)
        return self
