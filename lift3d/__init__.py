"""lift3d — lift noisy per-frame 2D panoptic predictions into a 3D-consistent panoptic radiance field.

The public API for downstream tools (docs/api.md, docs/export.md)::

    import lift3d
    run = lift3d.load_run("outputs/room0/fast/2026-11-22_101500", device="cpu")   # a trained run
    q = run.query_points(xyz)                                # labels at world points
    out = run.render(c2w, K, width, height)                  # a view from any pose
    pts = lift3d.load_labelled_points("export/points.ply")   # an export: xyz, rgb, semantic, instance, confidence
    for inst in lift3d.instances("export/instances.json"):    # per-object records
        print(inst.id, inst.class_name, inst.centroid)
"""

from __future__ import annotations

__version__ = "0.1.0"

from lift3d.utils.threads import choose_openmp_waiting as _choose_openmp_waiting

# OpenMP threads that spin briefly, then sleep, while they wait (lift3d/utils/threads.py): as fast as spinning
# alone, a fraction of its cost next to a busy neighbour. Only effective before torch loads; a value the user
# set is kept.
_choose_openmp_waiting()

__all__ = ["__version__", "load_run", "load_labelled_points", "instances"]


def __getattr__(name: str):
    if name in ("load_labelled_points", "instances"):
        from lift3d.export import api  # on first use: keeps `import lift3d` cheap (no torch, no Open3D)

        return getattr(api, name)
    if name == "load_run":
        from lift3d.model.run import load_run  # on first use: keeps `import lift3d` cheap (no torch)

        return load_run
    raise AttributeError(f"module 'lift3d' has no attribute {name!r}")
