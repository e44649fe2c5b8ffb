"""lift3d — lift noisy per-frame 2D panoptic predictions into a 3D-consistent panoptic radiance field.

The public API for downstream tools::

    import lift3d
    pts = lift3d.load_labelled_points("export/points.ply")   # xyz, rgb, semantic, instance, confidence
    for inst in lift3d.instances("export/instances.json"):    # per-object records
        print(inst.id, inst.class_name, inst.centroid)
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__", "load_labelled_points", "instances"]


def __getattr__(name: str):
    if name in ("load_labelled_points", "instances"):
        from lift3d.export import api  # on first use: keeps `import lift3d` cheap (no torch, no Open3D)

        return getattr(api, name)
    raise AttributeError(f"module 'lift3d' has no attribute {name!r}")
