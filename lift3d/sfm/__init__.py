"""Geometry from the images themselves, with the poses known: sparse triangulation and dense plane sweep.

Pure numpy / OpenCV / scipy (no torch). The one-call API::

    from lift3d.data.scene import load_scene
    from lift3d.sfm import SfmConfig, triangulate_scene, plane_sweep_scene

    scene = load_scene("scenes/room")
    sparse = triangulate_scene(scene)                  # SparsePoints: xyz, observations (uv, depth, sigma)
    dense = plane_sweep_scene(scene, sparse=sparse)    # DenseDepth: per-frame depth + sigma maps

``lift3d triangulate`` runs both and stores the result in the scene folder (docs/sfm.md,
docs/scene-format.md).
"""

from lift3d.data.stereo import DenseDepth, SparsePoints
from lift3d.sfm.config import DenseConfig, FeatureConfig, MatchConfig, PairConfig, SfmConfig, TrackConfig
from lift3d.sfm.mvs import plane_sweep_scene
from lift3d.sfm.sparse import triangulate_scene

__all__ = ["SfmConfig", "FeatureConfig", "PairConfig", "MatchConfig", "TrackConfig", "DenseConfig",
           "SparsePoints", "DenseDepth", "triangulate_scene", "plane_sweep_scene"]
