"""``ply`` and ``ply-cloudcompare``: the labelled point cloud as binary PLY (:mod:`lift3d.data.ply`).

``ply`` writes ``points.ply`` with int32 ``semantic``/``instance`` and float32 ``confidence`` vertex
properties (Open3D's tensor API, plyfile and lift3d read them). ``ply-cloudcompare`` writes the same values
into ``points.cloudcompare.ply`` (and ``mesh.cloudcompare.ply`` with ``--mesh``) under the names
``scalar_semantic``, ``scalar_instance`` and ``scalar_confidence``: CloudCompare drops PLY vertex properties
whose names do not start with ``scalar_`` and shows these as scalar fields.
"""

from __future__ import annotations

from lift3d.data.ply import CLOUDCOMPARE_NAMES, write_labelled_ply
from lift3d.export.writers import ExportContext, ExportWriter, register


@register
class PlyWriter(ExportWriter):
    name = "ply"
    help = ("points.ply: float32 x y z, uchar rgb, int32 semantic/instance, float32 confidence, int32 "
            "field_semantic/field_instance (the field's own labels)")
    files = ("points.ply",)

    def write(self, ctx: ExportContext) -> list[str]:
        if ctx.points is None:
            return []
        p = ctx.points
        write_labelled_ply(ctx.out / "points.ply", p.xyz, rgb=p.rgb, semantic=p.semantic, instance=p.instance,
                           confidence=p.confidence, comments=ctx.comments, field_semantic=p.field_semantic,
                           field_instance=p.field_channel)
        return ["points.ply"]


@register
class CloudComparePlyWriter(ExportWriter):
    name = "ply-cloudcompare"
    help = "points.cloudcompare.ply (+ mesh.cloudcompare.ply): labels as CloudCompare scalar fields"
    files = ("points.cloudcompare.ply", "mesh.cloudcompare.ply")

    def write(self, ctx: ExportContext) -> list[str]:
        written = []
        if ctx.points is not None:
            p = ctx.points
            write_labelled_ply(ctx.out / "points.cloudcompare.ply", p.xyz, rgb=p.rgb, semantic=p.semantic,
                               instance=p.instance, confidence=p.confidence, comments=ctx.comments,
                               names=CLOUDCOMPARE_NAMES)
            written.append("points.cloudcompare.ply")
        if ctx.mesh is not None:
            m = ctx.mesh
            write_labelled_ply(ctx.out / "mesh.cloudcompare.ply", m.vertices, rgb=m.rgb, semantic=m.semantic,
                               instance=m.instance, confidence=m.confidence, faces=m.faces, comments=ctx.comments,
                               names=CLOUDCOMPARE_NAMES)
            written.append("mesh.cloudcompare.ply")
        return written
