"""``ros2bag``: a rosbag2 folder (MCAP storage) that ``ros2 bag play`` publishes into a ROS 2 robot stack.

``rosbag2/`` (``metadata.yaml`` + ``rosbag2.mcap``) holds one message per topic, stamped with the export
time, in the frame ``--frame-id`` (default ``map``):

``/lift3d/points`` — ``sensor_msgs/msg/PointCloud2``
    One row per exported point (``height`` 1, little-endian, dense), 28 bytes: ``x y z`` FLOAT32 (offsets
    0, 4, 8), ``rgb`` FLOAT32 at 12 holding PCL's packed colour bits ``255 << 24 | r << 16 | g << 8 | b`` (the
    layout of ``pcl::PointXYZRGB``, which RViz's RGB8 colour transformer reads), ``label`` UINT32 at 16
    (semantic category id), ``instance`` UINT32 at 20 (0 = stuff), ``confidence`` FLOAT32 at 24.
``/lift3d/instances`` — ``visualization_msgs/msg/MarkerArray``
    A ``DELETEALL`` marker, then per instance a ``CUBE`` (namespace ``boxes``, id = instance id) posed and
    sized as its oriented box in ``instances.json``, in its class colour at alpha 0.5, and a
    ``TEXT_VIEW_FACING`` (namespace ``labels``, same id) reading ``<id> <class>`` above the box.

Written with ``rosbags`` (pure Python, no ROS install; ``pip install 'lift3d[ros]'``) in rosbag2 format
version 8 with the message definitions of ROS 2 Jazzy. ``PointCloud2`` is unchanged since Foxy;
``Marker`` gained fields in Iron, so older distributions cannot decode ``/lift3d/instances``.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from lift3d.export.writers import ExportContext, ExportWriter, register
from lift3d.utils.atomic import atomic_dir

POINTS_TOPIC = "/lift3d/points"
MARKERS_TOPIC = "/lift3d/instances"
#: PointCloud2 layout: name → (offset, PointField datatype name, numpy dtype).
CLOUD_FIELDS = {"x": (0, "FLOAT32", "<f4"), "y": (4, "FLOAT32", "<f4"), "z": (8, "FLOAT32", "<f4"),
                "rgb": (12, "FLOAT32", "<u4"), "label": (16, "UINT32", "<u4"), "instance": (20, "UINT32", "<u4"),
                "confidence": (24, "FLOAT32", "<f4")}
POINT_STEP = 28


@register
class Ros2BagWriter(ExportWriter):
    name = "ros2bag"
    help = "rosbag2/ (MCAP): PointCloud2 /lift3d/points, MarkerArray /lift3d/instances"
    files = ("rosbag2/",)
    extra = "ros"
    modules = ("rosbags.rosbag2",)

    def write(self, ctx: ExportContext) -> list[str]:
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore

        typestore = get_typestore(Stores.ROS2_JAZZY)
        stamp_ns = time.time_ns()
        cloud = ctx.cloud
        colors = {int(c["id"]): c["color"] for c in ctx.classes}
        cloud_msg = pointcloud2(typestore, cloud.xyz, cloud.rgb, cloud.semantic, cloud.instance, cloud.confidence,
                                frame_id=ctx.options.frame_id, stamp_ns=stamp_ns)
        markers = marker_array(typestore, ctx.records, colors, up=ctx.up, frame_id=ctx.options.frame_id,
                               stamp_ns=stamp_ns, text_height=0.1 * ctx.world_length)
        with atomic_dir(ctx.out / "rosbag2") as folder:
            with Writer(folder, version=8, storage_plugin=StoragePlugin.MCAP) as bag:
                for topic, msg in ((POINTS_TOPIC, cloud_msg), (MARKERS_TOPIC, markers)):
                    conn = bag.add_connection(topic, msg.__msgtype__, typestore=typestore)
                    bag.write(conn, stamp_ns, typestore.serialize_cdr(msg, msg.__msgtype__))
        ctx.notes["ros2bag"] = {"frame_id": ctx.options.frame_id, "topics": [POINTS_TOPIC, MARKERS_TOPIC],
                                "stamp_ns": stamp_ns}
        return ["rosbag2/"]


def _header(typestore, frame_id: str, stamp_ns: int):
    t = typestore.types
    return t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000),
        frame_id=frame_id)


def cloud_rows(xyz, rgb, semantic, instance, confidence) -> np.ndarray:
    """The ``[N]`` structured array of :data:`CLOUD_FIELDS` (the PointCloud2 ``data`` bytes)."""
    n = len(xyz)
    rows = np.zeros(n, dtype=[(k, v[2]) for k, v in CLOUD_FIELDS.items()])
    xyz = np.asarray(xyz)
    rows["x"], rows["y"], rows["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    if rgb is not None:
        c = np.asarray(rgb, np.uint32)
        rows["rgb"] = np.uint32(255 << 24) | (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]
    rows["label"] = np.asarray(semantic)
    rows["instance"] = np.asarray(instance)
    rows["confidence"] = np.asarray(confidence) if confidence is not None else 1.0
    return rows


def pointcloud2(typestore, xyz, rgb, semantic, instance, confidence, *, frame_id: str, stamp_ns: int):
    """A ``sensor_msgs/msg/PointCloud2`` of the labelled points (layout in the module docstring)."""
    t = typestore.types
    field_cls = t["sensor_msgs/msg/PointField"]
    rows = cloud_rows(xyz, rgb, semantic, instance, confidence)
    fields = [field_cls(name=k, offset=off, datatype=getattr(field_cls, dt), count=1)
              for k, (off, dt, _) in CLOUD_FIELDS.items()]
    return t["sensor_msgs/msg/PointCloud2"](
        header=_header(typestore, frame_id, stamp_ns), height=1, width=len(rows), fields=fields,
        is_bigendian=False, point_step=POINT_STEP, row_step=POINT_STEP * len(rows),
        data=np.frombuffer(rows.tobytes(), np.uint8), is_dense=True)


def read_pointcloud2(msg) -> dict[str, np.ndarray]:
    """The fields of a ``PointCloud2`` written by :func:`pointcloud2`: ``xyz``, ``rgb`` (``[N, 3]`` uint8),
    ``label``, ``instance``, ``confidence`` (for tests and users checking a bag)."""
    offsets = {f.name: f.offset for f in msg.fields}
    dtype = np.dtype({"names": list(offsets), "formats": [CLOUD_FIELDS[k][2] for k in offsets],
                      "offsets": list(offsets.values()), "itemsize": msg.point_step})
    rows = np.frombuffer(np.asarray(msg.data, np.uint8).tobytes(), dtype=dtype, count=msg.width * msg.height)
    packed = rows["rgb"]
    return {"xyz": np.stack([rows["x"], rows["y"], rows["z"]], -1), "label": rows["label"].copy(),
            "rgb": np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255], -1).astype(np.uint8),
            "instance": rows["instance"].copy(), "confidence": rows["confidence"].copy()}


def marker_array(typestore, records: list[dict[str, Any]], colors: dict[int, Any], *, up: np.ndarray,
                 frame_id: str, stamp_ns: int, text_height: float):
    """A ``visualization_msgs/msg/MarkerArray``: DELETEALL, then a box and a text label per instance."""
    from scipy.spatial.transform import Rotation

    t = typestore.types
    marker_cls, geo = t["visualization_msgs/msg/Marker"], "geometry_msgs/msg/"
    header = _header(typestore, frame_id, stamp_ns)
    duration = t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0)

    def marker(ns, mid, kind, action, center, quat, scale, rgba, text=""):
        return marker_cls(
            header=header, ns=ns, id=mid, type=kind, action=action,
            pose=t[geo + "Pose"](position=t[geo + "Point"](x=float(center[0]), y=float(center[1]), z=float(center[2])),
                                 orientation=t[geo + "Quaternion"](x=float(quat[0]), y=float(quat[1]),
                                                                   z=float(quat[2]), w=float(quat[3]))),
            scale=t[geo + "Vector3"](x=float(scale[0]), y=float(scale[1]), z=float(scale[2])),
            color=t["std_msgs/msg/ColorRGBA"](r=float(rgba[0]), g=float(rgba[1]), b=float(rgba[2]), a=float(rgba[3])),
            lifetime=duration, frame_locked=False, points=[], colors=[], texture_resource="",
            texture=t["sensor_msgs/msg/CompressedImage"](header=header, format="", data=np.zeros(0, np.uint8)),
            uv_coordinates=[], text=text, mesh_resource="",
            mesh_file=t["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
            mesh_use_embedded_materials=False)

    identity = (0.0, 0.0, 0.0, 1.0)
    out = [marker("", 0, marker_cls.CUBE, marker_cls.DELETEALL, (0, 0, 0), identity, (1, 1, 1), (0, 0, 0, 0))]
    for r in records:
        obb = r["obb"]
        rot = np.asarray(obb["rotation"], np.float64)
        if np.linalg.det(rot) < 0:  # a box is symmetric: flipping one axis makes it a proper rotation
            rot = rot * np.array([1.0, 1.0, -1.0])
        quat = Rotation.from_matrix(rot).as_quat()  # x, y, z, w
        rgb = np.asarray(colors.get(int(r["class_id"]), (128, 128, 128)), float) / 255.0
        extent = np.maximum(np.asarray(obb["extent"], float), 1e-4)
        center = np.asarray(obb["center"], float)
        out.append(marker("boxes", int(r["id"]), marker_cls.CUBE, marker_cls.ADD, center, quat, extent,
                          (*rgb, 0.5)))
        top = center + np.asarray(up, float) * (0.5 * float(np.abs(rot.T @ up) @ extent) + text_height)
        out.append(marker("labels", int(r["id"]), marker_cls.TEXT_VIEW_FACING, marker_cls.ADD, top, identity,
                          (0, 0, text_height), (1.0, 1.0, 1.0, 1.0), text=f"{r['id']} {r['class_name']}"))
    return t["visualization_msgs/msg/MarkerArray"](markers=out)
