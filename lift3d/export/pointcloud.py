"""Labelled point clouds from a trained panoptic field (``lift3d export --pointcloud``).

:func:`extract_labelled_points` draws points from one of three sources (:mod:`lift3d.export.sources`: ``surface``,
the seen density isosurface; ``tsdf``, the fused rendered depth; ``rays``, back-projected rendered depth), then
runs the point steps (:mod:`lift3d.export.steps`) on them in order, each where the scene shows the premises it
needs (:func:`lift3d.export.steps.premises.run_premises`):

box-fill → thing-fill (``surface`` source: the rendered surface where the isosurface has holes) → heads (the
field's semantic and instance heads run *at the points*, once per point in chunks; no rays are rendered for them)
→ confidence-filter → frame-conversion → crop (``obb``) → outlier-removal (Open3D) → voxel-downsample (majority
labels) → link-radius → view-vote (the training views' 2D labels) → stuff-orientation → stuff-corners → instances
(:func:`lift3d.export.instances.assign_instances`) → filled-join → instance-cleanup (:mod:`lift3d.export.cleanup`).

``num_points`` is the number of points the source draws, before the steps. Each step's record (what it did, or why
it did not run) is in the result's ``steps`` and ``metadata.json``.

Examples
--------
>>> [s.name for s in PointSettings.from_options(voxel_size=0.05).steps if s.name.startswith("voxel")]
['voxel-downsample']
>>> PointSettings.from_options(voxel_size=0.05, frame="normalized").frame
'normalized'
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lift3d.data.ply import write_labelled_ply
from lift3d.data.scene import Scene
from lift3d.export.frames import world_from_normalized
from lift3d.export.points import LabelledPoints, OrientedBox, default_crumb_points, typical_spacing
from lift3d.export.sources import SOURCES, SourceSettings, draw_points, resolve_point_source
from lift3d.export.steps import ExportStep, PointState, StepContext, run_point_steps, step_records
from lift3d.export.steps.instances import MIN_INSTANCE_CONFIDENCE, MIN_SUPPORT_VIEWS
from lift3d.export.steps.options import configure_steps
from lift3d.export.steps.premises import run_premises
from lift3d.model.profiles import premises_of
from lift3d.model.run import LoadedRun, load_run
from lift3d.utils.device import resolve_device
from lift3d.utils.memory import peak_rss_mb

__all__ = ["extract_labelled_points", "PointSettings", "LabelledPoints", "OrientedBox", "SOURCES",
           "resolve_point_source", "benchmark_export", "typical_spacing", "default_crumb_points",
           "MIN_INSTANCE_CONFIDENCE", "MIN_SUPPORT_VIEWS"]


@dataclass
class PointSettings:
    """Everything that decides a point cloud: how the points are drawn, the steps (in order, each with its
    settings) and the profile whose premises they may rely on (``auto``: the run's)."""

    source: SourceSettings = field(default_factory=SourceSettings)
    steps: list[ExportStep] = field(default_factory=configure_steps)
    profile: str = "auto"

    @classmethod
    def from_options(cls, profile: str = "auto", steps: list[ExportStep] | None = None,
                     **options: Any) -> "PointSettings":
        """From keywords: :class:`~lift3d.export.sources.SourceSettings`' fields (``source``, ``num_points``,
        ``density_threshold``, ``refine_surface``) and the steps' settings by their Python keywords
        (:func:`lift3d.export.steps.options.configure_steps`: ``voxel_size``, ``obb``, ``complete_corners`` ...)."""
        names = {f.name for f in dataclasses.fields(SourceSettings)}
        source = SourceSettings(**{k: options.pop(k) for k in list(options) if k in names})
        return cls(source, configure_steps(None, steps, **options), profile)

    def step(self, name: str) -> ExportStep:
        """The step called ``name``."""
        return next(s for s in self.steps if s.name == name)

    @property
    def frame(self) -> str:
        """The output frame (``frame-conversion``'s)."""
        return self.step("frame-conversion").frame

    def check(self) -> None:
        """An :class:`~lift3d.errors.InputError` naming the flag of a setting out of range."""
        self.source.check()
        if self.profile != "auto":
            premises_of(self.profile)
        for step in self.steps:
            if not step.enabled and not step.switchable:
                raise ValueError(f"the {step.name} step cannot be turned off (the steps after it build on it)")
            step.check()


def extract_labelled_points(loaded: LoadedRun, scene: Scene, settings: PointSettings | None = None, *,
                            view_depth_cache: dict | None = None, device=None, progress: bool = False,
                            **options: Any) -> LabelledPoints:
    """A labelled point cloud of a trained run: the source's points, then the steps (module docstring).

    Parameters
    ----------
    loaded : LoadedRun
        From :func:`lift3d.model.run.load_run`.
    scene : Scene
        The run's scene (``loaded.scene()``): training cameras decide visibility and ray origins.
    settings : PointSettings, optional
        The source, the steps and the profile; default from ``options``.
    view_depth_cache : dict, optional
        The renders of the training views without a depth map (fills and vote) are kept in it and reused
        (:func:`lift3d.export.views.rendered_depth`): pass the same dict to
        :func:`lift3d.export.mesh.extract_labelled_mesh` of the same run and scene.
    device : str, optional
        Move the model to this device first (``cpu``, ``cuda``, ``auto``).
    progress : bool
    **options
        Instead of ``settings``: :meth:`PointSettings.from_options` keywords, e.g. ``source="tsdf"``,
        ``num_points=200_000``, ``frame="normalized"``, ``voxel_size=0.05``, ``obb=OrientedBox(...)``,
        ``min_points=200``, ``complete_corners=False``, ``profile="room"``.

    Returns
    -------
    LabelledPoints
        ``steps`` has each step's record; ``stats["premises"]`` the premises the steps could rely on and why.
    """
    if settings is None:
        settings = PointSettings.from_options(**options)
    elif options:
        raise TypeError(f"extract_labelled_points: give settings or keyword options, not both ({', '.join(options)})")
    settings.check()
    source, source_rule = resolve_point_source(settings.source.source, loaded, scene)
    if device is not None:
        loaded.model.to(resolve_device(device))
    premises, premises_why = run_premises(loaded, settings.profile)
    timings: dict[str, float] = {}
    start = time.perf_counter()
    drawn = draw_points(loaded, scene, settings.source, source, progress, timings)
    thresholds = dict(drawn.thresholds)
    if settings.source.source == "auto":
        thresholds["source"] = {"source": source, "rule": source_rule}
    transform = world_from_normalized(loaded.norm)
    state = PointState(dataclasses.replace(drawn.points, transform=transform, thresholds=thresholds))
    context = StepContext(loaded, scene, source, drawn.grid_link, drawn.cameras,
                          {} if view_depth_cache is None else view_depth_cache, progress)
    records = run_point_steps(settings.steps, state, context, premises)
    timings.update({r.name: r.seconds for r in records if r.ran})
    p = state.points
    instance = p.instance if p.instance is not None else np.zeros(len(p), np.int32)
    stats = {"source": source, "drawn": len(drawn.points), "points": len(p),
             "premises": {"shown": sorted(premises), "why": premises_why}, "seconds": timings,
             "total_seconds": time.perf_counter() - start}
    return LabelledPoints(
        xyz=np.asarray(p.xyz, np.float32), rgb=np.asarray(p.rgb, np.uint8), semantic=np.asarray(p.semantic, np.int32),
        instance=np.asarray(instance, np.int32), confidence=np.asarray(p.confidence, np.float32), frame=p.frame,
        transform=transform, thresholds=p.thresholds, stats=stats, steps=step_records(settings.steps, records),
        field_semantic=np.asarray(p.field_semantic if p.field_semantic is not None else np.zeros(len(p)), np.int32),
        field_channel=np.asarray(p.field_channel if p.field_channel is not None else np.zeros(len(p)), np.int32))


# ------------------------------------------------------------------------------------------ benchmark
def benchmark_export(run_path, num_points: int = 1_000_000, output_dir=None) -> dict[str, float]:
    """Time a labelled point-cloud export of ``run_path``: extraction plus writing ``points.ply``.

    Importing Open3D and PyVista (``import_seconds``) and loading the checkpoint and the scene
    (``load_seconds``) are timed separately and not included in ``seconds``. ``peak_rss_mb`` is the
    process's peak resident memory so far (it includes whatever ran before in the same process: call it in
    a fresh process for a clean figure).

    Returns
    -------
    dict
        ``seconds``, ``peak_rss_mb``, ``load_seconds``, ``import_seconds``, ``extract_seconds``,
        ``write_seconds``, ``points``, ``threads`` (torch intra-op threads), ``stages`` (seconds per
        extraction stage).
    """
    t0 = time.perf_counter()
    import open3d  # noqa: F401  (library import time is process start-up, reported apart)
    import pyvista  # noqa: F401

    t_import = time.perf_counter() - t0
    t0 = time.perf_counter()
    loaded = load_run(run_path, "cpu")
    scene = loaded.scene()
    t1 = time.perf_counter()
    pts = extract_labelled_points(loaded, scene, num_points=num_points)
    t2 = time.perf_counter()
    if output_dir is not None:
        Path(output_dir).mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=output_dir) as tmp:
        write_labelled_ply(Path(tmp) / "points.ply", pts.xyz, rgb=pts.rgb, semantic=pts.semantic,
                           instance=pts.instance, confidence=pts.confidence)
        t3 = time.perf_counter()
    return {"seconds": t3 - t1, "peak_rss_mb": peak_rss_mb(), "load_seconds": t1 - t0, "import_seconds": t_import,
            "extract_seconds": t2 - t1, "write_seconds": t3 - t2, "points": int(len(pts)),
            "threads": torch.get_num_threads(), "stages": pts.stats.get("seconds", {})}


