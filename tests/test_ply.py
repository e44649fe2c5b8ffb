"""Labelled PLY (docs/export.md): round trips through our reader, Open3D's tensor API and PyVista (clients from
``tests/interop.py``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lift3d.data.ply import read_labelled_ply, write_labelled_ply
from lift3d.errors import InputError
from interop import require_module

INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1


def _labelled_points(n: int = 64, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    semantic = rng.integers(0, 200, n).astype(np.int64)
    instance = rng.integers(0, 2**20, n).astype(np.int64)
    # The int32 extremes must survive (no float or uint16 detour).
    semantic[:2] = [INT32_MAX, 0]
    instance[:2] = [INT32_MIN, INT32_MAX]
    return {
        "xyz": rng.normal(size=(n, 3)).astype(np.float32),
        "rgb": rng.integers(0, 256, (n, 3), dtype=np.uint8),
        "normals": rng.normal(size=(n, 3)).astype(np.float32),
        "semantic": semantic,
        "instance": instance,
        "confidence": rng.random(n).astype(np.float32),
    }


def _write(path: Path, data: dict, **extra) -> None:
    write_labelled_ply(path, data["xyz"], rgb=data["rgb"], normals=data["normals"], semantic=data["semantic"],
                       instance=data["instance"], confidence=data["confidence"], **extra)


def test_labelled_points_round_trip(tmp_path: Path) -> None:
    data = _labelled_points()
    path = tmp_path / "points.ply"
    _write(path, data, comments=["frame world", "lift3d test"])
    out = read_labelled_ply(path)
    assert "faces" not in out
    assert out["comments"] == ["frame world", "lift3d test"]
    for key in ("xyz", "rgb", "normals", "semantic", "instance", "confidence"):
        np.testing.assert_array_equal(out[key], data[key], err_msg=key)
    assert out["semantic"].dtype == out["instance"].dtype == np.int32
    assert out["rgb"].dtype == np.uint8 and out["xyz"].dtype == out["confidence"].dtype == np.float32
    header = path.read_bytes().split(b"end_header")[0].decode()
    assert "binary_little_endian" in header
    assert "property int semantic" in header and "property int instance" in header


def test_float_colours_are_scaled(tmp_path: Path) -> None:
    path = tmp_path / "c.ply"
    write_labelled_ply(path, np.zeros((2, 3)), rgb=np.array([[0.0, 0.5, 1.0], [1.0, 1.0, 0.0]]))
    assert read_labelled_ply(path)["rgb"].tolist() == [[0, 128, 255], [255, 255, 0]]


@pytest.mark.parametrize("n_faces", [5, 0])
def test_labelled_mesh_round_trip(tmp_path: Path, n_faces: int) -> None:
    data = _labelled_points(12)
    faces = np.random.default_rng(3).integers(0, 12, (n_faces, 3))
    path = tmp_path / "mesh.ply"
    _write(path, data, faces=faces)
    out = read_labelled_ply(path)
    assert out["faces"].dtype == np.int32 and out["faces"].shape == (n_faces, 3)
    np.testing.assert_array_equal(out["faces"], faces)
    np.testing.assert_array_equal(out["semantic"], data["semantic"])
    np.testing.assert_array_equal(out["instance"], data["instance"])


def test_open3d_tensor_reader_keeps_int32_attributes(tmp_path: Path) -> None:
    o3d = require_module("open3d", pip="pip install open3d")
    data = _labelled_points()
    path = tmp_path / "points.ply"
    _write(path, data)
    cloud = o3d.t.io.read_point_cloud(str(path))
    # Open3D names: positions/colors/normals for the standard properties, the PLY names for the rest,
    # each custom scalar as an [N, 1] tensor.
    assert {"positions", "colors", "normals", "semantic", "instance", "confidence"} <= set(cloud.point)
    assert cloud.point["semantic"].dtype == o3d.core.Dtype.Int32
    assert cloud.point["instance"].dtype == o3d.core.Dtype.Int32
    assert cloud.point["colors"].dtype == o3d.core.Dtype.UInt8
    assert tuple(cloud.point["semantic"].shape) == (len(data["xyz"]), 1)
    np.testing.assert_array_equal(cloud.point["semantic"].numpy()[:, 0], data["semantic"])
    np.testing.assert_array_equal(cloud.point["instance"].numpy()[:, 0], data["instance"])
    np.testing.assert_array_equal(cloud.point["confidence"].numpy()[:, 0], data["confidence"])
    np.testing.assert_array_equal(cloud.point["positions"].numpy(), data["xyz"])
    np.testing.assert_array_equal(cloud.point["colors"].numpy(), data["rgb"])


def test_open3d_reads_the_mesh_faces(tmp_path: Path) -> None:
    o3d = require_module("open3d", pip="pip install open3d")
    data = _labelled_points(12)
    faces = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 11]])
    path = tmp_path / "mesh.ply"
    _write(path, data, faces=faces)
    mesh = o3d.t.io.read_triangle_mesh(str(path))
    np.testing.assert_array_equal(mesh.triangle.indices.numpy(), faces)
    np.testing.assert_array_equal(mesh.vertex.positions.numpy(), data["xyz"])


def test_pyvista_reads_points_mesh_and_colours(tmp_path: Path) -> None:
    pv = require_module("pyvista", pip="pip install pyvista")
    data = _labelled_points(12)
    faces = np.array([[0, 1, 2], [2, 3, 4]])
    path = tmp_path / "mesh.ply"
    _write(path, data, faces=faces)
    mesh = pv.read(path)
    np.testing.assert_array_equal(np.asarray(mesh.points), data["xyz"])
    np.testing.assert_array_equal(mesh.faces.reshape(-1, 4)[:, 1:], faces)
    np.testing.assert_array_equal(mesh.point_data["RGB"], data["rgb"])
    # VTK's PLY reader (9.x) drops custom scalar properties; when a later VTK keeps them they must be exact.
    for key in ("semantic", "instance"):
        if key in mesh.point_data:
            np.testing.assert_array_equal(mesh.point_data[key], data[key])


def test_unreadable_ply(tmp_path: Path) -> None:
    missing = tmp_path / "missing.ply"
    with pytest.raises(InputError, match="file not found") as info:
        read_labelled_ply(missing)
    assert str(missing) in str(info.value)
    broken = tmp_path / "broken.ply"
    broken.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nend_header\n\x00")
    with pytest.raises(InputError, match="not a readable PLY") as info:
        read_labelled_ply(broken)
    assert str(broken) in str(info.value)
    no_xyz = tmp_path / "no_xyz.ply"
    no_xyz.write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float a\nend_header\n1\n")
    with pytest.raises(InputError, match="no x, y, z"):
        read_labelled_ply(no_xyz)


def test_non_triangle_faces_are_bad_input(tmp_path: Path) -> None:
    from plyfile import PlyData, PlyElement

    vertex = np.zeros(6, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    face = np.empty(2, dtype=[("vertex_indices", "O")])
    face["vertex_indices"][0] = np.array([0, 1, 2, 3], np.int32)
    face["vertex_indices"][1] = np.array([2, 3, 4], np.int32)
    path = tmp_path / "quads.ply"
    PlyData([PlyElement.describe(vertex, "vertex"),
             PlyElement.describe(face, "face", val_types={"vertex_indices": "int32"})]).write(str(path))
    with pytest.raises(InputError, match=r"face.vertex_indices: only triangle meshes.*\[4\]") as info:
        read_labelled_ply(path)
    assert info.value.where == str(path)
