"""Rendered images of a trained run on disk: what ``lift3d render`` runs.

The images' layout, the panoptic ids and the camera paths are :mod:`lift3d.render.output`'s; this module
loads the run, renders each camera and, by default, names the objects in the images as the export names
them: each thing pixel takes the id of the nearest object of its class in the run's labelled point cloud
(:func:`lift3d.export.pointcloud.extract_labelled_points` with ``lift3d export``'s defaults, then
:func:`lift3d.export.instances.frame_instance_ids`). So an object has one id in every frame, and it is the
``id`` of its record in the ``instances.json`` of ``lift3d export --pointcloud``, as ``lift3d eval`` scores
it. ``instances="field"`` writes the argmax of the field's instance channels instead (one object can hold
different channels in different views; Panoptic Lifting's rule).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from lift3d.errors import InputError
from lift3d.export.instances import INSTANCE_SOURCES, check_instance_source, frame_instance_ids
from lift3d.export.pointcloud import extract_labelled_points
from lift3d.model.run import load_run
from lift3d.render.images import MIN_SEGMENT_FRACTION, check_min_segment_fraction, render_frame
from lift3d.render.output import DEFAULT_OUTPUTS, RenderedOutputWriter, load_camera_path, resolve_outputs
from lift3d.render.rays import RayGenerator
from lift3d.utils.progress import progress_bar


@dataclass
class RenderResult:
    """What :func:`render_to_folder` wrote."""

    output_dir: Path
    outputs: list[str]
    stems: list[str]
    seconds: float
    panoptic_json: Path | None
    size: tuple[int, int]  # (H, W) of the first frame
    instances_from: str = "field"  # "export", "field" or "field (<why not the export>)"


@dataclass(frozen=True)
class FrameSettings:
    """How each frame is rendered."""

    downscale: int = 1
    """Render every ``downscale``-th pixel block (images ``downscale`` times smaller)."""
    chunk_size: int | None = None
    """Rays per rendering chunk (memory vs. speed); default from the run's config."""
    min_segment_fraction: float = MIN_SEGMENT_FRACTION
    """Thing segments under this fraction of a frame take their surroundings' labels
    (:func:`lift3d.render.images.merge_small_segments`; 0 writes the raw argmax labels)."""


def render_to_folder(
    run: str | Path,
    output_dir: str | Path,
    outputs: Sequence[str] = DEFAULT_OUTPUTS,
    *,
    split: str = "test",
    camera_path: str | Path | None = None,
    data: str | Path | None = None,
    frames: FrameSettings = FrameSettings(),
    device: str = "auto",
    previews: bool = True,
    progress: bool = True,
    instances: str = INSTANCE_SOURCES[0],
) -> RenderResult:
    """Render a split of the run's scene (or a camera path) into ``output_dir``.

    Parameters
    ----------
    run : str or Path
        Run folder (its newest readable checkpoint is used).
    output_dir : str or Path
        Where ``<output>/<stem>.png`` (and ``panoptic.json``) go.
    outputs : sequence of str
        Names from :data:`lift3d.render.output.OUTPUTS`; previews are added unless ``previews`` is False.
    split : str
        ``train``, ``val`` or ``test`` (ignored with ``camera_path``).
    camera_path : str or Path, optional
        A camera path JSON (:func:`lift3d.render.output.load_camera_path`) to render instead of a split.
    data : str or Path, optional
        The scene folder, when it moved since training.
    frames : FrameSettings
        Downscale, rays per chunk and the small-segment rule.
    device : str
        ``auto``, ``cpu`` or ``cuda[:N]``.
    previews, progress : bool
        Colourised previews; progress bar.
    instances : {"export", "field"}
        Instance ids of thing pixels: the exported objects' ids (default; extracting the cloud takes a few
        seconds; thing pixels no object of their class is near get 0), or the field's channels ``1..V``.
        Without the scene's training cameras (a camera path with no scene folder) or an instance head the
        field's channels are written, with a warning.

    Returns
    -------
    RenderResult
    """
    downscale, chunk_size, min_segment_fraction = frames.downscale, frames.chunk_size, frames.min_segment_fraction
    if downscale < 1:
        raise InputError("--downscale", f"must be a positive integer (got {downscale})")
    check_min_segment_fraction(min_segment_fraction)
    if chunk_size is not None and chunk_size < 1:
        raise InputError("--chunk-size", f"must be a positive number of rays (got {chunk_size})")
    check_instance_source(instances)
    names = resolve_outputs(outputs, previews)
    loaded = load_run(run, device)
    scene = None
    try:
        scene = loaded.scene(data)
    except InputError:
        if camera_path is None or data is not None:
            raise  # a split needs the scene's cameras; a --data that does not load is always an error
    categories = list(scene.categories) if scene is not None else list(loaded.classes.values())
    if camera_path is not None:
        cp = load_camera_path(camera_path, scene.cameras if scene is not None else None)
        cameras = cp.cameras
        indices, stems = list(range(len(cp.stems))), cp.stems
        source = {"camera_path": str(Path(camera_path).resolve())}
    else:
        assert scene is not None
        cameras = scene.cameras
        indices = [int(i) for i in scene.split(split)]
        stems = [scene.frames[i].name for i in indices]
        source = {"split": split, "scene": str(scene.root.resolve())}
    if not indices:
        raise InputError("--split", f"split {split!r} has no frames")
    rays = RayGenerator(cameras, loaded.norm.c2w_normalized(cameras.c2w), loaded.device)

    needs_labels = bool(set(names) - {"rgb", "depth", "depth_vis"})
    needs_ids = bool(set(names) & {"instance", "instance_vis", "panoptic"})
    cloud, things, instances_from = None, [], "field"
    if needs_ids and instances == "export":
        cloud, things, instances_from = _export_cloud(loaded, scene)
    num_ids = int(loaded.cfg.field.num_instance_channels)
    if cloud is not None:
        num_ids = int(cloud.instance.max(initial=0))
    writer = RenderedOutputWriter(Path(output_dir), names, categories, num_instance_channels=num_ids)
    start = time.perf_counter()
    size = (0, 0)
    for i, stem in progress_bar(list(zip(indices, stems)), desc="render", disable=not progress, unit="frame"):
        fr = render_frame(loaded.model, rays, i, loaded.norm.scale, downscale=downscale, with_labels=needs_labels,
                          chunk_size=chunk_size, min_segment_fraction=min_segment_fraction)
        if cloud is not None and fr.semantic is not None:
            fr.instance = frame_instance_ids(cameras, i, fr.semantic, fr.surface_depth, cloud.xyz, cloud.semantic,
                                             cloud.instance, things, downscale=downscale)
        if size == (0, 0):
            size = fr.rgb.shape[:2]
        writer.write(stem, fr)
    info = {"run": str(Path(run).resolve()), "step": loaded.step, "downscale": downscale,
            "instances_from": instances_from, **source}
    pj = writer.finish(info)
    return RenderResult(Path(output_dir), names, stems, time.perf_counter() - start, pj, size, instances_from)


def _export_cloud(loaded, scene):
    """The run's labelled cloud with ``lift3d export``'s defaults, its thing ids and where ids come from.

    ``(None, [], "field (<why>)")`` when the export cannot name objects: no instance head, no scene folder
    (its training cameras decide what the export keeps), or a field with no surface yet.
    """
    why = None
    if not loaded.model.has_instances:
        why = "the model has no instance head"
    elif scene is None:
        why = "no scene folder: the export needs the training cameras (--data)"
    if why is None:
        try:
            cloud = extract_labelled_points(loaded, scene)
        except InputError as exc:
            why = f"no export: {exc}"
        else:
            things = sorted({int(c) for c in np.unique(cloud.semantic[cloud.instance > 0])})
            return cloud, things, "export"
    warnings.warn(f"lift3d render: instance ids are the field's channels ({why})", stacklevel=3)
    return None, [], f"field ({why})"
