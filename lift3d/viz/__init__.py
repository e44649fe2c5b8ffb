"""Pictures of lift3d's results: labelled points and meshes (PyVista), runs and benchmarks (matplotlib).

Everything renders off-screen by default, so it works on headless machines; ``plot_instances`` returns a
:class:`pyvista.Plotter` a notebook or desktop session can ``.show()``.

* :func:`plot_instances` — instance colours | class colours | legend of labelled points or a mesh
  (a ``points.ply`` / ``mesh.ply`` path, arrays, a dict, or the export API's dataclass).
* :func:`save_views`, :func:`save_turntable` — PNG per camera view, GIF/MP4 orbit.
* :func:`write_html` — one self-contained web page (WebGL, offline) with instance/class colours and a legend.
* :func:`plot_run` — test views beside their labels, and training curves, of a run folder.
* :func:`plot_pareto`, :func:`plot_scaling` — the benchmark's speed/accuracy and scaling charts.
* :func:`instance_color`, :func:`semantic_color`, :func:`panoptic_color` — the palette: an instance id has
  the same colour in every picture.

Examples
--------
>>> from lift3d.viz import instance_color
>>> instance_color([1, 2]).shape
(2, 3)
"""

from lift3d.viz.bench import plot_pareto, plot_scaling
from lift3d.viz.html import write_html
from lift3d.viz.palette import instance_color, panoptic_color, semantic_color
from lift3d.viz.points import as_geometry, plot_instances, save_turntable, save_views
from lift3d.viz.run import plot_curves, plot_frame_grid, plot_run

__all__ = [
    "as_geometry",
    "instance_color",
    "panoptic_color",
    "plot_curves",
    "plot_frame_grid",
    "plot_instances",
    "plot_pareto",
    "plot_run",
    "plot_scaling",
    "save_turntable",
    "save_views",
    "semantic_color",
    "write_html",
]
