"""Camera conventions: OpenGL camera-to-world in transforms.json, OpenCV pinhole math, pixel centres at +0.5."""

from __future__ import annotations

import numpy as np
import pytest

from lift3d.data.cameras import Cameras, is_rigid, look_at, opencv_to_opengl, opengl_to_opencv

FX, FY, CX, CY, W, H = 120.0, 100.0, 64.0, 48.0, 128, 96


def _camera(c2w: np.ndarray, model: str = "PINHOLE", distortion=None) -> Cameras:
    return Cameras(c2w=c2w[None], fx=FX, fy=FY, cx=CX, cy=CY, width=W, height=H, camera_model=model,
                   distortion=distortion)


def _random_rigid(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = q, rng.normal(size=3)
    return m


# A camera at (0, -3, 0) looking at the origin with z up: by construction its OpenCV axes are
# x = world +x (right), y = world -z (down), z = world +y (forward); its OpenGL axes are x = +x, y = +z, z = -y.
EYE = np.array([0.0, -3.0, 0.0])
POINT = np.array([0.5, 0.0, 0.25])
# Pinhole by hand in OpenCV axes: camera coordinates (0.5, -0.25, 3).
EXPECTED_UV = np.array([FX * 0.5 / 3 + CX, FY * -0.25 / 3 + CY])  # (84, 39.67)


def test_look_at_axes() -> None:
    c2w = look_at(EYE, np.zeros(3))
    np.testing.assert_allclose(c2w[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)
    np.testing.assert_array_equal(c2w[:3, 3], EYE)
    assert is_rigid(c2w)
    # Looking straight down the up vector still gives a rotation.
    assert is_rigid(look_at(np.array([0.0, 0.0, 5.0]), np.zeros(3)))


def test_known_point_projects_to_known_pixel_in_both_conventions() -> None:
    c2w_gl = look_at(EYE, np.zeros(3))
    # OpenGL: the camera looks down -z and y points up, so v grows with -y.
    p_gl = (np.linalg.inv(c2w_gl) @ np.append(POINT, 1.0))[:3]
    np.testing.assert_allclose(p_gl, [0.5, 0.25, -3.0], atol=1e-12)
    uv_gl = np.array([FX * p_gl[0] / -p_gl[2] + CX, FY * -p_gl[1] / -p_gl[2] + CY])
    # OpenCV: plain pinhole.
    p_cv = (np.linalg.inv(opengl_to_opencv(c2w_gl)) @ np.append(POINT, 1.0))[:3]
    np.testing.assert_allclose(p_cv, [0.5, -0.25, 3.0], atol=1e-12)
    uv_cv = np.array([FX * p_cv[0] / p_cv[2] + CX, FY * p_cv[1] / p_cv[2] + CY])
    np.testing.assert_allclose(uv_gl, EXPECTED_UV, atol=1e-9)
    np.testing.assert_allclose(uv_cv, EXPECTED_UV, atol=1e-9)

    uv, depth = _camera(c2w_gl).project(0, POINT[None])
    np.testing.assert_allclose(uv[0], EXPECTED_UV, atol=1e-9)
    np.testing.assert_allclose(depth, [3.0], atol=1e-12)
    assert _camera(c2w_gl).project(0, np.array([[0.0, -4.0, 0.0]]))[1][0] < 0  # behind the camera


def test_ray_through_the_pixel_passes_through_the_point() -> None:
    cam = _camera(look_at(EYE, np.zeros(3)))
    # rays() takes pixel indices and shoots through the centre (index + 0.5).
    origins, dirs = cam.rays(0, np.array([EXPECTED_UV[0] - 0.5]), np.array([EXPECTED_UV[1] - 0.5]))
    np.testing.assert_allclose(origins[0], EYE)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=-1), 1.0)
    t = (POINT - origins[0]) @ dirs[0]
    assert t > 0
    np.testing.assert_allclose(origins[0] + t * dirs[0], POINT, atol=1e-12)
    # The centre pixel's ray is the viewing direction.
    _, centre = cam.rays(0, np.array([CX - 0.5]), np.array([CY - 0.5]))
    np.testing.assert_allclose(centre[0], cam.forward[0], atol=1e-12)


def test_opengl_to_opencv_is_an_involution_flipping_y_and_z() -> None:
    rng = np.random.default_rng(0)
    c2w = np.stack([_random_rigid(rng) for _ in range(5)])
    cv = opengl_to_opencv(c2w)
    np.testing.assert_array_equal(opengl_to_opencv(cv), c2w)
    np.testing.assert_array_equal(opencv_to_opengl(cv), c2w)
    np.testing.assert_array_equal(cv[:, :3, 0], c2w[:, :3, 0])  # x axis kept
    np.testing.assert_array_equal(cv[:, :3, 1], -c2w[:, :3, 1])  # y axis flipped
    np.testing.assert_array_equal(cv[:, :3, 2], -c2w[:, :3, 2])  # z axis flipped
    np.testing.assert_array_equal(cv[:, :, 3], c2w[:, :, 3])  # camera centre kept
    np.testing.assert_array_equal(cv, c2w @ np.diag([1.0, -1.0, -1.0, 1.0]))
    assert all(is_rigid(m) for m in cv)
    # 3x4 matrices and the input array are left alone.
    np.testing.assert_array_equal(opengl_to_opencv(c2w[0, :3]), cv[0, :3])


@pytest.mark.parametrize("model, distortion", [
    ("OPENCV", [-0.3, 0.1, 0.001, -0.002, 0.0]),  # strong barrel
    ("OPENCV", [0.2, 0.05, 0.001, 0.001, 0.01]),  # pincushion
    ("OPENCV_FISHEYE", [0.1, -0.05, 0.01, 0.002, 0.0]),
])
def test_distorted_rays_and_project_round_trip(model: str, distortion: list[float]) -> None:
    cam = _camera(look_at(np.array([0.3, -3.0, 1.0]), np.zeros(3)), model, np.array(distortion))
    assert cam.has_distortion
    u, v = np.meshgrid(np.arange(0, W, 3), np.arange(0, H, 3))
    u, v = u.ravel(), v.ravel()
    corners_u, corners_v = np.array([0, W - 1, 0, W - 1]), np.array([0, 0, H - 1, H - 1])
    u, v = np.concatenate([u, corners_u]), np.concatenate([v, corners_v])
    origins, dirs = cam.rays(0, u, v)
    uv, depth = cam.project(0, origins + 2.0 * dirs)
    assert np.all(depth > 0)
    np.testing.assert_allclose(uv, np.stack([u + 0.5, v + 0.5], -1), atol=1e-3, rtol=0)
    # Distortion really bends the rays: the pinhole camera gives different directions at the corners.
    _, pinhole_dirs = _camera(cam.c2w[0]).rays(0, corners_u, corners_v)
    assert np.abs(pinhole_dirs - dirs[-4:]).max() > 1e-3


def test_is_rigid() -> None:
    rng = np.random.default_rng(1)
    m = _random_rigid(rng)
    assert is_rigid(m)
    scaled, sheared, mirrored, bad_row = m.copy(), m.copy(), m.copy(), m.copy()
    scaled[:3, :3] *= 1.01
    sheared[:3, :3] = sheared[:3, :3] @ np.array([[1, 0.05, 0], [0, 1, 0], [0, 0, 1]])
    mirrored[:3, 2] *= -1
    bad_row[3, 0] = 0.5
    for bad in (scaled, sheared, mirrored, bad_row, m[:3], np.full((4, 4), np.nan)):
        assert not is_rigid(bad)


def test_cameras_indexing_and_broadcasting() -> None:
    rng = np.random.default_rng(2)
    c2w = np.stack([_random_rigid(rng) for _ in range(4)])
    cams = Cameras(c2w=c2w, fx=np.arange(1.0, 5.0), fy=2.0, cx=3.0, cy=4.0, width=10, height=8)
    assert len(cams) == 4 and cams.distortion.shape == (4, 5) and not cams.has_distortion
    sub = cams[1:3]
    assert len(sub) == 2 and sub.fx.tolist() == [2.0, 3.0] and sub.width.tolist() == [10, 10]
    one = cams[2]
    assert len(one) == 1 and one.fx.tolist() == [3.0]
    np.testing.assert_array_equal(one.c2w[0], c2w[2])
    np.testing.assert_array_equal(cams.K(0), [[1, 0, 3], [0, 2, 4], [0, 0, 1]])
    np.testing.assert_array_equal(cams.centers, c2w[:, :3, 3])
    with pytest.raises(ValueError, match="camera model"):
        Cameras(c2w=c2w, fx=1, fy=1, cx=1, cy=1, width=2, height=2, camera_model="EQUIRECT")
